"""Fit a neural field to one 2D image (the course warm-up): training, sweeps, figures.

The model (:class:`~nerfkit.fields.image_field.ImageField`) maps normalised pixel
coordinates to RGB. Each step trains on ``batch`` random pixels; the full image is only
ever rendered in chunks of ``chunk`` pixels, so memory stays bounded for 12-megapixel
photos. PSNR = 10 log10(1 / MSE) for colours in [0, 1].

Run folder (``write_run``)::

    psnr.png         PSNR against step (evaluated on a schedule, see the axis label)
    progression.png  the original beside the reconstruction at chosen steps
    final.png        the final reconstruction at full resolution
    metrics.json     final PSNR, the PSNR curve, speed
    config.json      every hyperparameter, the image path and the resolved device

A sweep (``run_sweep``) writes one such folder per combination plus ``sweep_grid.png``
(final images labelled with the swept values and PSNR), ``sweep_psnr.png`` (every curve)
and ``sweep.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .config import MAX_SEED, check_ranges, flag_type, option, parse_background
from .errors import fail
from .images import write_image
from .io.atomic import write_json
from .train.metrics import psnr_from_mse
from .viz.plots import image_grid, plot_curves

if TYPE_CHECKING:  # torch is imported inside functions so the CLI can build its parser quickly
    import torch
    from torch import Tensor

    from .fields.image_field import ImageField

DEFAULT_IMAGE_NAME = "astronaut.jpg"
SWEEPABLE = ("L", "width", "depth", "lr", "batch", "steps")
# the largest MLP fit-image builds: far beyond what fitting one image needs (the course's
# sweeps stay within width 512 and depth 8), and a bound before memory runs out
MAX_WIDTH = 8192
MAX_DEPTH = 64


@dataclass
class FitImageConfig:
    """Hyperparameters of ``nerfkit fit-image`` (each is a flag of the same name)."""

    L: int = option(10, "positional-encoding octaves; the MLP sees 2 * (1 + 2 L) inputs (42 at L = 10)", min=0, max=30)
    width: int = option(256, "hidden layer width", min=1, max=MAX_WIDTH)
    depth: int = option(3, "number of hidden Linear+ReLU layers", min=1, max=MAX_DEPTH)
    lr: float = option(1e-2, "Adam learning rate", above=0, max=100)
    batch: int = option(10_000, "random pixels per training step", min=1, max=1 << 24)
    steps: int = option(2000, "training steps", min=0, max=100_000_000)
    seed: int = option(
        0, "random seed (weights, pixel sampling, PSNR subset); same seed, same result", min=0, max=MAX_SEED
    )
    device: str = option("auto", "auto (cuda when available, else cpu), cpu, cuda or cuda:N")
    precision: str = option(
        "auto",
        "matmul precision: bf16 autocast or fp32; auto = bf16 on CPUs with native "
        "bf16 (avx512_bf16/amx) and on CUDA GPUs that support it, else fp32",
        choices=["auto", "bf16", "fp32"],
    )
    eval_every: int = option(
        50,
        "evaluate PSNR for the curve every N steps and at the progression steps (one "
        "evaluation of a 512x512 image costs about as much as 9 training steps)",
        min=1,
    )
    eval_pixels: int = option(
        262_144,
        "the curve's PSNR uses the full image up to this many pixels, else a "
        "fixed random subset of this size (the final PSNR always uses every pixel)",
        min=1,
    )
    progress_steps: str = option(
        "0,50,100,200,500",
        "steps shown in the progression figure, comma-separated (the final step is always added)",
        metavar="LIST",
    )
    background: str = option(
        "white", "colour behind transparent pixels: white, black, grey, R,G,B in 0-1, or #rrggbb", metavar="COLOUR"
    )
    chunk: int = option(65_536, "pixels per forward pass when rendering whole images (bounds memory)", min=1)
    preview_size: int = option(
        1024, "figures show images at full resolution up to this long side, larger images on a downscaled grid", min=8
    )


# ---------------------------------------------------------------------------------------
# Small pure helpers


def validate_config(cfg: FitImageConfig) -> None:
    """Raise a one-line NerfkitError for values that cannot train."""
    check_ranges(cfg)
    if cfg.precision not in ("auto", "bf16", "fp32"):
        raise fail("--precision", f"unknown precision '{cfg.precision}'", "Use auto, bf16 or fp32")
    parse_steps(cfg.progress_steps)
    parse_background(cfg.background)


def model_bytes(L: int, width: int, depth: int) -> int:
    """Bytes an :class:`ImageField` takes to train: its float32 weights, their gradients and
    Adam's two moments (4 copies)."""
    inputs = 2 * (1 + 2 * L)  # the encoded (x, y)
    weights = (inputs + 1) * width + (depth - 1) * (width + 1) * width + (width + 1) * 3
    return 16 * weights


