"""Where a training step of the default ``fast`` run (or ``--model splat``) spends its time, phase by phase.

    python benchmarks/step_profile.py [--data src/nerfkit/assets/lego_200x200.npz] [--steps 1200]
    python benchmarks/step_profile.py --model splat --data LLFF_FOLDER --points OUT/points.npz [--steps 300]
    python benchmarks/step_profile.py --ab OLD_SRC NEW_SRC [--repeats 3] [--steps 600]
    PYTHONPATH=NEW_SRC python benchmarks/step_profile.py --interleave OLD_SRC [--steps 700]
    PYTHONPATH=NEW_SRC python benchmarks/step_profile.py --model splat --interleave OLD_SRC [--data ...] [--steps 300]

One run trains the default model exactly as ``nerfkit train --steps N`` would (the scene
kind's defaults, seed 0, no evaluation, no checkpoints) and times every step with wrappers
around the compiled kernels and the trainer's parts. Each phase's time is exclusive (a
kernel's time is not counted again in the Python function that calls it):

* ``draw rays``: the random ray batch and its pixels (``RaysData.sample``);
* ``forward kernel`` / ``backward kernel`` / ``Adam kernel``: the compiled march-and-shade
  pass, its gradient pass, and the sparse Adam update (with the list of touched rows);
* ``forward, torch side``: the rest of ``render_rays`` (the box, SH basis, conversions,
  background); ``backward, torch side``: autograd around the compiled backward;
* ``loss``; ``finite check``; ``optimizer, python side``;
* ``schedules: before / after``: growth, and the occupancy refreshes with the other
  after-step jobs; ``rest of the step``: what ``train_step`` does around all these.
* ``--model splat``: ``project`` (3D covariances, EWA projection; on the compiled path also
  the SH colour and opacity, and ``project backward`` their gradients), ``SH colour`` (the
  torch path), ``depth sort``, ``tile binning``, ``rasterise forward`` / ``backward`` (the compiled kernels),
  ``render, torch side``, ``loss: SSIM forward`` (its backward is in autograd's time),
  ``optimizer``, ``schedules: after_step`` (density control); stages are the SH degrees.

Prints a table of milliseconds per step (wall, the mean over the timed steps, and by grid
stage) and the step's size (rays, samples per ray, touched grid rows). With ``--ab``, runs
the profile in fresh processes alternately on two source trees (``PYTHONPATH``), ``--repeats``
times each, and prints the per-phase medians side by side with the ratio of the step time:
an A/B that a shared machine's load affects alike. With ``--interleave``, one run of this
tree takes for each step, at random, the old tree's compiled grid kernels and ray batches
or its own (they must compute the same: the losses digest then equals a plain
run's), and prints the median step of each by grid stage: the closest A/B under a load that
changes from minute to minute. With ``--model splat``, the steps take at random the old
tree's splat rendering (its torch reference, compiled kernels and ``splat_ops``), its
model's ``render_view``, ``loss`` and ``gradients_finite`` and its Adam's ``fused`` flag,
or this tree's (they must compute the same up to rounding), by SH degree. Run under
``nice`` beside other work and the absolute figures grow; compare only runs made side by side.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LEGO = REPO / "src" / "nerfkit" / "assets" / "lego_200x200.npz"
KERNELS = {
    "render_forward": "forward kernel",
    "render_backward": "backward kernel",
    "distortion_forward": "forward kernel",
    "adam_rows": "Adam kernel",
    "touched_rows": "Adam kernel",
    "clear_rows": "rest of the step",
    "tv_rows": "schedules: gradients",
    "occupancy_from_grid": "schedules: after_step",
}
# the splat's compiled rasterizer, and its torch parts (module attributes looked up at call time)
SPLAT_KERNELS = {
    "project_forward": "project",
    "project_backward": "project backward",
    "depth_order": "depth sort",
    "bin_tiles": "tile binning",
    "rasterize_forward": "rasterise forward",
    "rasterize_backward": "rasterise backward",
}
SPLAT_TORCH = {
    "covariance_3d": "project",
    "project_gaussians": "project",
    "sh_to_rgb": "SH colour",
    "depth_order": "depth sort",
}
ORDER = (
    "schedules: before_step",
    "project",
    "SH colour",
    "depth sort",
    "tile binning",
    "rasterise forward",
    "render, torch side",
    "loss: SSIM forward",
    "rasterise backward",
    "project backward",
    "optimizer",
    "view corrections",
    "draw rays",
    "forward kernel",
    "forward, torch side",
    "loss",
    "backward kernel",
    "backward, torch side",
    "finite check",
    "schedules: gradients",
    "Adam kernel",
    "optimizer, python side",
    "schedules: after_step",
    "rest of the step",
)


class PhaseClock:
    """Exclusive time per phase label: a wrapped call's time, less its wrapped callees'.
    Wall time, and the process's CPU time (all its threads: a kernel on two threads
    counts up to twice its wall time; a thread waiting for a core counts nothing)."""

    def __init__(self):
        self.totals: dict[str, float] = defaultdict(float)
        self.cpu: dict[str, float] = defaultdict(float)
        self._stack: list[list] = []

    def wrap(self, fn, label):
        def timed(*args, **kwargs):
            frame = [label, 0.0, 0.0]
            self._stack.append(frame)
            start, cpu = time.perf_counter(), time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed, used = time.perf_counter() - start, time.process_time() - cpu
                self._stack.pop()
                self.totals[frame[0]] += elapsed - frame[1]
                self.cpu[frame[0]] += used - frame[2]
                if self._stack:
                    self._stack[-1][1] += elapsed
                    self._stack[-1][2] += used

        return timed

    def take(self) -> tuple[dict[str, float], dict[str, float]]:
        out = dict(self.totals), dict(self.cpu)
        self.totals, self.cpu = defaultdict(float), defaultdict(float)
        return out


def load_scene(data: str, model: str, points: str | None):
    """The training scene: a scene ``.npz``, or an LLFF folder as ``heldout.py`` trains flower
    (every 8th photo held out, ``images_8``). For the splat, an LLFF scene starts from the
    points triangulated at its poses; with ``points`` (an ``.npz``, written on first use)
    they are computed once and every run starts from the same ones."""
    import numpy as np

    from nerfkit.data.npz import load_npz

    if Path(data).is_dir():
        from heldout import load_flower

        scene = load_flower(Path(data), 8.0).train
    else:
        scene = load_npz(data)
    if model != "splat" or scene.points is not None or points is None:
        return scene
    from dataclasses import replace

    if not Path(points).is_file():
        from nerfkit.capture.points import triangulate_views

        with tempfile.TemporaryDirectory(dir=Path(points).resolve().parent) as work:
            pts = triangulate_views(scene.train, work=work)
        np.savez(points, xyz=pts.xyz, rgb=pts.rgb)
    saved = np.load(points)
    return replace(scene, points=saved["xyz"], point_colors=saved["rgb"])


def wrap_fast(clock: PhaseClock, tr) -> list:
    """Time the ``fast`` model's compiled grid kernels and its ray batch; returns a list
    that collects each step's touched grid rows."""
    from nerfkit.kernels import numba_kernels

    nb = numba_kernels()
    if nb is None:
        raise SystemExit("step_profile: the compiled kernels are not available (numba)")
    for name, label in KERNELS.items():
        setattr(nb, name, clock.wrap(getattr(nb, name), label))
    touched: list = []
    touched_rows = nb.touched_rows

    def count_rows(flags):
        rows = touched_rows(flags)
        touched.append(len(rows))
        return rows

    nb.touched_rows = count_rows
    tr.rays.sample = clock.wrap(tr.rays.sample, "draw rays")
    tr.model.render_rays = clock.wrap(tr.model.render_rays, "forward, torch side")
    return touched


