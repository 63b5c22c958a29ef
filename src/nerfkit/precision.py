"""Device and numeric precision: decided once per command, then passed down (a
``torch.device``, and an autocast dtype).

:func:`resolve_device` turns ``--device`` into the device.

``--precision`` is ``auto``, ``fp32`` or ``bf16``. :func:`resolve_precision` turns it into
the dtype handed to every place that runs a network (training steps, the vanilla model's
occupancy refresh, rendering): ``torch.bfloat16`` or ``None`` for plain float32.
:func:`autocast` is the one context those places enter.
"""

from __future__ import annotations

from pathlib import Path

import torch

from .errors import fail

PRECISIONS = ("auto", "fp32", "bf16")


def cpu_has_native_bf16() -> bool:
    """True when the CPU does bf16 dot products natively.

    Reads the Linux /proc/cpuinfo flags (``avx512_bf16`` or ``amx_bf16``); elsewhere asks
    oneDNN (mkldnn) whether it has a bf16 path.
    """
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return bool(torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported())
    return "avx512_bf16" in flags or "amx_bf16" in flags


def resolve_precision(name: str, device: torch.device) -> torch.dtype | None:
    """``auto``/``fp32``/``bf16`` -> the autocast dtype (``None``: plain float32).

    ``auto`` picks bf16 where the device has it natively (a CUDA GPU with bf16, or a CPU
    with avx512_bf16/amx), else float32; ``fp32`` is always ``None``.
    """
    if name not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {name!r}")
    if name == "fp32":
        return None
    if name == "bf16":
        return torch.bfloat16
    if device.type == "cuda":  # native bf16 from Ampere (compute capability 8.0) on; older GPUs only emulate it
        return torch.bfloat16 if torch.cuda.get_device_capability(device) >= (8, 0) else None
    return torch.bfloat16 if device.type == "cpu" and cpu_has_native_bf16() else None


def resolve_device(name: str) -> torch.device:
    """``--device`` (auto, cpu, cuda or cuda:N) -> the device every part of a command then
    runs on; one that is not there is one error naming the flag. A GPU asked for by number
    becomes the current one."""
    if not isinstance(name, str):
        raise fail("--device", f"{name!r} is not a device", "Use auto, cpu, cuda or cuda:N")
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
            raise fail(
                "--device",
                f"'{name}' asks for GPU {device.index}, but this machine has {count} "
                f"(cuda:0{f' to cuda:{count - 1}' if count > 1 else ''})",
                "Use --device cuda",
            )
        torch.cuda.set_device(device)  # what asks for "the current GPU" (bf16 support, gsplat) asks this one
    return device


def autocast(device: torch.device | str, dtype: torch.dtype | None):
    """The autocast context for a resolved precision: disabled (plain float32) for ``None``."""
    device_type = device if isinstance(device, str) else device.type
    if dtype is None:
        return torch.autocast(device_type, enabled=False)
    return torch.autocast(device_type, dtype=dtype)


__all__ = ["PRECISIONS", "autocast", "cpu_has_native_bf16", "resolve_device", "resolve_precision"]