def step_bytes(batch: int, width: int, depth: int) -> int:
    """Rough bytes of one training step's activations: each hidden layer's output for
    ``batch`` pixels, kept for the backward pass, and its gradient (float32)."""
    return 8 * batch * width * depth


def memory_bytes(device) -> int | None:
    """The memory of ``device`` (a torch.device): the GPU's, or the machine's RAM; None when unknown."""
    try:
        if device.type == "cuda":
            import torch

            return int(torch.cuda.get_device_properties(device).total_memory)
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError, RuntimeError):
        return None


def check_memory(cfg: FitImageConfig, device) -> None:
    """Refuse, naming the flag to lower, a model (``--width``, ``--depth``) or a training step
    (``--batch``) that needs more memory than ``device`` has, before anything is built."""
    have = memory_bytes(device)
    if not have:
        return
    model = model_bytes(cfg.L, cfg.width, cfg.depth)
    where = "the GPU's" if device.type == "cuda" else "this machine's"
    if model > have:
        raise fail(
            "--width/--depth",
            f"a model of width {cfg.width} and depth {cfg.depth} needs about "
            f"{model / 1e9:.3g} GB to train (weights, gradients, Adam's state), more than {where} "
            f"{have / 1e9:.3g} GB of memory",
            "Lower --width or --depth (the defaults: 256 and 3)",
        )
    step = step_bytes(cfg.batch, cfg.width, cfg.depth)
    if model + step > have:
        raise fail(
            "--batch",
            f"a step of {cfg.batch} pixels through width {cfg.width} and depth {cfg.depth} needs "
            f"about {(model + step) / 1e9:.3g} GB, more than {where} {have / 1e9:.3g} GB of memory",
            "Lower --batch (or --width)",
        )


def parse_steps(text: str) -> list[int]:
    """``"0,50,100"`` -> ``[0, 50, 100]`` (sorted, unique, non-negative)."""
    try:
        steps = sorted({int(s) for s in text.replace(" ", "").split(",") if s})
    except ValueError:
        raise fail(
            "--progress-steps", f"cannot read '{text}'", "Give whole step numbers like 0,50,100,200,500"
        ) from None
    if any(s < 0 for s in steps):
        raise fail("--progress-steps", f"negative step in '{text}'", "Steps count from 0")
    return steps


def parse_sweep(tokens: list[str]) -> list[dict[str, int | float]]:
    """``["L=3,10", "width=64,256"]`` -> one dict per combination (the Cartesian product).

    Keys are config fields from ``SWEEPABLE`` (``-`` or ``_`` accepted); values are
    comma-separated numbers, each within the bounds of the key's flag. Combinations are
    ordered like nested loops, first key outermost.
    """
    axes: dict[str, list[int | float]] = {}
    for tok in tokens:
        key, sep, values = tok.partition("=")
        key = key.strip().replace("-", "_")
        if not sep or not values.strip():
            raise fail("--sweep", f"cannot read '{tok}'", "Write KEY=V1,V2 items such as L=3,10 width=64,256")
        if key not in SWEEPABLE:
            raise fail("--sweep", f"cannot sweep '{key}'", f"Sweepable keys: {', '.join(SWEEPABLE)}")
        if key in axes:
            raise fail("--sweep", f"'{key}' is given twice", "List all its values once, comma-separated")
        parse = flag_type(FitImageConfig, key)  # the flag's own check: --sweep L=100 is refused as --L 100 is
        try:
            axes[key] = [parse(v.strip()) for v in values.split(",") if v.strip()]
        except argparse.ArgumentTypeError as e:
            raise fail(f"--sweep {tok}", str(e)) from None
    if not axes:
        raise fail("--sweep", "no KEY=V1,V2 items", "Example: --sweep L=3,10 width=64,256")
    for key, chosen in axes.items():  # each run has its own folder, named after its values
        labels = [sweep_label({key: v}) for v in chosen]
        twice = sorted({lab for lab in labels if labels.count(lab) > 1})
        if twice:
            raise fail(
                "--sweep",
                f"{', '.join(twice)} is given twice (or as values that print alike)",
                "List each value once",
            )
    return [dict(zip(axes, combo)) for combo in itertools.product(*axes.values())]


