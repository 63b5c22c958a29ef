"""The training loop: rays in, Adam steps, evaluations, checkpoints, plots.

The trainer never does camera math or sampling; it asks the model to render a batch of
rays (see :mod:`nerfkit.models.base`) and keeps the run folder up to date.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .. import presets
from ..cameras import Rays
from ..data.load import dataset_inputs
from ..data.rays import RaysData
from ..data.scene import Scene
from ..errors import NerfkitError, fail
from ..io import stop
from ..io.lock import left_by_others
from ..io.paths import guard_run_folder
from ..models import SceneBounds, build_model, check_config
from ..models.base import NerfModel, StepState, grads_finite, run_schedules
from ..precision import autocast, resolve_device, resolve_precision
from ..render.output import RenderOutput
from .checkpoint import (
    MODEL_FILE,
    RunInfo,
    check_dataset,
    checkpoint_paths,
    read_run,
    run_lock,
    save_checkpoint,
    save_model,
    scene_record,
    write_run_config,
)
from .config import MAX_BATCH_RAYS, TrainConfig, parse_background
from .evaluate import score_val_views
from .metrics import psnr_from_mse
from .optim import build_optimizer, decay_lr
from .progress import marks_reached, run_length, run_progress
from .reports import PSNR_WINDOW, eval_rows, scored_at, train_row, write_metrics, write_plots, write_view_corrections
from .resume import (
    load_for_resume,
    precision_name,
    psnr_window,
    restore_rng,
    restore_views,
    resumed_precision,
    rng_state,
)
from .sight_lines import SIGHT_LINES_PER_STEP, SightLines, sight_lines_note
from .view_corrections import PoseCorrection, ViewAdam, build_view_corrections

# Stop after this many consecutive steps with a non-finite loss or gradient.
MAX_BAD_STEPS = 20


@dataclass
class TrainResult:
    run_dir: Path
    step: int
    train_seconds: float
    final_val_psnr: float | None
    interrupted: bool = False
    rows: list[dict] = field(default_factory=list)


class Trainer:
    """Trains one model on one scene into one run folder (new, or resumed)."""

    def __init__(self, scene: Scene, cfg: TrainConfig, model_config, resume: bool = False, quiet: bool = False):
        if not scene.train.has_images:
            raise fail(scene.source, "has no training images")
        self.scene, self.cfg, self.quiet = scene, cfg, quiet
        self.run_dir = Path(cfg.out)
        self.device = resolve_device(cfg.device)
        self.autocast = resolve_precision(cfg.precision, self.device)
        self.background = torch.tensor(parse_background(cfg.background), dtype=torch.float32, device=self.device)
        torch.manual_seed(cfg.seed)
        # NDC for the forward-facing kind the run resolved (with --capture on or off too); a
        # trainer built without resolving (cfg.preset auto) follows the dataset
        ndc = None if cfg.preset == "auto" else cfg.preset == presets.FORWARD_FACING
        self.bounds = SceneBounds.from_scene(scene, ndc) if not resume else read_run(self.run_dir).bounds
        # a resumed run with no checkpoint yet (stopped before its first) starts as a new one does
        fresh = not resume or not checkpoint_paths(self.run_dir)
        self.model: NerfModel = build_model(cfg.model, model_config, self.bounds).to(self.device)
        self.model.set_precision(self.autocast)  # resolved once, above; the model uses it, never its own
        # models that render whole views (splat) train on one view per step, posed by its corrected camera
        self.whole_images = self.model.whole_images
        if fresh:
            note = self.model.init_from_scene(scene, self.background, self.run_dir)
            if note:
                self.log(note)
        self.optimizer = build_optimizer(self.model, cfg.lr)
        self.schedules = self.model.schedules()
        self.rays = RaysData(scene.train, self.device, seed=cfg.seed)
        # the sparse points' sight lines, when the dataset records who saw them and the model weighs them
        sight = self.model.uses_sight_lines
        self.sight = SightLines.from_scene(scene, self.device) if sight and not self.whole_images else None
        self.sight_generator = torch.Generator().manual_seed(cfg.seed + 1)
        note = sight_lines_note(scene, self.sight, sight) if fresh else None
        if note:
            self.log(note)
        on = cfg.capture == "on"
        self.views, self.view_optimizer = build_view_corrections(
            len(scene.train),
            self.bounds.radius,
            cfg.pose_lr if on else 0.0,
            cfg.exposure_lr if on else 0.0,
            cfg.colour_mix,
            self.whole_images,  # one view per step: only its corrections step (ViewAdam)
            self.device,
        )
        self._remember_initial_lr()
        self.step = 0
        self.train_seconds = 0.0
        self.rows: list[dict] = []
        self.notes: list[str] = []  # the model's notes at the end of training (metrics.json)
        self.bad_steps = 0
        self.train_psnr: list[float] = []  # the last steps' PSNR, averaged in the metrics' train rows
        self._marks_passed = 0
        if resume:
            self._resume()
        else:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            write_run_config(self.run_dir, cfg, model_config, self.bounds, scene_record(scene))

    # -- state ---------------------------------------------------------------------
    def _param_groups(self) -> list[dict]:
        """Every optimizer parameter group: the model's, then the per-view corrections'."""
        groups = list(self.optimizer.param_groups)
        if self.view_optimizer is not None:
            groups += self.view_optimizer.param_groups
        return groups

    def _remember_initial_lr(self) -> None:
        for g in self._param_groups():
            g.setdefault("initial_lr", g["lr"])

    def refresh_appearance(self) -> None:
        """The model's colour by view direction from the training photos' current colour
        corrections (:class:`~nerfkit.models.appearance.DirectionalColour`), for the renders of
        new views and the files saved; none without them."""
        views = self.views
        self.model.appearance = (
            None if views is None else views.directional_colour(self.scene.train.c2w, self.scene.center)
        )

    def save(self) -> Path:
        self.refresh_appearance()
        extra = {
            **rng_state(self.rays, self.sight_generator, self.device),
            "train_seconds": self.train_seconds,
            "rows": json.dumps(self.rows),
            "bad_steps": self.bad_steps,
            "train_psnr": list(self.train_psnr),
            "precision": precision_name(self.autocast),
            "training_state": self.model.training_state(),
        }
        if self.views is not None:
            assert self.view_optimizer is not None  # (built with the views)
            extra["views"] = self.views.state_dict()
            extra["views_optimizer"] = self.view_optimizer.state_dict()
        return save_checkpoint(self.run_dir, self.step, self.model, self.optimizer, extra, self.cfg.keep_checkpoints)

    def _resume(self) -> None:
        """Go on from the run's newest good checkpoint (:mod:`nerfkit.train.resume`), or from
        step 0 when it has none yet."""
        loaded = load_for_resume(self.run_dir, self.model, self.device)
        if loaded is None:
            self.log(f"{self.run_dir}: no checkpoint yet, starting from step 0")
            return
        ckpt, path = loaded
        self.optimizer = build_optimizer(self.model, self.cfg.lr)
        self.optimizer.load_state_dict(ckpt["optimizer"])
        self._remember_initial_lr()
        self.step = int(ckpt["step"])
        self.train_seconds = float(ckpt["train_seconds"])
        self.rows = json.loads(ckpt["rows"])
        self.bad_steps = int(ckpt.get("bad_steps", 0))
        self.train_psnr = psnr_window(ckpt.get("train_psnr"))
        self.autocast, warning = resumed_precision(ckpt.get("precision"), self.autocast, self.device)
        self.model.set_precision(self.autocast)
        if warning:
            print(f"warning: {self.run_dir}: {warning}", file=sys.stderr)
        self._marks_passed = marks_reached(self.progress())  # validated there before the stop
        if self.views is not None:
            restore_views(ckpt, path, self.views, self.view_optimizer)
        restore_rng(ckpt, self.rays, self.sight_generator, self.device)
        self.log(f"resumed from {path.name} (step {self.step}, {self.train_seconds:.0f} s trained)")

    # -- schedule ------------------------------------------------------------------
    def progress(self) -> float:
        """Fraction of the run done, by steps or by training time, whichever is further."""
        return run_progress(self.step, self.train_seconds, self.cfg.steps, self.cfg.minutes)

    def done(self) -> bool:
        return self.progress() >= 1.0

    def run_steps(self) -> float | None:
        """The run's length in steps (:func:`~nerfkit.train.progress.run_length`)."""
        return run_length(self.step, self.train_seconds, self.cfg.steps, self.cfg.minutes)

    def _set_lr(self) -> None:
        decay_lr(self._param_groups(), self.progress(), self.run_steps(), self.cfg.lr_final_factor)

    def _eval_due(self) -> bool:
        """Every ``--eval-every`` steps; without it each time the run passes one of
        :data:`~nerfkit.train.progress.EVAL_MARKS`."""
        if self.cfg.eval_every:
            return self.step % self.cfg.eval_every == 0
        passed = marks_reached(self.progress())
        due = passed > self._marks_passed
        self._marks_passed = passed
        return due

    # -- one step ------------------------------------------------------------------
    def train_step(self) -> dict:
        state = StepState(self.step, self.progress(), self.optimizer)
        # (a job that installs new parameters swaps them into the optimizer itself)
        for note in run_schedules(self.schedules, state, phase="before_step"):
            self.log(f"step {self.step}: {note}")
        self._set_lr()
        out, target, loss, rays, seen = self._forward()
        self._zero_grad()
        if not self._backward(loss):
            self._zero_grad()
            self._bad_step("non-finite loss or gradient, step skipped")
            return {"loss": float("nan"), "psnr": float("nan"), "samples": 0, "rays": 0}
        after = replace(state, optimizer=self.optimizer, rays=rays, out=out if rays is not None else None)
        run_schedules(self.schedules, after, phase="gradients")
        self._step_optimizers(seen)
        for note in run_schedules(self.schedules, after, phase="after_step"):
            self.log(f"step {self.step}: {note}")
        mse = float(torch.mean((out.rgb.detach().float() - target) ** 2))
        n_rays = target.numel() // 3  # (a whole view: its pixels)
        return {"loss": float(loss.detach()), "psnr": psnr_from_mse(mse), "samples": out.n_samples, "rays": n_rays}

    def _forward(self) -> tuple[RenderOutput, Tensor, Tensor, Rays | None, Tensor | None]:
        """This step's render, its target and loss; the rays of a ray batch (None for a whole
        view) and the view a whole-view step rendered (None for a ray batch)."""
        if self.whole_images:
            out, target, seen = self._render_training_view()
            return out, target, self.model.loss(out, target) + self._corrections_penalty(), None, seen
        views = self.views
        batch = self.rays.sample(min(self.model.rays_per_step(self.cfg.batch_rays), MAX_BATCH_RAYS))
        rays = batch.rays
        pose = self._pose_correction()
        if pose is not None:
            rays = pose(rays, batch.image_index)
        with autocast(self.device, self.autocast):
            out = self.model.render_rays(rays, self.background, perturb=True)
            if views is not None and views.exposure is not None:
                out = replace(out, rgb=views.exposure(out.rgb.float(), batch.image_index))
            shape = (self.rays.n_images, self.rays.width, self.rays.height)
            self.model.see_batch(self.progress(), batch.image_index, batch.uv, shape)
            loss = self.model.loss(out, batch.rgb) + self._corrections_penalty() + self._sight_term()
        return out, batch.rgb, loss, rays, None

    def _backward(self, loss: Tensor) -> bool:
        """Backpropagate ``loss``; False when it or a gradient is not finite."""
        if not bool(torch.isfinite(loss)):
            return False
        loss.backward()
        views = self.views
        return self.model.gradients_finite() and (views is None or grads_finite(views.parameters()))

    def _step_optimizers(self, seen: Tensor | None) -> None:
        """Step the scene's optimizer and the views' (only the rendered view's rows for a
        whole-view step); grid rows the optimizer refused count as a bad step."""
        self.optimizer.step()
        if isinstance(self.view_optimizer, ViewAdam):
            self.view_optimizer.step(rows=seen)
        elif self.view_optimizer is not None:
            self.view_optimizer.step()
        skipped = getattr(self.optimizer, "nonfinite_rows", 0)
        if skipped:
            self._bad_step(f"{skipped} grid rows had non-finite gradients and were not updated")
        else:
            self.bad_steps = 0

    def _pose_correction(self) -> PoseCorrection | None:
        """The per-view pose correction once it applies (from ``--pose-start`` on), else None."""
        views = self.views
        return views.pose if views is not None and self.step >= self.cfg.pose_start else None

    def _sight_term(self) -> Tensor | float:
        """The sparse points' sight lines in the loss (the model's ``sight_loss``), each
        from its view's corrected camera; 0 without them."""
        if self.sight is None:
            return 0.0
        rays, distance, view = self.sight.sample(SIGHT_LINES_PER_STEP, self.sight_generator, self.model.sight_spread())
        pose = self._pose_correction()
        if pose is not None:
            with torch.no_grad():  # the lines follow the poses; they do not move them
                rays = pose(rays, view)
        term = self.model.sight_loss(rays, distance)
        return 0.0 if term is None else term

    def _corrections_penalty(self) -> Tensor | float:
        """The per-view corrections' regulariser (the colour mixing's), 0 without them."""
        exposure = self.views.exposure if self.views is not None else None
        return 0.0 if exposure is None else self.cfg.colour_mix_weight * exposure.mix_penalty()

    def _render_training_view(self):
        """One random training view rendered whole (fp32) from its corrected camera once
        poses are corrected: ``(out, target (H, W, 3), view (1,) long)``."""
        i = int(torch.randint(self.rays.n_images, (1,), generator=self.rays.generator))
        h, w = self.rays.height, self.rays.width
        target = self.rays.images[i].float() / 255.0
        c2w = self.rays.c2w[i]
        pose = self._pose_correction()
        if pose is not None:
            c2w = pose.camera(c2w, i)
        out = self.model.render_view(self.rays.K[i], c2w, w, h, self.background)
        if self.views is not None and self.views.exposure is not None:
            index = torch.full((h * w,), i, dtype=torch.long, device=self.device)
            out = replace(out, rgb=self.views.exposure(out.rgb.reshape(-1, 3), index).reshape(h, w, 3))
        return out, target, torch.tensor([i], device=self.device)

    def _zero_grad(self) -> None:
        self.optimizer.zero_grad(set_to_none=True)
        if self.view_optimizer is not None:
            self.view_optimizer.zero_grad(set_to_none=True)

    def _bad_step(self, what: str) -> None:
        """Report a step with non-finite values; stop after MAX_BAD_STEPS in a row."""
        self.bad_steps += 1
        self.log(f"step {self.step}: {what} ({self.bad_steps} in a row)")
        if self.bad_steps >= MAX_BAD_STEPS:
            fix = (
                "The last good checkpoint is kept; lower --lr and resume with --resume"
                if checkpoint_paths(self.run_dir)
                else "No checkpoint was written yet; start again with a lower --lr into a new --out"
            )
            raise fail(self.run_dir, f"training diverged: {self.bad_steps} steps in a row had non-finite values", fix)

    # -- evaluation ------------------------------------------------------------------
    def evaluate(self, n_views: int | None = None) -> tuple[list[float], int] | None:
        """PSNR of each of the first ``n_views`` validation images (None: all, whole) and the
        pixels scored per view (:func:`~nerfkit.train.evaluate.score_val_views`)."""
        self.refresh_appearance()
        cfg = self.cfg
        first = self.run_dir / "progress" / f"step_{self.step:08d}.png"
        return score_val_views(
            self.model,
            self.scene.val,
            n_views,
            self.background,
            cfg.render_chunk,
            self.autocast,
            cfg.eval_pixels,
            first,
        )

    # -- the loop ------------------------------------------------------------------
    def log(self, msg: str) -> None:
        if not self.quiet:
            from tqdm import tqdm

            tqdm.write(msg, file=sys.stderr)

    def run(self, stop_after: int | None = None) -> TrainResult:
        """Train until the stopping rule (or Ctrl-C / SIGTERM, or step ``stop_after``), then save."""
        with stop.signals_caught() as interrupted:  # until all is saved: a second Ctrl-C must not cut it short
            bar = self._start()
            try:
                self._loop(bar, stop_after, interrupted)
                self.save()
                save_model(self.run_dir, self.step, self.model)
                self.write_reports()
            finally:
                bar.close()
        if interrupted():
            self.log(
                f"interrupted: checkpoint saved at step {self.step}; continue with "
                f"`nerfkit train --resume {self.run_dir}`"
            )
            if self.result().final_val_psnr is None and len(self.scene.val):
                self.log(
                    f"the model saved at step {self.step} was not evaluated (no val PSNR is reported): "
                    f"`nerfkit eval {self.run_dir}` scores it"
                )
        return self.result(interrupted())

    def _start(self):
        """Load the model's kernels (saying so when they took long: compiled) and open the
        progress bar."""
        from tqdm import tqdm

        start = time.perf_counter()
        self.model.load_kernels()
        loading = time.perf_counter() - start
        if loading > 5.0:
            self.log(f"compiled the kernels in {loading:.0f} s (once: later runs load them from numba's cache)")
        return tqdm(
            total=self.cfg.steps if self.cfg.steps else None,
            initial=self.step,
            desc=f"train {self.cfg.model}",
            unit="step",
            dynamic_ncols=True,
            disable=self.quiet,
            file=sys.stderr,
            mininterval=1.0 if sys.stderr.isatty() else 30.0,
        )  # sparse updates in log files

    def result(self, interrupted: bool = False) -> TrainResult:
        """The run so far; its val PSNR only from an evaluation of the current step (one of
        an earlier step, before an interrupt, is not the saved model's)."""
        final = [r for r in self.rows if r["split"] == "val" and r["step"] == self.step]
        return TrainResult(
            self.run_dir, self.step, self.train_seconds, final[-1]["psnr"] if final else None, interrupted, self.rows
        )

    def _loop(self, bar, stop_after: int | None, interrupted) -> None:
        """The training steps, with their metrics, evaluations and periodic checkpoints, until
        the stopping rule, ``interrupted()`` or step ``stop_after``."""
        last_ckpt = time.perf_counter()
        start = self.step
        if self.step == 0:
            self._record_eval()
        while not self.done() and not interrupted() and (stop_after is None or self.step < stop_after):
            t0 = time.perf_counter()
            stats = self.train_step()
            if self.device.type == "cuda":
                torch.cuda.synchronize(self.device)
            self.train_seconds += time.perf_counter() - t0
            self.step += 1
            if math.isfinite(stats["psnr"]):
                self.train_psnr = [*self.train_psnr, float(stats["psnr"])][-PSNR_WINDOW:]
            if self.step % 10 == 0 or self.done():
                window = float(np.mean(self.train_psnr or [float("nan")]))
                self.rows.append(train_row(self.step, self.train_seconds, stats["loss"], window, stats["rays"]))
            bar.update(1)
            bar.set_postfix(
                loss=f"{stats['loss']:.4f}",
                psnr=f"{stats['psnr']:.2f}",
                rays=stats["rays"],
                spr=f"{stats['samples'] / max(stats['rays'], 1):.0f}",
                refresh=False,
            )
            if self.cfg.minutes and not self.cfg.steps:
                bar.set_description(
                    f"train {self.cfg.model} {self.train_seconds:.0f}/{60 * self.cfg.minutes:.0f}s", refresh=False
                )  # redraws follow the bar's own interval
            if self._eval_due() or self.done():
                self._record_eval()
            if time.perf_counter() - last_ckpt >= self.cfg.checkpoint_seconds:
                self.save()
                last_ckpt = time.perf_counter()
        if self.step == start and self.done():  # resumed at its end: the final evaluation, unless made
            self._record_eval()

    def _record_eval(self) -> None:
        """Evaluate this step, unless it was (periodic: the first ``--eval-views`` val views,
        none with 0; at the run's end every view, whole, after the model's last notes)."""
        final = self.done()
        if scored_at(self.rows, self.step, self.scene.val, final) or (not final and self.cfg.eval_views == 0):
            return
        if final:
            self.notes = list(self.model.finish_training())
            for note in self.notes:
                self.log(f"note: {note}")
        scored = self.evaluate(None if final else self.cfg.eval_views)
        if scored is None:
            return
        rows, message = eval_rows(
            self.step, self.train_seconds, *scored, final, self.scene.val, self.cfg.eval_views, self.cfg.eval_pixels
        )
        self.rows += rows
        self.log(message)

    def write_reports(self) -> None:
        """metrics.csv/json, view_corrections.json when the run learns a correction per
        training view, and the plots (:mod:`nerfkit.train.reports`)."""
        write_metrics(self.run_dir, self.rows, self.step, self.train_seconds, self.done(), self.notes)
        if self.views is not None:
            write_view_corrections(self.run_dir, self.views.report(self.scene.train.names))
        write_plots(self.run_dir, self.rows, self.cfg.model, self.scene.val)