def wrap_splat(clock: PhaseClock, tr) -> None:
    """Time the splat's parts: projection, SH colour, depth sort, tile binning, the compiled
    rasterizer forward and backward, D-SSIM (forward; its backward is in autograd's time)."""
    from nerfkit.kernels import splat_kernels
    from nerfkit.kernels import splat_reference as ref
    from nerfkit.models import splat

    nb = splat_kernels()
    if nb is None:
        raise SystemExit("step_profile: the compiled splat kernels are not available (numba)")
    for name, label in SPLAT_KERNELS.items():
        if hasattr(nb, name):  # (an older tree may lack some)
            setattr(nb, name, clock.wrap(getattr(nb, name), label))
    for name, label in SPLAT_TORCH.items():
        setattr(ref, name, clock.wrap(getattr(ref, name), label))
    splat.ssim = clock.wrap(splat.ssim, "loss: SSIM forward")
    tr.model.render_view = clock.wrap(tr.model.render_view, "render, torch side")
    if tr.view_optimizer is not None:
        tr.view_optimizer.step = clock.wrap(tr.view_optimizer.step, "view corrections")


def profile(data: str, steps: int, start: int, seed: int, model_name: str = "fast", points: str | None = None) -> dict:
    """Train ``model_name`` for ``steps`` steps; phase times of steps ``start`` on."""
    import numpy as np
    import torch

    from nerfkit import presets
    from nerfkit.models import model_config_class
    from nerfkit.train import trainer as trainer_module
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    scene = load_scene(data, model_name, points)
    with tempfile.TemporaryDirectory() as out:
        cfg = TrainConfig(data=data, model=model_name, out=out, steps=steps, seed=seed, checkpoint_seconds=1e9)
        cfg, model_cfg = presets.resolve(cfg.validate(), model_config_class(model_name)(), scene).configs()
        tr = Trainer(scene, cfg, model_cfg, quiet=True)
        tr.model.load_kernels()
        clock = PhaseClock()
        splatting = model_name == "splat"
        touched = [] if splatting else wrap_fast(clock, tr)
        if splatting:
            wrap_splat(clock, tr)
        run_schedules = trainer_module.run_schedules
        trainer_module.run_schedules = lambda jobs, state, phase: clock.wrap(run_schedules, f"schedules: {phase}")(
            jobs, state, phase
        )
        model = tr.model
        model.loss = clock.wrap(model.loss, "loss")
        model.gradients_finite = clock.wrap(model.gradients_finite, "finite check")
        tr.optimizer.step = clock.wrap(tr.optimizer.step, "optimizer" if splatting else "optimizer, python side")
        backward = torch.autograd.backward
        torch.autograd.backward = clock.wrap(backward, "backward, torch side")
        step_fn = clock.wrap(tr.train_step, "rest of the step")
        by_stage: dict[int, dict] = {}
        try:
            while tr.step < steps:
                # (splat: stages are the SH degrees)
                stage = model.active_degree if splatting else model.stage
                touched_before = len(touched)
                t0 = time.perf_counter()
                stats = step_fn()
                wall = time.perf_counter() - t0
                tr.step += 1
                phases, cpu = clock.take()
                if tr.step <= start:
                    continue
                s = by_stage.setdefault(stage, new_stage())
                s["steps"] += 1
                s["wall"].append(wall)
                for k, v in phases.items():
                    s["phases"][k] += v
                for k, v in cpu.items():
                    s["cpu"][k] += v
                s["spr"].append(stats["samples"] / max(stats["rays"], 1))
                s["rays"].append(stats["rays"])
                s["rows"].extend([model.n_gaussians] if splatting else touched[touched_before:][:1])
                s["visible"].append(stats["samples"])
        finally:
            torch.autograd.backward = backward
            trainer_module.run_schedules = run_schedules
        res = [model.n_gaussians] if splatting else model.field.res
    stages = []
    for stage, s in sorted(by_stage.items()):
        n = s["steps"]
        stages.append(
            {
                "stage": stage,
                "steps": n,
                "ms_per_step": 1000 * float(np.mean(s["wall"])),
                "median_ms": 1000 * float(np.median(s["wall"])),
                "phases_ms": {k: 1000 * v / n for k, v in s["phases"].items()},
                "cpu_ms": {k: 1000 * v / n for k, v in s["cpu"].items()},
                "samples_per_ray": float(np.mean(s["spr"])),
                "rays": float(np.mean(s["rays"])),
                "touched_rows": float(np.mean(s["rows"])) if s["rows"] else 0.0,
                "visible": float(np.mean(s["visible"])),
            }
        )
    total_steps = sum(s["steps"] for s in stages)
    phases, cpu_ms = defaultdict(float), defaultdict(float)
    for s in stages:
        for k, v in s["phases_ms"].items():
            phases[k] += v * s["steps"] / total_steps
        for k, v in s["cpu_ms"].items():
            cpu_ms[k] += v * s["steps"] / total_steps
    return {
        "data": data,
        "model": model_name,
        "steps": steps,
        "from": start,
        "final_res": list(res),
        "ms_per_step": sum(s["ms_per_step"] * s["steps"] for s in stages) / total_steps,
        "median_ms": float(np.median([w for s in by_stage.values() for w in s["wall"]])),
        "phases_ms": dict(phases),
        "cpu_ms": dict(cpu_ms),
        "stages": stages,
        "loadavg": os.getloadavg(),
        "torch_threads": torch.get_num_threads(),
        "src": str(Path(trainer_module.__file__).resolve().parents[2]),
    }


