"""What a resumed run takes back from its checkpoint besides the model and its optimizer:
the training state the model keeps, the per-view corrections, the random streams, the
precision it trained in and the last training PSNRs.

Each function reads one part of a checkpoint dict (:func:`~nerfkit.train.checkpoint.save_checkpoint`'s
``extra``, as the trainer writes it) into the objects given; none reads the trainer.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import torch

from ..data.rays import RaysData
from ..errors import fail
from ..models.base import NerfModel
from .checkpoint import MODEL_FILE, load_latest_checkpoint, set_aside
from .reports import PSNR_WINDOW
from .view_corrections import ViewCorrections


def precision_name(dtype: torch.dtype | None) -> str:
    """How a checkpoint records the precision a run trains in: "bf16" or "fp32"."""
    return "bf16" if dtype == torch.bfloat16 else "fp32"


def resumed_precision(
    recorded: object, here: torch.dtype | None, device: torch.device
) -> tuple[torch.dtype | None, str | None]:
    """The precision a resumed run goes on in, and a warning when it is not the one it trained
    in: the recorded one (``--precision auto`` chose it where the run started), unless that is
    bf16 and ``here`` (what auto chooses on this device) is not; older checkpoints: ``here``."""
    if recorded not in ("bf16", "fp32") or recorded == precision_name(here):
        return here, None
    if recorded == "fp32":
        return None, None
    return here, (
        f"trained in bf16, which this {device.type} does not do natively: it goes on in fp32 "
        "(--precision auto), so no longer exactly as an uninterrupted run"
    )


def psnr_window(saved: object) -> list[float]:
    """A checkpoint's last training PSNRs (older checkpoints, or anything else: none)."""
    if not isinstance(saved, list) or not all(isinstance(v, float) and math.isfinite(v) for v in saved):
        return []
    return saved[-PSNR_WINDOW:]


def load_for_resume(run_dir: Path, model: NerfModel, device: torch.device) -> tuple[dict, Path] | None:
    """Load the run's newest good checkpoint into ``model`` (moved to ``device``), with the
    training state the model keeps; set aside the checkpoints that did not load or are newer
    (with a warning). Returns the checkpoint dict and its path; None: no checkpoint yet.
    Raises for a trained run (model.pt) whose checkpoints are gone, and for a malformed
    training state."""
    loaded = load_latest_checkpoint(run_dir, model)
    if loaded is None:
        if (run_dir / MODEL_FILE).exists():  # trained, its checkpoints gone: never train over it
            raise fail(
                run_dir,
                "holds a trained model (model.pt) but no checkpoint to continue it from",
                "Train a new run with another --out, or delete model.pt to start this run over",
            )
        return None
    ckpt, path = loaded
    moved = set_aside(run_dir, path, int(ckpt["step"]))
    if moved:  # (else pruning would keep them over the checkpoints this run writes)
        print(
            f"warning: {run_dir}: moved {', '.join(p.name for p in moved)} to {moved[0].parent} "
            f"(not loadable, or newer than {path.name}, which training goes on from)",
            file=sys.stderr,
        )
    model.to(device)
    try:
        training_state = ckpt.get("training_state", {})  # (older checkpoints: none)
        if not isinstance(training_state, dict):
            raise ValueError("not a dict")
        model.load_training_state(training_state)
    except ValueError as e:
        raise fail(path, f"malformed checkpoint ('training_state': {e})", "Put the run's own file back") from None
    return ckpt, path


def restore_views(ckpt: dict, path: Path, views: ViewCorrections, optimizer: torch.optim.Optimizer | None) -> None:
    """The per-view corrections (and their optimizer's state, when every correction was
    saved) from checkpoint ``ckpt`` (read from ``path``). Corrections newer than the
    checkpoint (colour mixing, a splat run's pose) start at zero; any other difference raises."""
    if "views" not in ckpt:
        raise fail(
            path,
            "holds no per-view corrections, but this run trains them",
            "The checkpoint is from another nerfkit; re-train",
        )
    missing = set(views.state_dict()) - set(ckpt["views"])
    # a run from before --colour-mix, or a splat run from before its pose corrections: these start at zero
    if not missing <= {"exposure.mix", "pose.rotation", "pose.translation"}:
        raise fail(
            path,
            f"holds other per-view corrections than this run trains ({sorted(missing)} missing)",
            "The checkpoint is from another nerfkit; re-train",
        )
    views.load_state_dict(ckpt["views"], strict=False)
    if not missing:  # (else the views' Adam state starts afresh too)
        assert optimizer is not None  # (built with the views)
        optimizer.load_state_dict(ckpt["views_optimizer"])


def rng_state(rays: RaysData, sight_generator: torch.Generator, device: torch.device) -> dict:
    """Training's random streams, for a checkpoint: torch's global one (and CUDA's on a GPU),
    the ray sampler's and the sight lines'."""
    state = {
        "torch_rng": torch.get_rng_state(),
        "sampler_rng": rays.rng_state(),
        "sight_rng": sight_generator.get_state(),
    }
    if device.type == "cuda":
        state["cuda_rng"] = torch.cuda.get_rng_state(device)
    return state


def restore_rng(ckpt: dict, rays: RaysData, sight_generator: torch.Generator, device: torch.device) -> None:
    """Set the random streams :func:`rng_state` saved in ``ckpt`` (older checkpoints have no
    sight lines' stream; a CPU run's has no CUDA one)."""
    torch.set_rng_state(ckpt["torch_rng"])
    rays.set_rng_state(ckpt["sampler_rng"])
    if "sight_rng" in ckpt:
        sight_generator.set_state(ckpt["sight_rng"])
    if "cuda_rng" in ckpt and device.type == "cuda":
        torch.cuda.set_rng_state(ckpt["cuda_rng"], device)