def train(scene: Scene, cfg: TrainConfig, model_config, quiet: bool = False, user_set=None) -> TrainResult:
    """Train a new run (``cfg.out`` is created; an existing run, or a folder of other files, is refused).
    The options not in ``user_set`` (the names of those the user gave; None: those that differ
    from their defaults) take the scene kind's settings (:func:`nerfkit.presets.resolve`)."""
    run_dir = Path(cfg.out)
    check_new_run_folder(run_dir)
    if cfg.data:
        guard_run_folder(run_dir, cfg.data, dataset_inputs(cfg.data))  # never among its data: eval would write there
    resolved = presets.resolve(cfg.validate(), model_config, scene, user_set)
    cfg, model_config = resolved.train, resolved.model
    if cfg.data:
        cfg = replace(cfg, data=str(Path(cfg.data).resolve()))  # eval and --resume must find it from any folder
    # what the trainer would refuse at start (the device, the model's settings), before --out is made
    device = resolve_device(cfg.device)
    resolve_precision(cfg.precision, device)
    check_config(cfg.model, model_config, device)
    with run_lock(run_dir):
        check_new_run_folder(run_dir)  # again, holding the lock: another process may have just started
        trainer = Trainer(scene, cfg, model_config, quiet=quiet)
        for note in resolved.notes:
            trainer.log(f"note: {note}")
        return trainer.run()