def new_stage() -> dict:
    return {
        "steps": 0,
        "wall": [],
        "phases": defaultdict(float),
        "cpu": defaultdict(float),
        "spr": [],
        "rays": [],
        "rows": [],
        "visible": [],
    }


def table(results: list[tuple[str, dict]]) -> str:
    """Markdown: one row per phase, one column per result: wall ms per step (CPU ms)."""
    names = [n for n, _ in results]
    lines = ["| phase | " + " | ".join(f"{n}: wall (CPU) ms" for n in names) + " |", "|---|" + "---:|" * len(names)]
    phases = [p for p in ORDER if any(p in r["phases_ms"] for _, r in results)]
    for p in phases:
        cells = (f"{r['phases_ms'].get(p, 0.0):.1f} ({r['cpu_ms'].get(p, 0.0):.1f})" for _, r in results)
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    total = (f"**{r['ms_per_step']:.1f}** ({sum(r['cpu_ms'].values()):.1f})" for _, r in results)
    lines.append("| **step** | " + " | ".join(total) + " |")
    return "\n".join(lines)


def stage_lines(r: dict) -> list[str]:
    if r.get("model") == "splat":
        return [
            f"  SH degree {s['stage']}: {s['steps']} steps, {s['ms_per_step']:.1f} ms/step "
            f"(median {s['median_ms']:.1f}), {s['rays']:.0f} pixels, "
            f"{s['touched_rows']:.0f} Gaussians ({s['visible']:.0f} visible)"
            for s in r["stages"]
        ]
    return [
        f"  stage {s['stage']}: {s['steps']} steps, {s['ms_per_step']:.1f} ms/step (median {s['median_ms']:.1f}), "
        f"{s['rays']:.0f} rays, {s['samples_per_ray']:.1f} samples/ray, {s['touched_rows']:.0f} grid rows touched"
        for s in r["stages"]
    ]


