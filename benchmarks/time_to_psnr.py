"""Held-out PSNR against training time, ``vanilla`` vs ``fast``, under the same budgets.

    python benchmarks/time_to_psnr.py OUT [--data src/nerfkit/assets/lego_200x200.npz] [--budgets 10,60,600]

For every model and every budget B (seconds of training, evaluation excluded) one fresh
run trains with ``--minutes B/60`` exactly as ``nerfkit train`` would (its learning-rate
schedule spans the budget) and is scored on all validation views: that is "PSNR after B
seconds". The longest run of each model is also evaluated at fixed times on the way, for
the curve. Each run is a separate process, so its peak memory (max RSS) is its own.

Writes ``OUT/results.json``, ``OUT/table.md`` and ``OUT/psnr_vs_time.png``; run folders go
to ``OUT/runs/``. Also recorded: training samples per second, process CPU seconds spent
in training steps (the machine may be shared: compare CPU and wall seconds), seconds to
render one validation frame, the load average, and the compiled kernels' warm-up time
(with the on-disk cache, and cold into an empty cache).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import typing
from pathlib import Path

from nerfkit.config import base_type

CURVE_TIMES = [2, 5, 10, 20, 30, 45, 60, 90, 120, 180, 240, 300, 420, 600, 900, 1200]


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", help="output folder")
    lego = Path(__file__).resolve().parents[1] / "src" / "nerfkit" / "assets" / "lego_200x200.npz"
    p.add_argument("--data", default=str(lego))
    p.add_argument("--models", default="fast,vanilla", help="comma-separated model names")
    p.add_argument("--budgets", default="10,60,600", help="training seconds, comma-separated")
    p.add_argument(
        "--curve-views",
        type=int,
        default=0,
        help="validation views per evaluation on the curve (0: all for fast, 2 for vanilla)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-cold-compile", action="store_true", help="skip timing a cold numba compile")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a model or training option for every run (repeatable), e.g. --set upsample_steps=60,300,1000",
    )
    # internal: one training run in this process
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--model", help=argparse.SUPPRESS)
    p.add_argument("--seconds", type=float, help=argparse.SUPPRESS)
    p.add_argument("--eval-at", default="", help=argparse.SUPPRESS)
    p.add_argument("--eval-views", type=int, default=0, help=argparse.SUPPRESS)
    return p.parse_args(argv)


def worker(args) -> dict:
    """Train one model for one budget in this process and return its figures."""
    import numpy as np
    import torch

    from nerfkit import presets
    from nerfkit.data.npz import load_npz
    from nerfkit.models import model_config_class
    from nerfkit.output.images import render_image
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    warmup = None
    if args.model == "fast":
        from nerfkit.kernels import kernel_status

        warmup = kernel_status()
    scene = load_npz(args.data)
    eval_at = [float(s) for s in args.eval_at.split(",") if s]
    model_cfg = model_config_class(args.model)()
    run_dir = Path(args.out)
    cfg = TrainConfig(
        data=args.data,
        model=args.model,
        out=str(run_dir),
        minutes=args.seconds / 60.0,
        seed=args.seed,
        eval_views=args.eval_views or len(scene.val),
        checkpoint_seconds=1e9,
    )
    overrides(args.set, model_cfg, cfg)
    cfg, model_cfg = presets.resolve(cfg.validate(), model_cfg, scene).configs()  # the defaults `nerfkit train` picks

    class TimedTrainer(Trainer):
        """Evaluates at the given training seconds; counts samples and CPU time."""

        samples = 0
        rays_drawn = 0
        cpu_seconds = 0.0
        _next = 0

        def _eval_due(self) -> bool:
            due = False
            while self._next < len(eval_at) and self.train_seconds >= eval_at[self._next]:
                self._next += 1
                due = True
            return due

        def train_step(self) -> dict:
            c = time.process_time()
            stats = super().train_step()
            self.cpu_seconds += time.process_time() - c
            self.samples += int(stats["samples"])
            self.rays_drawn += int(stats["rays"])
            return stats

    load_before = os.getloadavg()
    trainer = TimedTrainer(scene, cfg, model_cfg, quiet=True)
    result = trainer.run()
    # rendering speed: one warm-up frame, then the mean of three
    bg = trainer.background
    view = lambda i: render_image(
        trainer.model,
        scene.val.K[i],
        scene.val.c2w[i],
        scene.val.width,  # noqa: E731
        scene.val.height,
        bg,
        cfg.render_chunk,
        trainer.autocast,
    )
    view(0)
    t = time.perf_counter()
    n_frames = min(3, len(scene.val))
    for i in range(n_frames):
        view(i)
    render_s = (time.perf_counter() - t) / n_frames
    val = [r for r in result.rows if r["split"] == "val"]
    return {
        "model": args.model,
        "budget_s": args.seconds,
        "steps": result.step,
        "train_s": result.train_seconds,
        "train_cpu_s": trainer.cpu_seconds,
        "final_val_psnr": result.final_val_psnr,
        "samples": trainer.samples,
        "samples_per_s": trainer.samples / max(result.train_seconds, 1e-9),
        "render_s_per_frame": render_s,
        "frame": [scene.val.width, scene.val.height],
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "curve": [{"seconds": r["seconds"], "psnr": r["psnr"], "views": r.get("views")} for r in val],
        "kernels": warmup,
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(),
        "batch_rays": cfg.batch_rays,
        "mean_rays_per_step": trainer.rays_drawn / max(result.step, 1),
        "precision": cfg.precision,
        "torch_threads": torch.get_num_threads(),
        "model_config": {k: v for k, v in vars(model_cfg).items()},
        "val_views": len(scene.val),
        "mean_val_psnr_check": float(np.mean([r["psnr"] for r in val[-1:]])) if val else None,
    }


def overrides(pairs: list[str], model_cfg, train_cfg) -> None:
    """Apply ``NAME=VALUE`` pairs to the model config (first) or the training config."""
    for pair in pairs:
        name, sep, value = pair.partition("=")
        target = next((c for c in (model_cfg, train_cfg) if sep and hasattr(c, name)), None)
        if target is None:
            raise SystemExit(f"--set {pair}: expected NAME=VALUE with NAME an option of the model or of training")
        kind, _ = base_type(typing.get_type_hints(type(target))[name])  # X for X | None
        setattr(target, name, (value.lower() in ("1", "true", "yes")) if kind is bool else kind(value))


def cold_compile_seconds() -> float | None:
    """Warm-up time of the compiled kernels with an empty numba cache (a first run)."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        code = "from nerfkit.kernels import kernel_status; import json; print(json.dumps(kernel_status()))"
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    if out.returncode != 0:
        return None
    status = json.loads(out.stdout.strip().splitlines()[-1])
    return status["warmup_seconds"] if status["numba"] else None


