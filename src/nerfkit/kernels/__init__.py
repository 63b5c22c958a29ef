"""Fast operations of the grid field: compiled numba kernels beside pure-torch references.

:func:`numba_kernels` returns the compiled module (compiling it, or loading it from
numba's on-disk cache, on first use), or None when numba is not installed, is disabled
with ``NERFKIT_NO_NUMBA=1``, or fails to compile; callers then use the torch path, which
is also the path for CUDA tensors.
"""

from __future__ import annotations

import os
import time
import warnings

_STATE: dict = {"tried": False, "module": None, "error": None, "seconds": 0.0}


def numba_kernels():
    """The compiled kernel module :mod:`nerfkit.kernels.grid_numba`, or None."""
    if not _STATE["tried"]:
        _STATE["tried"] = True
        if os.environ.get("NERFKIT_NO_NUMBA", "") not in ("", "0"):
            _STATE["error"] = "disabled by NERFKIT_NO_NUMBA"
            return None
        start = time.perf_counter()
        try:
            from . import grid_numba

            grid_numba.warm_up()
        except Exception as e:  # ImportError, or a numba/LLVM failure: fall back to torch
            _STATE["error"] = f"{type(e).__name__}: {e}"
            if not isinstance(e, ImportError):
                warnings.warn(f"nerfkit: compiled kernels unavailable ({_STATE['error']}); using the slower "
                              "pure-torch path", RuntimeWarning, stacklevel=2)
            return None
        _STATE["module"] = grid_numba
        _STATE["seconds"] = time.perf_counter() - start
    return _STATE["module"]


_SPLAT: dict = {"tried": False, "module": None, "error": None}


def splat_kernels():
    """The compiled splat rasterizer :mod:`nerfkit.kernels.splat_numba`, or None (as
    :func:`numba_kernels`: no numba, ``NERFKIT_NO_NUMBA=1``, or a compile failure)."""
    if not _SPLAT["tried"]:
        _SPLAT["tried"] = True
        if os.environ.get("NERFKIT_NO_NUMBA", "") not in ("", "0"):
            _SPLAT["error"] = "disabled by NERFKIT_NO_NUMBA"
            return None
        try:
            from . import splat_numba

            splat_numba.warm_up()
        except Exception as e:  # ImportError, or a numba/LLVM failure: fall back to torch
            _SPLAT["error"] = f"{type(e).__name__}: {e}"
            if not isinstance(e, ImportError):
                warnings.warn(f"nerfkit: compiled splat kernels unavailable ({_SPLAT['error']}); using the slower "
                              "pure-torch path", RuntimeWarning, stacklevel=2)
            return None
        _SPLAT["module"] = splat_numba
    return _SPLAT["module"]


def kernel_status() -> dict:
    """``{"numba": bool, "warmup_seconds": float, "error": str | None}`` (loads the kernels)."""
    mod = numba_kernels()
    return {"numba": mod is not None, "warmup_seconds": _STATE["seconds"], "error": _STATE["error"]}
