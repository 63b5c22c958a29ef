"""Training configuration: one dataclass, turned into flags and saved into every run."""

from __future__ import annotations

from dataclasses import dataclass

from ..config import MAX_BATCH_RAYS, MAX_SEED, MIN_DOWNSCALE, check_ranges, option, parse_background
from ..errors import fail
from ..models import MODEL_NAMES
from ..presets import SCENE_KINDS, default_model


def kind_models_help() -> str:
    """What --help says --model defaults to: the model of each scene kind (presets.default_model)."""
    by_model: dict[str, list[str]] = {}
    for kind in SCENE_KINDS:
        by_model.setdefault(default_model(kind, MODEL_NAMES), []).append(kind)
    return "by the dataset's kind: " + "; ".join(f"{m} for {' and '.join(k)}" for m, k in by_model.items())


@dataclass
class TrainConfig:
    data: str = option(
        "",
        "dataset to train on: a course .npz, or any format `nerfkit convert` reads",
        metavar="PATH",
        group="the options changed first",
    )
    downscale: float = option(
        0.0,
        "divide the dataset's image size by this as it loads, K following (an LLFF "
        "scene's 4 or 8 reads its images_4 or images_8); at least 1, or 0: the size it has",
        min=MIN_DOWNSCALE,
        off=0,
        group="data",
    )
    model: str = option(
        "fast",
        "which radiance field to train",
        choices=list(MODEL_NAMES),
        group="the options changed first",
        default_help=kind_models_help(),
    )
    out: str = option(
        "runs/latest",
        "run folder for checkpoints, metrics, plots and videos",
        metavar="DIR",
        group="the options changed first",
    )
    steps: int = option(
        0, "optimizer steps (0: run until --minutes is spent)", min=0, group="the options changed first"
    )
    minutes: float = option(
        0.0,
        "training-time budget in minutes, evaluation excluded (0: no limit; with neither --steps nor --minutes, 5)",
        min=0,
        group="the options changed first",
    )
    batch_rays: int = option(
        4096,
        "rays per step (vanilla's default: 1024; splat trains on one view per step); "
        "fast takes multiples of it at its finer stages (--stage-rays); lower it if memory "
        "runs out",
        min=1,
        max=MAX_BATCH_RAYS,
        group="optimisation",
    )
    lr: float = option(
        0.3,
        "base learning rate (vanilla's default: 5e-4; splat's: 8, times 3DGS's own rates; forward-facing scenes: 5)",
        min=0,
        max=100,
        group="optimisation",
    )
    lr_final_factor: float = option(
        0.1,
        "learning rate decays exponentially to lr x this at the end (0.02 for the "
        "fast model on a capture: a table texel is hit by few rays, and the low final "
        "rate lets it settle on what the photos agree on)",
        min=0,
        max=1,
        group="optimisation",
    )
    seed: int = option(0, "random seed (rays, sampling, initialisation)", min=0, max=MAX_SEED, group="optimisation")
    device: str = option("auto", "auto, cpu, cuda or cuda:N", group="the options changed first")
    precision: str = option(
        "auto",
        "auto (bf16 where the hardware has it), fp32, or bf16",
        choices=["auto", "fp32", "bf16"],
        group="optimisation",
    )
    background: str = option(
        "black", "colour behind the object: black, white, grey, r,g,b in [0, 1] or #rrggbb", group="data"
    )
    eval_every: int = option(
        0,
        "steps between validation renders (0: at each tenth of the run, and at 1% and 3% of it)",
        min=0,
        group="evaluation and checkpoints",
    )
    eval_views: int = option(
        2,
        "validation views rendered at each periodic evaluation (0: none; the final evaluation renders every one)",
        min=0,
        group="evaluation and checkpoints",
    )
    eval_pixels: int = option(
        MAX_BATCH_RAYS,
        "pixels scored per periodic evaluation, every k-th pixel of each "
        "view on an even grid (the final evaluation scores whole images; vanilla's default: "
        "4096)",
        min=1,
        max=MAX_BATCH_RAYS,
        group="evaluation and checkpoints",
    )
    checkpoint_seconds: float = option(
        60.0, "seconds of training between checkpoints", above=0, group="evaluation and checkpoints"
    )
    keep_checkpoints: int = option(
        1,
        "how many recent resume checkpoints (with optimizer state) to keep (a new "
        "one is written in full before an old one is deleted)",
        min=1,
        group="evaluation and checkpoints",
    )
    render_chunk: int = option(
        65536,
        "rays rendered at once for full images; bounds memory (vanilla's default: 4096)",
        min=1,
        max=MAX_BATCH_RAYS,
        group="evaluation and checkpoints",
    )
    allow_outside_paths: bool = option(
        False,
        "read dataset images that lie outside the dataset's folder (only for a dataset file you trust)",
        group="data",
    )
    capture: str = option(
        "auto",
        "real-capture training: per-view pose and exposure corrections, and (fast model) "
        "the room and the table as background instead of density. auto: on for datasets that "
        "record they are real photos (nerfkit poses writes that)",
        choices=["auto", "on", "off"],
        group="real captures",
    )
    preset: str = option(
        "auto",
        "the scene kind whose settings the run took (nerfkit.presets): object, capture or "
        "forward-facing; recorded in config.json (auto: not resolved yet)",
        choices=["auto", "object", "capture", "forward-facing"],
        cli=False,
    )
    pose_lr: float = option(
        1e-3,
        "with --capture: learning rate of the per-view pose corrections (0: off; the splat model's are off "
        "unless this is given)",
        min=0,
        group="real captures",
    )
    pose_start: int = option(
        100,
        "with --capture: first step that corrects poses (the scene takes shape first)",
        min=0,
        group="real captures",
    )
    exposure_lr: float = option(
        1e-2,
        "with --capture: learning rate of the per-view exposure corrections (0: off)",
        min=0,
        group="real captures",
    )
    colour_mix: bool = option(
        True,
        "with --capture: the exposure correction is an affine colour transform per "
        "photo (each channel also takes some of the others), not only a gain and offset per "
        "channel",
        group="real captures",
    )
    colour_mix_weight: float = option(
        0.01,
        "with --colour-mix: weight of a pull of each photo's colour mixing "
        "towards none (the mean over photos of the squared off-diagonal entries): "
        "grey things (a sheet, a dark table) pin only a photo's gains, and without it "
        "the colours of what few photos see drift",
        min=0,
        group="real captures",
    )

    def validate(self) -> TrainConfig:
        check_ranges(self)
        if self.steps == 0 and self.minutes == 0:
            raise fail("train", "no stopping rule", "Give --steps N or --minutes M (or both)")
        parse_background(self.background)
        return self


def eval_stride(width: int, height: int, n_views: int, pixels: int) -> int:
    """The smallest pixel stride s with ``n_views * ceil(width / s) * ceil(height / s) <= pixels``
    (at least 1 pixel per view: s never exceeds the image's larger side)."""
    side = max(width, height, 1)
    for s in range(1, side + 1):
        if n_views * -(-width // s) * -(-height // s) <= pixels:
            return s
    return side