def resolve_precision(name: str, device: torch.device) -> str:
    """``auto`` -> ``bf16`` where it is native and fast (measured: benchmarks/fit_image.py), else ``fp32``
    (the one rule of :func:`nerfkit.precision.resolve_precision`)."""
    from .precision import resolve_precision as resolve

    return "fp32" if resolve(name, device) is None else "bf16"


def autocast(device: torch.device, precision: str):
    """The autocast context for a precision (disabled for fp32)."""
    import torch

    from .precision import autocast as precision_autocast

    return precision_autocast(device, torch.bfloat16 if precision == "bf16" else None)


def default_image_path() -> Path:
    """The image shipped in ``nerfkit/assets`` (NASA, public domain; see assets/README.md)."""
    return Path(str(resources.files("nerfkit") / "assets" / DEFAULT_IMAGE_NAME))


def preview_shape(height: int, width: int, max_side: int) -> tuple[int, int]:
    """(h, w) no larger than ``max_side`` on the long side, keeping the aspect ratio."""
    scale = min(1.0, max_side / max(height, width))
    return max(1, round(height * scale)), max(1, round(width * scale))


def downscale(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Area-average (H, W, 3) float image to ``shape`` = (h, w) (a no-op when equal)."""
    if image.shape[:2] == tuple(shape):
        return image
    from PIL import Image

    chans = [
        np.asarray(
            Image.fromarray(np.ascontiguousarray(image[..., c])).resize((shape[1], shape[0]), Image.Resampling.BOX)
        )
        for c in range(3)
    ]
    return np.stack(chans, axis=-1).astype(np.float32)


# ---------------------------------------------------------------------------------------
# Rendering and evaluation (chunked, memory bounded)


def render_image(
    model: ImageField,
    height: int,
    width: int,
    *,
    chunk: int = 65_536,
    precision: str = "fp32",
    target: np.ndarray | None = None,
) -> tuple[np.ndarray, float | None]:
    """Render the field on a (height, width) pixel-centre grid, a few rows at a time.

    Args:
        target: optional (height, width, 3) float image; when given, its MSE against
            the render is accumulated chunk by chunk.

    Returns:
        (image (height, width, 3) float32 in [0, 1], mse or None).
    """
    import torch

    from .fields.image_field import grid_xy

    device = next(model.parameters()).device
    out = np.empty((height, width, 3), np.float32)
    rows_per_chunk = max(1, chunk // width)
    sse = 0.0
    for r0 in range(0, height, rows_per_chunk):
        rows = torch.arange(r0, min(r0 + rows_per_chunk, height), device=device)
        with torch.inference_mode(), autocast(device, precision):
            rgb = model(grid_xy(rows, height, width))
        block = rgb.float().cpu().numpy().reshape(len(rows), width, 3)
        out[r0 : r0 + len(rows)] = block
        if target is not None:
            sse += float(np.sum((block.astype(np.float64) - target[r0 : r0 + len(rows)]) ** 2))
    mse = sse / (height * width * 3) if target is not None else None
    return out, mse


def eval_mse(
    model: ImageField, colors: Tensor, index: Tensor, height: int, width: int, *, chunk: int, precision: str
) -> float:
    """MSE of the field at flat pixel ``index`` (M,) against ``colors`` (M, 3) (same device)."""
    import torch

    from .fields.image_field import pixel_xy

    device = colors.device
    sse = 0.0
    for s in range(0, len(index), chunk):
        idx = index[s : s + chunk]
        with torch.inference_mode(), autocast(device, precision):
            rgb = model(pixel_xy(idx, height, width))
            sse += float(torch.sum((rgb.float() - colors[s : s + chunk]) ** 2, dtype=torch.float64))
    return sse / (len(index) * 3)


# ---------------------------------------------------------------------------------------
# Training


@dataclass
class FitResult:
    """What one fit produced.

    Attributes:
        final_image: (H, W, 3) float32 full-resolution reconstruction.
        final_psnr: PSNR of ``final_image`` on every pixel.
        curve_steps, curve_psnr: the PSNR curve (evaluated on ``eval_note``'s pixels).
        progression: [(step, (h, w, 3) float32 render at preview size, PSNR)].
        steps_per_s: training steps per second (evaluation time excluded).
        train_seconds / eval_seconds: wall time in training steps / in evaluations.
    """

    config: FitImageConfig
    device: str
    precision: str
    height: int
    width: int
    final_image: np.ndarray
    final_psnr: float
    curve_steps: list[int]
    curve_psnr: list[float]
    progression: list[tuple[int, np.ndarray, float]]
    eval_note: str
    steps_per_s: float
    train_seconds: float
    eval_seconds: float
    model: ImageField = field(repr=False)
    interrupted: bool = False  # stopped by Ctrl-C: ``config.steps`` is the steps done

    def metrics(self) -> dict:
        return {
            "final_psnr_db": self.final_psnr,
            "final_psnr_note": "on every pixel of the full-resolution image",
            "image_height": self.height,
            "image_width": self.width,
            "steps": self.config.steps,
            "steps_per_s": self.steps_per_s,
            "train_seconds": self.train_seconds,
            "eval_seconds": self.eval_seconds,
            "device": self.device,
            "precision": self.precision,
            "curve": {"note": self.eval_note, "step": self.curve_steps, "psnr_db": self.curve_psnr},
            "progression": [{"step": s, "psnr_db": p} for s, _, p in self.progression],
        }


def fit_image(target: np.ndarray, cfg: FitImageConfig, progress: bool = True, desc: str = "fit-image") -> FitResult:
    """Train an :class:`ImageField` on ``target`` (H, W, 3) float in [0, 1].

    Deterministic for a given ``cfg.seed`` on a given device and thread count.
    """
    import torch
    from tqdm import tqdm

    from .fields.image_field import ImageField, pixel_xy

    validate_config(cfg)
    if target.ndim != 3 or target.shape[2] != 3 or target.shape[0] < 1 or target.shape[1] < 1:
        raise fail("image", f"expected an (H, W, 3) image, got shape {target.shape}")
    height, width = target.shape[:2]
    n_pix = height * width
    from .precision import resolve_device

    device = resolve_device(cfg.device)
    precision = resolve_precision(cfg.precision, device)

    check_memory(cfg, device)
    torch.manual_seed(cfg.seed)
    model = ImageField(cfg.L, cfg.width, cfg.depth).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    gen = torch.Generator(device=device).manual_seed(cfg.seed)
    colors = torch.from_numpy(np.ascontiguousarray(target, dtype=np.float32)).reshape(-1, 3).to(device)

    # The curve's PSNR: every pixel, or a fixed random subset for big images.
    eval_all = n_pix <= cfg.eval_pixels
    if eval_all:
        eval_index = torch.arange(n_pix, device=device)
        eval_note = f"PSNR on the full image ({width}x{height})"
    else:
        rng = np.random.default_rng(cfg.seed)
        eval_index = torch.from_numpy(np.sort(rng.choice(n_pix, cfg.eval_pixels, replace=False))).to(device)
        eval_note = f"PSNR on a fixed random subset of {cfg.eval_pixels:,} of the {n_pix:,} pixels ({width}x{height})"
    eval_colors = colors[eval_index]
    shot_steps = set(s for s in parse_steps(cfg.progress_steps) if s < cfg.steps) | {cfg.steps}
    prev_h, prev_w = preview_shape(height, width, cfg.preview_size)
    full_preview = (prev_h, prev_w) == (height, width)

    curve_steps: list[int] = []
    curve_psnr: list[float] = []
    progression: list[tuple[int, np.ndarray, float]] = []
    eval_seconds = 0.0

    def evaluate(step: int) -> float:
        nonlocal eval_seconds
        t0 = time.perf_counter()
        model.eval()
        full_psnr = None
        if step in shot_steps:
            # Progression image: full resolution (and its every-pixel PSNR) or a preview grid.
            img, mse = render_image(
                model, prev_h, prev_w, chunk=cfg.chunk, precision=precision, target=target if full_preview else None
            )
            if full_preview:
                assert mse is not None  # rendered against the target
                full_psnr = psnr_from_mse(mse)
        if full_psnr is not None and eval_all:
            psnr = full_psnr  # same pixels as the curve's evaluation, no need to evaluate twice
        else:
            psnr = psnr_from_mse(
                eval_mse(model, eval_colors, eval_index, height, width, chunk=cfg.chunk, precision=precision)
            )
        if step in shot_steps:
            progression.append((step, img, psnr if full_psnr is None else full_psnr))
        model.train()
        curve_steps.append(step)
        curve_psnr.append(psnr)
        eval_seconds += time.perf_counter() - t0
        return psnr

    psnr = evaluate(0)
    train_seconds = 0.0
    bar = tqdm(range(1, cfg.steps + 1), desc=desc, disable=None if progress else True, unit="step", leave=False)
    done, interrupted = 0, False
    try:
        for step in bar:
            t0 = time.perf_counter()
            idx = torch.randint(0, n_pix, (cfg.batch,), device=device, generator=gen)
            with autocast(device, precision):
                rgb = model(pixel_xy(idx, height, width))
            loss = torch.mean((rgb - colors[idx]) ** 2)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            train_seconds += time.perf_counter() - t0
            if step % cfg.eval_every == 0 or step in shot_steps:
                psnr = evaluate(step)
            if step % 10 == 0 or step == cfg.steps:
                bar.set_postfix(loss=f"{loss.item():.5f}", psnr=f"{psnr:.2f}dB", refresh=False)
            done = step
    except KeyboardInterrupt:  # keep what was fitted: the figures of the steps done
        interrupted = True
    bar.close()
    if interrupted:
        if done == 0:
            raise KeyboardInterrupt
        cfg = dataclasses.replace(cfg, steps=done)
        if done not in shot_steps:
            shot_steps.add(done)
            evaluate(done)
    if cfg.steps and not math.isfinite(loss.item()):
        raise fail("training", "the loss became NaN/inf", "Lower --lr")

    # The final image at full resolution, and its PSNR on every pixel.
    t0 = time.perf_counter()
    model.eval()
    if full_preview:
        final_image, final_psnr = progression[-1][1], progression[-1][2]
    else:
        final_image, mse = render_image(model, height, width, chunk=cfg.chunk, precision=precision, target=target)
        assert mse is not None  # rendered against the target
        final_psnr = psnr_from_mse(mse)
    eval_seconds += time.perf_counter() - t0
    return FitResult(
        cfg,
        str(device),
        precision,
        height,
        width,
        final_image,
        final_psnr,
        curve_steps,
        curve_psnr,
        progression,
        eval_note,
        cfg.steps / train_seconds if train_seconds > 0 else 0.0,
        train_seconds,
        eval_seconds,
        model,
        interrupted,
    )


# ---------------------------------------------------------------------------------------
# Files and figures


def load_target(image: str | Path | None, background: str) -> tuple[np.ndarray, Path]:
    """Load the image to fit (the shipped default when ``image`` is None) -> ((H, W, 3) float32, path)."""
    from .images import load_image

    path = default_image_path() if image is None else Path(image)
    return load_image(path, parse_background(background)), path


# What a fit (write_run) and a sweep (_write_sweep_summary) write into their folder.
RUN_FILES = ("psnr.png", "progression.png", "final.png", "metrics.json", "config.json")
SWEEP_FILES = ("sweep_grid.png", "sweep_psnr.png", "sweep.json")


def write_run(out: str | Path, result: FitResult, target: np.ndarray, image_path: Path) -> None:
    """Write the PSNR curve, progression figure, final image, metrics and config into ``out``."""
    out = Path(out)
    cfg = result.config
    plot_curves(
        out / "psnr.png",
        {"PSNR": (result.curve_steps, result.curve_psnr)},
        xlabel=f"step (evaluated every {cfg.eval_every} steps and at the progression steps)",
        ylabel="PSNR (dB)",
        title=_wrap(f"{image_path.name}: {result.eval_note}"),
    )
    shape = result.progression[-1][1].shape[:2]
    shown = downscale(target, shape)
    size_note = "" if shape == target.shape[:2] else f" (shown at {shape[1]}x{shape[0]})"
    images = [shown] + [img for _, img, _ in result.progression]
    last = result.curve_steps[-1] if result.curve_steps else None
    titles = [f"original {result.width}x{result.height}{size_note}"] + [
        # the last step's tile shows the every-pixel PSNR of the title (the others: the curve's)
        f"step {s}: {result.final_psnr if s == last else p:.2f} dB"
        for s, _, p in result.progression
    ]
    image_grid(
        out / "progression.png",
        images,
        titles,
        ncols=_grid_cols(len(images)),
        suptitle=f"L={cfg.L} width={cfg.width} depth={cfg.depth}: final {result.final_psnr:.2f} dB",
    )
    write_image(out / "final.png", result.final_image)
    write_json(out / "metrics.json", result.metrics())
    write_json(
        out / "config.json",
        {
            "image": str(image_path),
            **dataclasses.asdict(cfg),
            "resolved_device": result.device,
            "resolved_precision": result.precision,
        },
    )


def _grid_cols(n: int, max_cols: int = 7) -> int:
    """Columns for ``n`` tiles: one row up to ``max_cols``, else balanced rows.

    (One row also avoids image_grid's titles overlapping the row above for square images.)
    """
    rows = -(-n // max_cols)
    return -(-n // rows)


def _wrap(text: str, width: int = 70) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width))


def run_fit(image: str | Path | None, out: str | Path, cfg: FitImageConfig, progress: bool = True) -> FitResult:
    """Load, train, write the run folder; returns the result."""
    validate_config(cfg)
    target, path = load_target(image, cfg.background)
    result = fit_image(target, cfg, progress=progress)
    write_run(out, result, target, path)
    return result


def sweep_label(combo: dict) -> str:
    """``{"L": 3, "width": 64}`` -> ``"L=3 width=64"``."""
    return " ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in combo.items())


def sweep_folder(out: str | Path, combo: dict) -> Path:
    """The run folder of one sweep combination: ``{"L": 3, "width": 64}`` -> ``out/L3_width64``."""
    return Path(out) / sweep_label(combo).replace(" ", "_").replace("=", "")


def sweep_outputs(out: str | Path, combos: list[dict]) -> list[Path]:
    """Every file a sweep writes: the summary files and each combination's run files."""
    out = Path(out)
    return [out / name for name in SWEEP_FILES] + [sweep_folder(out, c) / name for c in combos for name in RUN_FILES]


def run_sweep(
    image: str | Path | None, out: str | Path, cfg: FitImageConfig, combos: list[dict], progress: bool = True
) -> list[dict]:
    """Train one model per combination (each overriding ``cfg``); write each run folder and the summary.

    Writes ``out/<label>/`` per run, ``out/sweep_grid.png``, ``out/sweep_psnr.png`` and
    ``out/sweep.json``. Returns the JSON's run entries, one per combination: the swept
    values plus ``label``, ``final_psnr_db``, ``steps_per_s`` and ``folder``.
    """
    validate_config(cfg)
    for combo in combos:
        validate_config(dataclasses.replace(cfg, **combo))
    target, path = load_target(image, cfg.background)
    out = Path(out)
    done: list[_SweepRun] = []
    entries: list[dict] = []
    for i, combo in enumerate(combos):
        label = sweep_label(combo)
        folder = sweep_folder(out, combo)
        result = fit_image(
            target, dataclasses.replace(cfg, **combo), progress=progress, desc=f"[{i + 1}/{len(combos)}] {label}"
        )
        write_run(folder, result, target, path)
        # Keep only the preview-size final image, so a sweep over a big photo stays small in memory.
        done.append(
            _SweepRun(
                label,
                result.final_psnr,
                result.curve_steps,
                result.curve_psnr,
                result.progression[-1][1],
                result.eval_note,
            )
        )
        entries.append(
            {
                **combo,
                "label": label,
                "final_psnr_db": result.final_psnr,
                "steps_per_s": result.steps_per_s,
                "folder": folder.name,
            }
        )
        interrupted = result.interrupted
        del result
        # Rewritten after every run, so an interrupted sweep keeps what finished.
        _write_sweep_summary(out, done, entries, path, target, cfg.eval_every)
        if interrupted:  # Ctrl-C: the run it stopped is written with the steps it did; no more runs
            raise KeyboardInterrupt
    return entries


@dataclass
class _SweepRun:
    label: str
    final_psnr: float
    curve_steps: list[int]
    curve_psnr: list[float]
    preview: np.ndarray
    eval_note: str


def _write_sweep_summary(
    out: Path, done: list[_SweepRun], entries: list[dict], path: Path, target: np.ndarray, eval_every: int
) -> None:
    images = [downscale(target, done[0].preview.shape[:2])] + [r.preview for r in done]
    titles = ["original"] + [f"{r.label}: {r.final_psnr:.2f} dB" for r in done]
    image_grid(
        out / "sweep_grid.png",
        images,
        titles,
        ncols=_grid_cols(len(images)),
        suptitle=f"{path.name}: final images (PSNR on every pixel)",
    )
    curves: dict[str, tuple[Sequence[float], Sequence[float]]] = {
        f"{r.label} ({r.final_psnr:.1f} dB)": (r.curve_steps, r.curve_psnr) for r in done
    }
    plot_curves(
        out / "sweep_psnr.png",
        curves,
        xlabel=f"step (evaluated every {eval_every} steps)",
        ylabel="PSNR (dB)",
        title=_wrap(f"{path.name}: {done[0].eval_note}"),
    )
    write_json(out / "sweep.json", {"image": str(path), "curve_note": done[0].eval_note, "runs": entries})