def run_worker(src: str, args) -> dict:
    env = {**os.environ, "PYTHONPATH": str(Path(src).resolve())}
    cmd = [
        sys.executable,
        __file__,
        "--worker",
        "--data",
        args.data,
        "--steps",
        str(args.steps),
        "--from",
        str(args.start),
        "--model",
        args.model,
    ] + (["--points", args.points] if args.points else [])
    out = subprocess.run(cmd + ["--seed", str(args.seed)], env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"step_profile: the run on {src} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def load_file(path: Path, name: str):
    """The Python module in ``path``, imported as ``name`` (beside the one of the same file name in use)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None or not path.is_file():
        raise SystemExit(f"step_profile: cannot load {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # (numba's cache finds a module's globals by its name)
    spec.loader.exec_module(module)
    return module


def stage_medians(times: dict) -> list[dict]:
    """Per stage timed in both trees (``times[tree][stage]``: (wall s, CPU s) per step): the
    steps each tree took and the median wall and CPU ms of each, old first."""
    import numpy as np

    stages = []
    for stage in sorted(set(times["old"]) & set(times["new"])):
        o, n = np.array(times["old"][stage]), np.array(times["new"][stage])
        stages.append(
            {
                "stage": stage,
                "steps": [len(o), len(n)],
                "wall_ms": [1000 * float(np.median(o[:, 0])), 1000 * float(np.median(n[:, 0]))],
                "cpu_ms": [1000 * float(np.median(o[:, 1])), 1000 * float(np.median(n[:, 1]))],
            }
        )
    return stages


def interleaved(old_src: str, data: str, steps: int, seed: int) -> dict:
    """One training run of this tree whose steps take, each at random, the
    compiled grid kernels and the ray batch gathering of ``old_src`` or of this tree: the
    parts whose speed changed, which compute the same, so both halves train one model under
    the same load. Wall and CPU seconds of each step, by grid stage."""
    import hashlib

    import numpy as np

    from nerfkit import kernels, presets
    from nerfkit.data.npz import load_npz
    from nerfkit.data.rays import RaysData
    from nerfkit.models import model_config_class
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    old_kernels = load_file(Path(old_src) / "nerfkit" / "kernels" / "grid_numba.py", "step_profile_old_grid_numba")
    old_kernels.warm_up()
    old_rays = load_file(Path(old_src) / "nerfkit" / "data" / "rays.py", "nerfkit.data.step_profile_old_rays")
    new_kernels, new_batch = kernels.numba_kernels(), RaysData._batch
    parts = {"old": (old_kernels, old_rays.RaysData._batch), "new": (new_kernels, new_batch)}
    scene = load_npz(data)
    times: dict[str, dict[int, list]] = {"old": {}, "new": {}}
    losses = []
    with tempfile.TemporaryDirectory() as out:
        cfg = TrainConfig(data=data, model="fast", out=out, steps=steps, seed=seed, checkpoint_seconds=1e9)
        cfg, model_cfg = presets.resolve(cfg.validate(), model_config_class("fast")(), scene).configs()
        tr = Trainer(scene, cfg, model_cfg, quiet=True)
        tr.model.load_kernels()
        pick = np.random.default_rng(seed)  # (not a fixed pattern: the periodic refreshes would all fall to one side)
        try:
            while tr.step < steps:
                which = "old" if pick.random() < 0.5 else "new"
                kernels._STATE["module"], RaysData._batch = parts[which]
                stage, t, c = tr.model.stage, time.perf_counter(), time.process_time()
                losses.append(tr.train_step()["loss"])
                times[which].setdefault(stage, []).append((time.perf_counter() - t, time.process_time() - c))
                tr.step += 1
        finally:
            kernels._STATE["module"], RaysData._batch = parts["new"]
    stages = stage_medians(times)
    digest = hashlib.sha1(np.array(losses).tobytes()).hexdigest()[:16]
    return {"stages": stages, "loss_digest": digest, "loadavg": os.getloadavg()}


def interleaved_splat(old_src: str, data: str, points: str | None, steps: int, seed: int) -> dict:
    """:func:`interleaved` for the splat: one training run of this tree whose steps take, each
    at random, ``old_src``'s way of rendering and stepping (its ``splat_reference``,
    ``splat_numba`` and ``splat_ops`` modules, its ``SplatModel``'s ``render_view``, ``loss``
    and ``gradients_finite``, and the ``fused`` flag of its Adam groups) or this tree's.
    Wall and CPU seconds of each step, by SH degree."""
    import types

    import numpy as np

    from nerfkit import kernels, presets
    from nerfkit.models import model_config_class
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    old_dir = Path(old_src) / "nerfkit"
    # (named inside nerfkit's packages, so their relative imports resolve; the names they
    # take from this tree are pointed at the old tree's modules here)
    old_ref = load_file(old_dir / "kernels" / "splat_reference.py", "nerfkit.kernels.step_profile_old_splat_reference")
    old_nb = load_file(old_dir / "kernels" / "splat_numba.py", "step_profile_old_splat_numba")
    old_nb.warm_up()
    old_ops = load_file(old_dir / "kernels" / "splat_ops.py", "nerfkit.kernels.step_profile_old_splat_ops")
    old_ops.ref = old_ref
    old_model = load_file(old_dir / "models" / "splat.py", "nerfkit.models.step_profile_old_splat")
    old_model.ref, old_model.render_gaussians, old_model.ssim = old_ref, old_ops.render_gaussians, old_ops.ssim
    scene = load_scene(data, "splat", points)
    times: dict[str, dict[int, list]] = {"old": {}, "new": {}}
    methods = ("render_view", "loss", "gradients_finite")
    with tempfile.TemporaryDirectory() as out:
        cfg = TrainConfig(data=data, model="splat", out=out, steps=steps, seed=seed, checkpoint_seconds=1e9)
        cfg, model_cfg = presets.resolve(cfg.validate(), model_config_class("splat")(), scene).configs()
        tr = Trainer(scene, cfg, model_cfg, quiet=True)
        tr.model.load_kernels()
        model = tr.model
        fused = {
            "old": [g.get("fused") for g in old_model.SplatModel.param_groups(model, cfg.lr)],
            "new": [g.get("fused") for g in model.param_groups(cfg.lr)],
        }
        bound = {name: types.MethodType(getattr(old_model.SplatModel, name), model) for name in methods}
        new_nb = kernels.splat_kernels()
        pick = np.random.default_rng(seed)
        try:
            while tr.step < steps:
                which = "old" if pick.random() < 0.5 else "new"
                kernels._SPLAT["module"] = old_nb if which == "old" else new_nb
                for name in methods:
                    if which == "old":
                        setattr(model, name, bound[name])
                    else:
                        model.__dict__.pop(name, None)
                for group, flag in zip(tr.optimizer.param_groups, fused[which]):
                    group["fused"] = flag
                stage, t, c = model.active_degree, time.perf_counter(), time.process_time()
                tr.train_step()
                times[which].setdefault(stage, []).append((time.perf_counter() - t, time.process_time() - c))
                tr.step += 1
        finally:
            kernels._SPLAT["module"] = new_nb
        n = model.n_gaussians
    stages = stage_medians(times)
    return {"stages": stages, "gaussians": n, "loadavg": os.getloadavg()}


def median_result(runs: list[dict]) -> dict:
    keys = {k for r in runs for k in r["phases_ms"]}
    return {
        "ms_per_step": statistics.median(r["ms_per_step"] for r in runs),
        "phases_ms": {k: statistics.median(r["phases_ms"].get(k, 0.0) for r in runs) for k in keys},
        "cpu_ms": {k: statistics.median(r["cpu_ms"].get(k, 0.0) for r in runs) for k in keys},
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--data",
        default=str(LEGO),
        help="a scene .npz (default: the bundled lego 200x200) or an LLFF folder (as heldout.py trains flower)",
    )
    p.add_argument("--steps", type=int, default=1200, help="train this many steps (the 60-s run makes about 1200)")
    p.add_argument("--from", dest="start", type=int, default=0, help="time the steps after this one")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--model", default="fast", choices=["fast", "splat"], help="the model to train (its defaults)")
    p.add_argument(
        "--points",
        help="splat on an LLFF folder: an .npz of the points triangulated at its poses (written on first use)",
    )
    p.add_argument("--ab", nargs=2, metavar=("OLD_SRC", "NEW_SRC"), help="two source trees (their src/ folders)")
    p.add_argument("--repeats", type=int, default=3, help="with --ab: runs of each tree, alternating")
    p.add_argument(
        "--interleave",
        metavar="OLD_SRC",
        help="one run of this tree whose steps take at random OLD_SRC's compiled grid kernels and "
        "ray batches and this tree's (they must compute the same); medians per grid stage "
        "(--model splat: its torch reference and compiled rasterizer; medians per SH degree)",
    )
    p.add_argument("--json", help="write the results here")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        print(json.dumps(profile(args.data, args.steps, args.start, args.seed, args.model, args.points)))
        return 0
    if args.interleave:
        splatting = args.model == "splat"
        if splatting:
            results = interleaved_splat(args.interleave, args.data, args.points, args.steps, args.seed)
        else:
            results = interleaved(args.interleave, args.data, args.steps, args.seed)
        stage_name = "SH degree" if splatting else "grid stage"
        print(f"| {stage_name} | steps old + new | wall ms old / new (ratio) | CPU ms old / new (ratio) |")
        print("|---|---:|---|---|")
        for s in results["stages"]:
            (wo, wn), (co, cn) = s["wall_ms"], s["cpu_ms"]
            print(
                f"| {s['stage']} | {s['steps'][0]} + {s['steps'][1]} | {wo:.1f} / {wn:.1f} ({wo / wn:.3f}) | "
                f"{co:.1f} / {cn:.1f} ({co / cn:.3f}) |"
            )
        if splatting:
            print(f"{results['gaussians']} Gaussians at the end")
        else:
            print(f"losses digest {results['loss_digest']} (equal to a plain run's when old and new compute the same)")
        print(f"load average {results['loadavg'][0]:.2f}")
    elif not args.ab:
        r = profile(args.data, args.steps, args.start, args.seed, args.model, args.points)
        print(table([("ms/step", r)]))
        print("\n".join(stage_lines(r)))
        print(f"load average {r['loadavg'][0]:.2f}")
        results = {"run": r}
    else:
        runs: dict[str, list[dict]] = {"old": [], "new": []}
        for i in range(args.repeats):
            for name, src in zip(("old", "new"), args.ab):
                r = run_worker(src, args)
                runs[name].append(r)
                print(f"{name} {i + 1}: {r['ms_per_step']:.1f} ms/step (load {r['loadavg'][0]:.2f})", file=sys.stderr)
        old, new = median_result(runs["old"]), median_result(runs["new"])
        print(table([("old (median)", old), ("new (median)", new)]))
        ratios = [a["ms_per_step"] / b["ms_per_step"] for a, b in zip(runs["old"], runs["new"])]
        print(
            f"step time old / new: {old['ms_per_step'] / new['ms_per_step']:.3f} (medians); "
            f"per pair {', '.join(f'{x:.3f}' for x in ratios)}"
        )
        for name in ("old", "new"):
            print(name)
            print("\n".join(stage_lines(runs[name][0])))
        results = {"runs": runs, "old": old, "new": new, "ratios": ratios}
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
