"""nerfkit: phone photos to neural radiance fields, practical on a CPU.

The course API lives here under its familiar names, and the pipeline's
(:mod:`nerfkit.api`: ``api.calibrate``, ``api.pose``, ``api.train``, ``api.render``, ...);
see :mod:`nerfkit.cameras` for the one camera convention (OpenCV axes, pixel centres at +0.5). The names are imported on
first use, so ``import nerfkit`` (and ``nerfkit --help``) does not pay for torch.
"""

from __future__ import annotations

import importlib
import os

# OpenMP threads that finish a parallel region sleep instead of spinning. Two OpenMP pools
# share the cores during training (torch's and the compiled kernels'), and a pool's
# spinning threads starve the other's work and the main thread: with both spinning, the
# fast model's step took about twice as long on 2 loaded cores (same results). Set here,
# before torch or numba load their OpenMP runtimes (which read it once); a value the user
# set wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"

_API = {
    "NeRFMLP": "nerfkit.models.vanilla",
    "Rays": "nerfkit.cameras",
    "RaysData": "nerfkit.data.rays",
    "VanillaConfig": "nerfkit.models.vanilla",
    "pixel_to_camera": "nerfkit.cameras",
    "pixel_to_ray": "nerfkit.cameras",
    "transform": "nerfkit.cameras",
    "positional_encoding": "nerfkit.fields.encoding",
    "sample_along_rays": "nerfkit.render.sampling",
    "volrend": "nerfkit.render.volrend",
    # the pipeline (nerfkit.api; its train, render, export and capture share their names with the
    # subpackages nerfkit.train, nerfkit.render, nerfkit.capture and the module nerfkit.export: call
    # them as api.train, ...)
    "api": None,
    "calibrate": "nerfkit.api",
    "pose": "nerfkit.api",
    "evaluate": "nerfkit.api",
    "resume": "nerfkit.api",
    "CaptureResult": "nerfkit.api",
    "CalibrationResult": "nerfkit.api",
    "PoseResult": "nerfkit.api",
    "TrainResult": "nerfkit.api",
    "RenderResult": "nerfkit.api",
    "EvaluationResult": "nerfkit.api",
    "ExportResult": "nerfkit.api",
}

__all__ = sorted(_API)


def __getattr__(name: str):
    if name in _API:
        module = _API[name]
        value = (
            importlib.import_module(f"nerfkit.{name}")
            if module is None
            else getattr(importlib.import_module(module), name)
        )
        globals()[name] = value
        return value
    raise AttributeError(f"module 'nerfkit' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_API))