def check_new_run_folder(run_dir: Path) -> None:
    """A new run goes into a new or empty folder, never over another run or the user's files."""
    if (run_dir / "config.json").exists():
        raise fail(run_dir, "already holds a run", "Continue it with --resume, or choose another --out")
    if run_dir.is_file():
        raise fail(run_dir, "is a file", "--out names the run folder to create")
    if run_dir.is_dir() and left_by_others(run_dir):
        raise fail(run_dir, "holds files that are not a nerfkit run", "Choose a new or empty --out")


def resume(
    run_dir: str | Path,
    scene: Scene,
    steps: int | None = None,
    minutes: float | None = None,
    quiet: bool = False,
    changes: dict | None = None,
    data: str | Path | None = None,
) -> TrainResult:
    """Continue a run from its newest good checkpoint (optionally with a new stopping rule,
    and the TrainConfig fields in ``changes``) on the dataset it was trained on; ``data``:
    where that dataset is now (recorded in config.json once ``scene`` passes the check)."""
    with run_lock(run_dir):
        info = read_run(run_dir)
        check_dataset(info, scene)
        moved = _record_moved_data(run_dir, info, scene, data)  # written below, once the resume is not refused
        cfg = info.train
        if steps is not None:
            cfg.steps = steps
        if minutes is not None:
            cfg.minutes = minutes
        for key, value in (changes or {}).items():
            setattr(cfg, key, value)
        cfg.out = str(run_dir)
        trainer = Trainer(scene, cfg.validate(), info.model_config, resume=True, quiet=quiet)
        finished = _finished_at(Path(run_dir), trainer.step)
        if cfg.steps and trainer.step > cfg.steps and not finished:
            raise fail(
                "--steps",
                f"{cfg.steps} is below step {trainer.step}, which run {run_dir} has reached",
                f"Pass --steps {trainer.step} to end it there (with its final evaluation), or more to go on",
            )
        if moved is not None:  # the dataset's new path, for later commands
            write_run_config(Path(run_dir), moved, info.model_config, info.bounds, info.scene)
        if trainer.done() and finished:  # changes nothing, config.json included
            trainer.log(f"{run_dir}: {_nothing_more(trainer)}")
            return trainer.result()
        # the run's config records the stopping rule (and the settings) it now goes on with
        write_run_config(Path(run_dir), trainer.cfg, info.model_config, info.bounds, info.scene)
        return trainer.run()


