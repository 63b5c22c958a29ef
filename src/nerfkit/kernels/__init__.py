"""Fast operations of the grid field: compiled numba kernels beside pure-torch references.

:func:`numba_kernels` returns the compiled module (compiling it, or loading it from
numba's on-disk cache, on first use), or None when numba is not installed, is disabled
with ``NERFKIT_NO_NUMBA=1``, or fails to compile; callers then use the torch path, which
is also the path for CUDA tensors.
"""

from __future__ import annotations

import importlib
import os
import time
import warnings

_STATE: dict = {"tried": False, "module": None, "error": None, "seconds": 0.0}
_SPLAT: dict = {"tried": False, "module": None, "error": None, "seconds": 0.0}


def _load(state: dict, name: str, what: str):
    """Import and warm up the compiled module ``name`` once; None (with the reason in
    ``state["error"]``) without numba, with ``NERFKIT_NO_NUMBA=1`` or on a compile failure."""
    if not state["tried"]:
        state["tried"] = True
        if os.environ.get("NERFKIT_NO_NUMBA", "") not in ("", "0"):
            state["error"] = "disabled by NERFKIT_NO_NUMBA"
            return None
        start = time.perf_counter()
        try:
            module = importlib.import_module(f"{__name__}.{name}")
            module.warm_up()
        except Exception as e:  # ImportError, or a numba/LLVM failure: fall back to torch
            state["error"] = f"{type(e).__name__}: {e}"
            if not isinstance(e, ImportError):
                warnings.warn(
                    f"nerfkit: compiled {what} unavailable ({state['error']}); using the slower pure-torch path",
                    RuntimeWarning,
                    stacklevel=2,
                )
            return None
        state["module"] = module
        state["seconds"] = time.perf_counter() - start
    return state["module"]


def numba_kernels():
    """The compiled kernel module :mod:`nerfkit.kernels.grid_numba`, or None."""
    return _load(_STATE, "grid_numba", "kernels")


def splat_kernels():
    """The compiled splat rasterizer :mod:`nerfkit.kernels.splat_numba`, or None (as
    :func:`numba_kernels`)."""
    return _load(_SPLAT, "splat_numba", "splat kernels")


def kernel_status() -> dict:
    """``{"numba": bool, "warmup_seconds": float, "error": str | None}`` (loads the kernels)."""
    mod = numba_kernels()
    return {"numba": mod is not None, "warmup_seconds": _STATE["seconds"], "error": _STATE["error"]}


def numba_refused(splat: bool = False):
    """The NerfkitError for ``--kernels numba`` when the compiled kernels (the splat's, with
    ``splat``) did not load, saying why: switched off by NERFKIT_NO_NUMBA, numba missing, or
    a compile failure."""
    from ..errors import fail

    why = (_SPLAT if splat else _STATE)["error"] or "not loaded"
    if "NERFKIT_NO_NUMBA" in why:
        return fail("--kernels numba", f"the compiled kernels are {why}", "Unset it, or use --kernels auto")
    fix = "pip install 'nerfkit[fast]', or use --kernels auto"
    return fail("--kernels numba", f"the compiled kernels are not available ({why})", fix)
