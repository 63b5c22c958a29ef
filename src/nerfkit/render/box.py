"""The box of a vertex grid: one value shared by the grid field, the occupancy estimator
and the marchers.

A :class:`GridBox` is the box ``[lo, lo + voxel * (res - 1)]`` cut into ``res - 1`` cubic
cells of side ``voxel`` per axis (``res = (rx, ry, rz)`` vertex counts). A point's cell is
``floor((p - lo) / voxel)`` clamped into the box (:func:`cell_of`), the rule the compiled
kernels use too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
import torch
from torch import Tensor


@dataclass(frozen=True)
class GridBox:
    """Box corner ``lo`` (3 floats), cubic ``voxel`` and vertex counts ``res`` (rx, ry, rz).

    Example: ``GridBox((0, 0, 0), 0.5, (3, 5, 2))`` spans [0, 1] x [0, 2] x [0, 0.5] and has
    (1, 4, 2) cells (z, y, x order: :attr:`cell_shape`).
    """

    lo: tuple[float, float, float]
    voxel: float
    res: tuple[int, int, int]

    def __post_init__(self):
        object.__setattr__(self, "lo", tuple(float(v) for v in np.asarray(self.lo, np.float64).reshape(3)))
        object.__setattr__(self, "voxel", float(self.voxel))
        object.__setattr__(self, "res", tuple(int(r) for r in self.res))
        if len(self.res) != 3 or min(self.res) < 2:
            raise ValueError(f"a grid box needs at least 2 vertices per axis, got {self.res}")

    @staticmethod
    def fit(lo: np.ndarray, hi: np.ndarray, size: int) -> GridBox:
        """A box of about ``size ** 3`` vertices with cubic voxels covering ``[lo, hi]``,
        centred on it (corner rounded to float32, as the grid stores it)."""
        ext = np.maximum(hi - lo, 1e-6)
        voxel = float(np.cbrt(np.prod(ext)) / max(size - 1, 1))
        res = np.maximum(np.ceil(ext / voxel - 1e-6).astype(int) + 1, 2)
        center = 0.5 * (lo + hi)
        new_lo = (center - 0.5 * voxel * (res - 1)).astype(np.float32)
        # res has one entry per axis of lo / hi (3; __post_init__ checks it)
        return GridBox(tuple(new_lo), voxel, cast(tuple[int, int, int], tuple(int(r) for r in res)))

    def lo_tensor(self, device=None, dtype: torch.dtype = torch.float32) -> Tensor:
        """(3,) ``lo`` as a tensor."""
        return torch.tensor(self.lo, dtype=dtype, device=device)

    def hi_tensor(self, device=None, dtype: torch.dtype = torch.float32) -> Tensor:
        """(3,) the far corner ``lo + voxel * (res - 1)``, computed in ``dtype``."""
        lo = self.lo_tensor(device, dtype)
        return lo + self.voxel * torch.tensor([r - 1 for r in self.res], dtype=dtype, device=device)

    @property
    def lo_array(self) -> np.ndarray:
        return np.asarray(self.lo, np.float32)

    @property
    def hi_array(self) -> np.ndarray:
        return self.hi_tensor().numpy()

    @property
    def cell_shape(self) -> tuple[int, int, int]:
        """``(rz - 1, ry - 1, rx - 1)``: the shape of a per-cell array."""
        rx, ry, rz = self.res
        return rz - 1, ry - 1, rx - 1

    @property
    def n_vertices(self) -> int:
        rx, ry, rz = self.res
        return rx * ry * rz

    def to_dict(self) -> dict:
        return {"lo": list(self.lo), "voxel": self.voxel, "res": list(self.res)}


def grid_coords(points: Tensor, lo: Tensor, voxel: float) -> Tensor:
    """World points (n, 3) -> continuous grid coordinates (n, 3): ``(p - lo) / voxel``."""
    return (points - lo) / voxel


def cell_of(g: Tensor, res: tuple[int, int, int]) -> Tensor:
    """The cell (n, 3) long ``(ix, iy, iz)`` holding grid coordinates ``g`` (n, 3).

    Coordinates are clamped into the box first, so every point has a cell in
    ``[0, res - 2]`` per axis. The same rule picks the trilinear base vertex and the
    occupancy cell, in both the reference and the compiled kernels.
    """
    hi = torch.tensor([r - 1 for r in res], dtype=g.dtype, device=g.device)
    gc = torch.minimum(torch.clamp(g, min=0.0), hi)
    i0 = torch.minimum(torch.floor(gc), hi - 1)
    return i0.long()


def ray_aabb(rays_o: Tensor, rays_d: Tensor, lo: Tensor, hi: Tensor, near: float, far: float) -> tuple[Tensor, Tensor]:
    """Where rays are inside a box and inside ``[near, far]``.

    Args:
        rays_o, rays_d: (n, 3) origins and directions.
        lo, hi: (3,) box corners.

    Returns:
        ``(t0, t1)``, each (n,); a ray misses when ``t1 <= t0``.

    Example: origin (0, 0, -5), direction +z, box [-1, 1]^3, near 0, far 10 -> (4, 6).
    """
    d = torch.where(rays_d.abs() < 1e-12, torch.full_like(rays_d, 1e-12), rays_d)
    inv = 1.0 / d
    ta = (lo - rays_o) * inv
    tb = (hi - rays_o) * inv
    t_enter = torch.minimum(ta, tb).amax(dim=-1)
    t_exit = torch.maximum(ta, tb).amin(dim=-1)
    t0 = torch.clamp(t_enter, min=near)
    t1 = torch.clamp(t_exit, max=far)
    return t0, t1
