"""Compact storage of a vertex grid for model files: occupied vertices only, in half precision.

Rendering samples only occupied cells (the occupancy grid), and a sample there
interpolates only the 8 corners of its cell. So the model file keeps the rows of the
vertices that touch an occupied cell (a bitmask over all vertices says which), the
density channel in float32 or float16 and the colour channels in float16; the model
maps every other vertex to a row of no density.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

F16_MAX = 65000.0


def vertices_touching(occ: Tensor) -> Tensor:
    """Which vertices are a corner of an occupied cell.

    Args:
        occ: (rz-1, ry-1, rx-1) cell occupancy (bool or 0/1).

    Returns:
        (rz * ry * rx,) bool, row-major like the flat vertex grid. Example: one occupied
        cell marks exactly its 8 corners.
    """
    cells = occ.float()[None, None]
    padded = F.pad(cells, (1, 1, 1, 1, 1, 1))  # a vertex on the border has cells on one side only
    return (F.max_pool3d(padded, kernel_size=2, stride=1)[0, 0] > 0).reshape(-1)


def pack_grid(rows: Tensor, keep: Tensor, density_dtype: torch.dtype = torch.float16) -> dict[str, Tensor]:
    """The features ``rows`` (M, C) of the vertices where ``keep`` (N,) bool is set (in
    vertex order), as tensors to save.

    Returns ``{"mask": (ceil(N / 8),) uint8 bits, "density": (M,) density_dtype,
    "colour": (M, C - 1) float16}``.
    """
    if rows.shape[0] != int(keep.sum()):
        raise ValueError(f"pack_grid: {rows.shape[0]} rows for {int(keep.sum())} kept vertices")
    rows = rows.detach().cpu()
    rows = rows.clamp(-F16_MAX, F16_MAX)  # float16 overflows past this (such values are saturated anyway)
    bits = np.packbits(keep.cpu().numpy().astype(np.uint8))
    return {
        "mask": torch.from_numpy(bits),
        "density": rows[:, 0].to(density_dtype).contiguous(),
        "colour": rows[:, 1:].to(torch.float16).contiguous(),
    }


def unpack_grid(packed: dict, n_rows: int, n_channels: int) -> tuple[Tensor, Tensor]:
    """Inverse of :func:`pack_grid`: ``(keep (n_rows,) bool, rows (M, n_channels) float32)``,
    the kept rows in order.

    Raises ValueError (one line) when the tensors do not fit a grid of that size; sizes
    are checked before the grid is allocated.
    """
    mask, density, colour = (packed.get(k) for k in ("mask", "density", "colour"))
    if not (isinstance(mask, Tensor) and isinstance(density, Tensor) and isinstance(colour, Tensor)):
        raise ValueError("compact grid: 'mask', 'density' or 'colour' is missing")
    n_bytes = -(-n_rows // 8)
    if mask.dtype != torch.uint8 or mask.shape != (n_bytes,):
        raise ValueError(
            f"compact grid: mask is {tuple(mask.shape)} {mask.dtype}, expected ({n_bytes},) uint8 for {n_rows} vertices"
        )
    keep = torch.from_numpy(np.unpackbits(mask.numpy(), count=n_rows).astype(bool))
    if bool(np.unpackbits(mask.numpy())[n_rows:].any()):
        raise ValueError("compact grid: mask has bits set past the last vertex")
    m = int(keep.sum())
    if density.dtype not in (torch.float16, torch.float32) or density.shape != (m,):
        raise ValueError(
            f"compact grid: density is {tuple(density.shape)} {density.dtype}, expected ({m},) float16 or float32"
        )
    if colour.dtype != torch.float16 or colour.shape != (m, n_channels - 1):
        raise ValueError(
            f"compact grid: colour is {tuple(colour.shape)} {colour.dtype}, expected ({m}, {n_channels - 1}) float16"
        )
    return keep, torch.cat([density.float()[:, None], colour.float()], dim=1)


__all__ = ["pack_grid", "unpack_grid", "vertices_touching"]
