"""A run's metrics rows and report files, as functions of the data they show.

The trainer keeps the rows (one dict per train or val measurement) and calls these; none of
them reads the trainer. The files: ``metrics.json`` and ``metrics.csv`` (every row),
``view_corrections.json`` (when the run learns a correction per training view), and the
figures in ``plots/``: the PSNR and loss curves and the progression of validation view 0.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from ..data.scene import Views
from ..io.atomic import write_json, write_text
from ..viz.plots import image_grid, plot_curves
from .config import eval_stride

# a metrics train row's PSNR is the mean over this many steps' batches (saved in checkpoints)
PSNR_WINDOW = 10
# metrics.csv's columns, in order (a row's other keys are left out)
CSV_COLUMNS = ["step", "seconds", "split", "loss", "psnr", "views", "pixels", "rays"]


def train_row(step: int, seconds: float, loss: float, psnr_db: float, rays: int) -> dict:
    """A metrics row of the training batches at ``step`` (``psnr_db``: the window's mean)."""
    return {"step": step, "seconds": round(seconds, 3), "split": "train", "loss": loss, "psnr": psnr_db, "rays": rays}


def val_row(step: int, seconds: float, psnr_db: float, views: int, pixels: int) -> dict:
    """A metrics row of an evaluation at ``step``: mean PSNR over ``views`` val views,
    ``pixels`` scored per view."""
    return {
        "step": step,
        "seconds": round(seconds, 3),
        "split": "val",
        "loss": float("nan"),
        "psnr": psnr_db,
        "views": views,
        "pixels": pixels,
    }


def scored_at(rows: list[dict], step: int, val: Views, final: bool) -> bool:
    """Whether ``rows`` hold an evaluation of ``step`` (``final``: on every one of the
    ``val`` views, whole; rows of older runs without ``views``/``pixels`` count as that)."""
    full = val.width * val.height
    return any(
        r["split"] == "val"
        and r["step"] == step
        and (not final or (r.get("views", len(val)) >= len(val) and r.get("pixels", full) >= full))
        for r in rows
    )


def eval_rows(
    step: int,
    seconds: float,
    scores: list[float],
    pixels: int,
    final: bool,
    val: Views,
    eval_views: int,
    eval_pixels: int,
) -> tuple[list[dict], str]:
    """The val rows of one evaluation (PSNR ``scores`` of the first ``len(scores)`` ``val``
    views, ``pixels`` scored per view; ``final``: the run's last) and its log line.

    A final evaluation over more views than the periodic ones (``eval_views``; their pixel
    stride from ``eval_pixels``), when those were whole images, also ends their curve with
    a row of its own over the same views, so that the score over every view is not read as
    the curve falling."""
    full = pixels == val.width * val.height
    views = len(scores)
    rows, also = [], ""
    periodic = min(eval_views, views)
    if final and 0 < periodic < views and eval_stride(val.width, val.height, periodic, eval_pixels) == 1:
        rows.append(val_row(step, seconds, float(np.mean(scores[:periodic])), periodic, pixels))
        also = f"; the first {periodic}, as evaluated during training: {rows[-1]['psnr']:.2f} dB"
    rows.append(val_row(step, seconds, float(np.mean(scores)), views, pixels))
    scope = f"all {views} views" if views == len(val) else f"first {views} of {len(val)} views"
    message = (
        f"step {step:6d}  {seconds:7.1f} s  val PSNR {rows[-1]['psnr']:.2f} dB ({scope}"
        + ("" if full else f", {pixels} pixels each")
        + also
        + ")"
    )
    return rows, message


def validation_series(rows: list[dict], n_val: int, full: int) -> dict[str, tuple[list, list]]:
    """Validation rows (``seconds``, ``psnr``, ``views``, ``pixels``) as curves of like
    scores, keyed by a legend label: periodic evaluations (the first ``--eval-views`` of
    ``n_val`` views, every k-th pixel) apart from the final ones (every view, all ``full``
    pixels), so that a plot does not join scores of different views into one line."""
    series: dict[str, tuple[list, list]] = {}
    for r in rows:
        views, pixels = min(r.get("views", n_val), n_val), r.get("pixels", full)  # older runs: views as asked
        which = f"all {views}" if views >= n_val else f"first {views} of {n_val}"
        label = (
            f"validation, {which} view{'s' * (views != 1 or views < n_val)}, "
            f"{'whole images' if pixels >= full else f'{pixels} px per view'}"
        )
        xs, ys = series.setdefault(label, ([], []))
        xs.append(r["seconds"])
        ys.append(r["psnr"])
    return series


def write_metrics(run_dir: Path, rows: list[dict], step: int, train_seconds: float, finished: bool, notes: list[str]):
    """metrics.json (the rows, the step and seconds reached, ``finished``: the stopping rule
    was reached, not cut short; ``notes``: the model's at the end) and metrics.csv (the rows,
    :data:`CSV_COLUMNS`)."""
    write_json(
        run_dir / "metrics.json",
        {"rows": rows, "step": step, "train_seconds": train_seconds, "finished": finished, "notes": notes},
    )
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    write_text(run_dir / "metrics.csv", buf.getvalue())


def write_view_corrections(run_dir: Path, report: list) -> None:
    """view_corrections.json: ``report``, one entry per training view
    (:meth:`~nerfkit.train.view_corrections.ViewCorrections.report`), with what it holds."""
    write_json(
        run_dir / "view_corrections.json",
        {
            "what": "per training view: pose correction (rotation in degrees, translation in scene units) "
            "and exposure gain relative to the average view (with colour mixing also the colour "
            "matrix: rendered rgb -> photo rgb, with the gains on its diagonal)",
            "views": report,
        },
    )


def write_plots(run_dir: Path, rows: list[dict], model_name: str, val: Views) -> None:
    """plots/psnr.png and plots/loss.png from the metrics ``rows`` (validation curves keyed
    by :func:`validation_series` over the ``val`` views), and plots/progress.png: up to 8 of
    the run's progress/step_*.png renders of val view 0 and that view's photo."""
    train = [r for r in rows if r["split"] == "train"]
    plots = run_dir / "plots"
    plot_curves(
        plots / "psnr.png",
        {
            "train (batch)": ([r["seconds"] for r in train], [r["psnr"] for r in train]),
            **validation_series([r for r in rows if r["split"] == "val"], len(val), val.width * val.height),
        },
        "training seconds",
        "PSNR (dB)",
        f"{model_name}: PSNR",
    )
    plot_curves(
        plots / "loss.png",
        {"train loss": ([r["step"] for r in train], [r["loss"] for r in train])},
        "step",
        "loss (photometric + regularisers)",
        f"{model_name}: training loss",
        logy=True,
    )
    snaps = sorted((run_dir / "progress").glob("step_*.png"))
    if len(snaps) > 8:  # keep the first, the last and evenly spaced ones between
        snaps = [snaps[int(round(i))] for i in np.linspace(0, len(snaps) - 1, 8)]
    if snaps and val.has_images:
        import imageio.v3 as iio

        assert val.images is not None  # (has_images)
        images = [iio.imread(p) for p in snaps] + [val.images[0]]
        titles = [f"step {int(p.stem.split('_')[1])}" for p in snaps] + ["ground truth"]
        image_grid(
            plots / "progress.png",
            images,
            titles,
            ncols=min(len(images), 5),
            suptitle="validation view 0 during training",
        )