def _record_moved_data(run_dir: str | Path, info: RunInfo, scene: Scene, data: str | Path | None) -> TrainConfig | None:
    """When ``data`` (the dataset's path now, if given) is not the path the run recorded:
    ``info`` takes it (and ``scene``'s source) and a copy of its TrainConfig is returned, for
    config.json; else None. Refuses a dataset and a run that lie one inside the other."""
    if data is None or str(Path(data).resolve()) == info.train.data:
        return None
    try:  # not among its data, as train refuses
        guard_run_folder(Path(run_dir), str(data), dataset_inputs(data))
    except NerfkitError:
        raise fail(
            "--data",
            f"{data} and the run {run_dir} lie one inside the other",
            "Keep the dataset out of the run's folder and the run out of the dataset's: eval and "
            "render write into the run",
        ) from None
    info.train.data = str(Path(data).resolve())
    info.scene = {**info.scene, "source": scene.source}
    return replace(info.train)


def _nothing_more(trainer: Trainer) -> str:
    """Why a resumed run that is already past its stopping rule trains no more, and what to give."""
    cfg = trainer.cfg
    by_steps = bool(cfg.steps and trainer.step >= cfg.steps)
    limit = (
        f"--steps {cfg.steps}" if by_steps else f"--minutes {cfg.minutes:g} ({trainer.train_seconds / 60:.3g} trained)"
    )
    more = (
        "give a larger --steps, or --steps 0 --minutes M to go on by time"
        if by_steps
        else "give a larger --minutes, or a --steps past this one"
    )
    return f"at step {trainer.step} the run is already past {limit}: nothing more to train ({more})"


def _finished_at(run_dir: Path, step: int) -> bool:
    """Whether the run's reports say it finished, scored and saved, at ``step`` (a run killed
    during its final save is not: resuming it finishes it)."""
    try:
        metrics = json.loads((run_dir / "metrics.json").read_text())
    except (OSError, ValueError):
        return False
    return (
        isinstance(metrics, dict)
        and metrics.get("finished") is True
        and metrics.get("step") == step
        and (run_dir / MODEL_FILE).is_file()
    )


__all__ = ["TrainResult", "Trainer", "resume", "train"]