def write_table(results: list[dict], extra: dict, path: Path) -> None:
    lines = [
        "| model | budget (s) | steps | rays / step | val PSNR (dB) | train CPU s | Msamples/s | render s/frame "
        "| peak RSS (MB) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        lines.append(
            f"| {r['model']} | {r['budget_s']:g} | {r['steps']} | {r.get('mean_rays_per_step', 0):.0f} | "
            f"{r['final_val_psnr']:.2f} | "
            f"{r['train_cpu_s']:.0f} | {r['samples_per_s'] / 1e6:.2f} | {r['render_s_per_frame']:.3f} | "
            f"{r['peak_rss_mb']:.0f} |"
        )
    lines += [
        "",
        f"PSNR on all {results[0]['val_views']} held-out validation views, "
        f"{results[0]['frame'][0]}x{results[0]['frame'][1]}; training seconds exclude evaluation.",
    ]
    for k, v in extra.items():
        lines.append(f"- {k}: {v}")
    path.write_text("\n".join(lines) + "\n")


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, model in enumerate(sorted({r["model"] for r in results})):
        runs = sorted((r for r in results if r["model"] == model), key=lambda r: r["budget_s"])
        colour = f"C{i}"
        longest = runs[-1]
        pts = [(c["seconds"], c["psnr"]) for c in longest["curve"] if c["seconds"] > 0]
        if pts:
            label = f"{model}: during the {longest['budget_s']:g} s run"
            ax.plot(*zip(*pts), "-", color=colour, alpha=0.6, label=label)
        ax.plot(
            [r["budget_s"] for r in runs],
            [r["final_val_psnr"] for r in runs],
            "o",
            color=colour,
            ms=7,
            label=f"{model}: run with that budget",
        )
    ax.set_xscale("log")
    ax.set_xlabel("training seconds (evaluation excluded)")
    ax.set_ylabel("held-out PSNR (dB)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("lego 200x200, validation views")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.worker:
        res = worker(args)
        Path(args.out, "result.json").write_text(json.dumps(res, indent=1))
        return 0
    out = Path(args.out)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    budgets = sorted(float(b) for b in args.budgets.split(","))
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    results = []
    for model in models:
        for budget in budgets:
            run = out / "runs" / f"{model}_{budget:g}s"
            if (run / "result.json").exists():  # finished earlier: keep it (delete to redo)
                results.append(json.loads((run / "result.json").read_text()))
                continue
            if run.exists():
                import shutil

                shutil.rmtree(run)
            eval_at = [t for t in CURVE_TIMES if t < budget] if budget == budgets[-1] else []
            views = args.curve_views or (2 if model == "vanilla" else 0)
            cmd = [
                sys.executable,
                __file__,
                str(run),
                "--worker",
                "--model",
                model,
                "--seconds",
                str(budget),
                "--data",
                args.data,
                "--seed",
                str(args.seed),
                "--eval-at",
                ",".join(map(str, eval_at)),
                "--eval-views",
                str(views),
            ] + [f"--set={x}" for x in args.set]
            print(f"{model}: {budget:g} s ...", flush=True)
            subprocess.run(cmd, check=True)
            r = json.loads((run / "result.json").read_text())
            print(
                f"  {r['steps']} steps ({r.get('mean_rays_per_step', 0):.0f} rays each), "
                f"val PSNR {r['final_val_psnr']:.2f} dB, {r['samples_per_s'] / 1e6:.2f} M samples/s, "
                f"render {r['render_s_per_frame']:.3f} s/frame",
                flush=True,
            )
            results.append(r)
    extra = {
        "load average (1, 5, 15 min) at the start of each run": sorted(
            {tuple(round(x, 1) for x in r["loadavg_before"]) for r in results}
        ),
        "CPU": f"{os.cpu_count()} logical cores",
    }
    fast = [r for r in results if r["model"] == "fast" and r.get("kernels")]
    if fast:
        extra["fast kernels warm-up with the numba cache (s)"] = round(fast[0]["kernels"]["warmup_seconds"], 2)
        if not args.no_cold_compile:
            cold = cold_compile_seconds()
            extra["fast kernels first compile, empty cache (s)"] = None if cold is None else round(cold, 1)
    (out / "results.json").write_text(json.dumps({"runs": results, "notes": extra}, indent=1))
    write_table(results, extra, out / "table.md")
    plot(results, out / "psnr_vs_time.png")
    print((out / "table.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
