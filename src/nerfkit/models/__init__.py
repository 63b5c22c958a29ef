"""Radiance-field models, by name.

``vanilla``: the course NeRF (8x256 MLP with positional encoding).
``fast``: grid-based field with empty-space skipping, practical on a CPU.
``splat``: 3D Gaussian splatting, rasterized tile by tile (compiled kernels on a CPU).
"""

from __future__ import annotations

import importlib
from dataclasses import asdict, fields
from typing import TYPE_CHECKING, Any

from ..config import check_ranges
from ..errors import fail
from .base import NerfModel, RenderOutput, SceneBounds

if TYPE_CHECKING:
    import torch

# name -> (module, model class, config dataclass)
_REGISTRY = {
    "vanilla": ("nerfkit.models.vanilla", "VanillaNeRF", "VanillaConfig"),
    "fast": ("nerfkit.models.fast", "FastNeRF", "FastConfig"),
    "splat": ("nerfkit.models.splat", "SplatModel", "SplatConfig"),
}

MODEL_NAMES = tuple(_REGISTRY)


def model_config_class(name: str):
    module, _, cfg = _REGISTRY[name]
    return getattr(importlib.import_module(module), cfg)


def check_config(name: str, config: Any, device: torch.device | None = None) -> Any:
    """``config`` of model ``name`` checked against its own bounds (:func:`check_ranges`), naming the
    model: `nerfkit train` parses a flag that models share within the widest of their bounds
    (``--sh-degree 3`` is splat's limit; fast's is 2), then by its own ``validate`` where
    it has one (fast's grid stages, splat's densification window). On a ``device`` that is
    not the CPU, ``--kernels numba`` (compiled for the CPU) is refused rather than ignored."""
    if device is not None and device.type != "cpu" and getattr(config, "kernels", None) == "numba":
        raise fail(
            "--kernels numba",
            f"the compiled kernels run on the CPU only, and this run trains on {device}",
            "Use --kernels auto (on CUDA: gsplat for splat when installed, else torch) or --kernels torch",
        )
    config = check_ranges(config, owner=f"the {name} model")
    return config.validate() if hasattr(config, "validate") else config


def build_model(name: str, config: Any, bounds: SceneBounds) -> NerfModel:
    module, cls, _ = _REGISTRY[name]
    return getattr(importlib.import_module(module), cls)(config, bounds)


def config_from_dict(name: str, d: dict):
    cls = model_config_class(name)
    known = {f.name for f in fields(cls)}
    return cls(**{k: v for k, v in d.items() if k in known})


__all__ = [
    "MODEL_NAMES",
    "NerfModel",
    "RenderOutput",
    "SceneBounds",
    "asdict",
    "build_model",
    "check_config",
    "config_from_dict",
    "model_config_class",
]
