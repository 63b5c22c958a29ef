"""Training configuration: one dataclass, turned into flags and saved into every run."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..config import MAX_SEED, MIN_DOWNSCALE, check_ranges, option, parse_background
from ..errors import fail
from ..models import MODEL_NAMES

# Rays per training step or per rendering chunk: far more than fits any memory is refused
# when the command line is parsed (a batch that still does not fit is a one-line error).
MAX_BATCH_RAYS = 1 << 20


@dataclass
class TrainConfig:
    data: str = option("", "dataset to train on: a course .npz, or any format `nerfkit convert` reads",
                       metavar="PATH")
    downscale: float = option(0.0, "divide the dataset's image size by this as it loads, K following (an LLFF "
                              "scene's 4 or 8 reads its images_4 or images_8); at least 1, or 0: the size it has",
                              min=MIN_DOWNSCALE, off=0)
    model: str = option("fast", "which radiance field to train", choices=list(MODEL_NAMES))
    out: str = option("runs/latest", "run folder for checkpoints, metrics, plots and videos", metavar="DIR")
    steps: int = option(0, "optimizer steps (0: run until --minutes is spent)", min=0)
    minutes: float = option(0.0, "training-time budget in minutes, evaluation excluded (0: no limit; with neither "
                                 "--steps nor --minutes, 5)", min=0)
    batch_rays: int = option(0, "rays per step (0: the model's default; fast takes multiples of it at its finer "
                             "stages, --stage-rays); lower it if memory runs out", min=0, max=MAX_BATCH_RAYS)
    lr: float = option(0.0, "base learning rate (0: the model's default)", min=0, max=100)
    lr_final_factor: float = option(0.0, "learning rate decays exponentially to lr x this at the end (0: 0.1, or "
                                    "0.02 for the fast model with --capture: a table texel is hit by few rays, and "
                                    "the low final rate lets it settle on what the photos agree on)", min=0, max=1)
    seed: int = option(0, "random seed (rays, sampling, initialisation)", min=0, max=MAX_SEED)
    device: str = option("auto", "auto, cpu, cuda or cuda:N")
    precision: str = option("auto", "auto (bf16 where the hardware has it), fp32, or bf16", choices=["auto", "fp32", "bf16"])
    background: str = option("black", "colour behind the object: black, white, grey, r,g,b in [0, 1] or #rrggbb")
    eval_every: int = option(0, "steps between validation renders (0: at each tenth of the run, and at 1% "
                             "and 3% of it)", min=0)
    eval_views: int = option(2, "validation views rendered at each periodic evaluation", min=0)
    eval_pixels: int = option(0, "pixels scored per periodic evaluation, every k-th pixel of each view on an even "
                              "grid (the final evaluation scores whole images); 0: the model's default (vanilla "
                              "4096, fast whole images)", min=0, max=MAX_BATCH_RAYS)
    checkpoint_seconds: float = option(60.0, "seconds of training between checkpoints", above=0)
    keep_checkpoints: int = option(2, "how many recent resume checkpoints (with optimizer state) to keep", min=1)
    render_chunk: int = option(0, "rays rendered at once for full images; bounds memory (0: the model's default)",
                               min=0, max=MAX_BATCH_RAYS)
    allow_outside_paths: bool = option(False, "read dataset images that lie outside the dataset's folder "
                                       "(only for a dataset file you trust)")
    capture: str = option("auto", "real-capture training: per-view pose and exposure corrections, and (fast model) "
                          "the room and the table as background instead of density. auto: on for datasets that "
                          "record they are real photos (nerfkit poses writes that)", choices=["auto", "on", "off"])
    pose_lr: float = option(1e-3, "with --capture: learning rate of the per-view pose corrections (0: off)", min=0)
    pose_start: int = option(100, "with --capture: first step that corrects poses (the scene takes shape first)",
                             min=0)
    exposure_lr: float = option(1e-2, "with --capture: learning rate of the per-view exposure corrections (0: off)",
                                min=0)
    colour_mix: bool = option(True, "with --capture: the exposure correction is an affine colour transform per "
                              "photo (each channel also takes some of the others), not only a gain and offset per "
                              "channel")
    colour_mix_weight: float = option(0.01, "with --colour-mix: weight of a pull of each photo's colour mixing "
                                      "towards none (the mean over photos of the squared off-diagonal entries): "
                                      "grey things (a sheet, a dark table) pin only a photo's gains, and without it "
                                      "the colours of what few photos see drift", min=0)

    def validate(self) -> "TrainConfig":
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


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError:
        raise fail("--device", f"'{name}' is not a device", "Use auto, cpu, cuda or cuda:N") from None
    if device.type not in ("cpu", "cuda"):
        raise fail("--device", f"nerfkit runs on the CPU or on CUDA, not on '{name}'", "Use auto, cpu, cuda or cuda:N")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise fail("--device", "CUDA was asked for but this PyTorch has no CUDA device", "Use --device cpu")
    if device.type == "cuda" and device.index is not None:
        count = torch.cuda.device_count()
        if device.index >= count:
            raise fail("--device", f"'{name}' asks for GPU {device.index}, but this machine has {count} "
                       f"(cuda:0{f' to cuda:{count - 1}' if count > 1 else ''})", "Use --device cuda")
        torch.cuda.set_device(device)  # what asks for "the current GPU" (bf16 support, gsplat) asks this one
    return device


def resolve_autocast(precision: str, device: torch.device) -> torch.dtype | None:
    """The autocast dtype for a precision setting, or None for plain fp32
    (:func:`nerfkit.precision.resolve_precision`: the one rule)."""
    from ..precision import resolve_precision

    return resolve_precision(precision, device)
