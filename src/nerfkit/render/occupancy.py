"""Empty-space skipping: a binary occupancy grid over a box, and ray marching through it.

The estimator's contract is narrow (as in nerfacc): it never sees a model, only an
optional ``sigma_fn(points (m, 3), ray_indices (m,)) -> (m,)`` used to stop rays early.

Samples lie on a per-ray lattice ``t_k = t0 + (k + u) * step`` (``k = 0, 1, ...``) where
``[t0, t1)`` is the part of the ray inside the box and inside ``[near, far]``, and
``u`` in ``[0, 1)`` is a per-ray jitter (0.5 without ``perturb``). A lattice sample is
kept when the cell holding it is occupied and, with ``sigma_fn``, while the
transmittance in front of it is at least ``early_stop_eps``. Every sample stands for an
interval of length ``step``.

Cells: the box ``[lo, lo + voxel * (res - 1)]`` is cut into ``res - 1`` cubic cells of side
``voxel`` per axis; a point's cell is ``floor((p - lo) / voxel)`` clamped into the box
(:func:`nerfkit.kernels.reference.cell_of`), the same rule the fused kernels use.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..kernels.reference import cell_of, grid_coords
from .volrend import render_weights


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


@dataclass
class RaySamples:
    """Samples along rays in the packed layout (:mod:`nerfkit.render.volrend`).

    Attributes:
        t: (n_samples,) sample distances, increasing along each ray.
        ray_indices: (n_samples,) long, non-decreasing: the ray of each sample.
        n_rays: rays in the batch (some may have no samples).
        step: interval length of every sample.
    """

    t: Tensor
    ray_indices: Tensor
    n_rays: int
    step: float

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    def counts(self) -> Tensor:
        """(n_rays,) long: how many samples each ray has."""
        return torch.bincount(self.ray_indices, minlength=self.n_rays)

    def points(self, rays_o: Tensor, rays_d: Tensor) -> Tensor:
        """(n_samples, 3) world points ``o + t d`` of the samples."""
        ri = self.ray_indices
        return rays_o[ri] + self.t.unsqueeze(-1) * rays_d[ri]

    def select(self, keep: Tensor) -> "RaySamples":
        """The samples where ``keep`` (n_samples,) bool is set, in order."""
        return RaySamples(self.t[keep], self.ray_indices[keep], self.n_rays, self.step)


def lattice(t0: Tensor, t1: Tensor, u: Tensor, step: float) -> RaySamples:
    """All lattice samples ``t0 + (k + u) step < t1`` (``k = 0, 1, ...``), packed.

    Each ray gets ``ceil((t1 - t0) / step) + 1`` candidates (a bound on its count, so no
    padding to the longest ray); the test ``t < t1`` on the computed ``t`` then decides,
    exactly as the compiled marcher does.

    Args:
        t0, t1, u: (n,) segment ends and jitter in [0, 1); step: lattice spacing.
    """
    n = t0.shape[0]
    span = torch.clamp(t1 - t0, min=0.0)
    bound = torch.where(t1 > t0, torch.ceil(span / step).long() + 1, torch.zeros_like(span, dtype=torch.long))
    rays = torch.repeat_interleave(torch.arange(n, device=t0.device), bound)
    first = torch.cumsum(bound, 0) - bound  # index of each ray's first candidate
    k = torch.arange(rays.shape[0], device=t0.device) - first[rays]
    t = t0[rays] + (k.to(t0.dtype) + u[rays]) * step
    inside = t < t1[rays]
    return RaySamples(t[inside], rays[inside], n, step)


class OccupancyGrid(nn.Module):
    """A binary occupancy grid over the cells of a box (nerfacc's estimator: a module whose
    buffers follow its owner's device; they are derived state, so not saved).

    Args:
        lo: (3,) box corner; voxel: cell side; res: vertex counts ``(rx, ry, rz)``
            (cells ``res - 1`` per axis).
        device: where the grid lives.
        occ: (rz - 1, ry - 1, rx - 1) the cells' occupancy to start from (any dtype, nonzero
            = occupied); None: every cell occupied.

    Attributes:
        occ: (rz - 1, ry - 1, rx - 1) bool.
    """

    def __init__(self, lo, voxel: float, res: tuple[int, int, int], device: torch.device | str = "cpu",
                 occ: Tensor | None = None):
        super().__init__()
        self.voxel = float(voxel)
        self.res = tuple(int(r) for r in res)
        if min(self.res) < 2:
            raise ValueError(f"occupancy grid needs at least 2 vertices per axis, got {self.res}")
        rx, ry, rz = self.res
        shape = (rz - 1, ry - 1, rx - 1)
        if occ is None:
            occ = torch.ones(shape, dtype=torch.bool, device=device)
        elif tuple(occ.shape) != shape:
            raise ValueError(f"occupancy has shape {tuple(occ.shape)}, expected {shape} for {self.res} vertices")
        self.register_buffer("lo", torch.as_tensor(lo, dtype=torch.float32, device=device).reshape(3), persistent=False)
        self.register_buffer("occ", occ.to(device=device, dtype=torch.bool), persistent=False)

    @property
    def hi(self) -> Tensor:
        return self.lo + self.voxel * torch.tensor([r - 1 for r in self.res], dtype=torch.float32,
                                                   device=self.lo.device)

    @property
    def occupied_fraction(self) -> float:
        return float(self.occ.float().mean())

    def set_from_cell_sigma(self, sigma_max: Tensor, step: float, alpha_thre: float) -> None:
        """Mark cells whose largest density gives ``alpha = 1 - exp(-sigma step) > alpha_thre``.

        Args:
            sigma_max: (rz - 1, ry - 1, rx - 1) an upper bound of the density inside each cell.
        """
        if sigma_max.shape != self.occ.shape:
            raise ValueError(f"sigma_max has shape {tuple(sigma_max.shape)}, expected {tuple(self.occ.shape)}")
        self.occ = (-torch.expm1(-sigma_max * step)) > alpha_thre

    def coarse(self, factor: int) -> Tensor:
        """Occupancy max-pooled by ``factor`` (ceil) per axis, for skipping big empty blocks:
        (ceil(cz / f), ceil(cy / f), ceil(cx / f)) bool."""
        if factor <= 1:
            return self.occ
        x = self.occ.float()[None, None]
        return F.max_pool3d(x, factor, factor, ceil_mode=True)[0, 0] > 0

    def is_occupied(self, points: Tensor) -> Tensor:
        """(m, 3) world points -> (m,) bool: is the cell holding each point occupied."""
        c = cell_of(grid_coords(points, self.lo.to(points.dtype), self.voxel), self.res)
        return self.occ[c[:, 2], c[:, 1], c[:, 0]]

    def ray_bounds(self, rays_o: Tensor, rays_d: Tensor, near: float, far: float) -> tuple[Tensor, Tensor]:
        """:func:`ray_aabb` against this grid's box."""
        return ray_aabb(rays_o, rays_d, self.lo.to(rays_o.dtype), self.hi.to(rays_o.dtype), near, far)

    @torch.no_grad()
    def sampling(
        self,
        rays_o: Tensor,
        rays_d: Tensor,
        near: float,
        far: float,
        step: float,
        sigma_fn=None,
        perturb: bool = False,
        early_stop_eps: float = 1e-4,
        alpha_thre: float = 0.0,
        u: Tensor | None = None,
        t_bounds: tuple[Tensor, Tensor] | None = None,
        use_occupancy: bool = True,
        generator: torch.Generator | None = None,
    ) -> RaySamples:
        """Samples along rays that skip empty cells (and, with ``sigma_fn``, stop early).

        Args:
            rays_o, rays_d: (n, 3) origins and unit directions.
            near, far: depth range; step: lattice spacing (the interval of every sample).
            sigma_fn: optional ``(points (m, 3), ray_indices (m,)) -> (m,)`` density, used
                (without gradient) to drop samples behind opaque matter (transmittance
                below ``early_stop_eps``) and samples with alpha below ``alpha_thre``.
            perturb: random per-ray jitter ``u``; else 0.5. ``u`` (n,) overrides both.
            t_bounds: precomputed ``(t0, t1)`` (default: :meth:`ray_bounds`).
            use_occupancy: False samples every lattice point (the reference for tests).

        Returns:
            :class:`RaySamples` (packed), samples in increasing ``t`` per ray.
        """
        n = rays_o.shape[0]
        t0, t1 = t_bounds if t_bounds is not None else self.ray_bounds(rays_o, rays_d, near, far)
        if u is None:
            u = (torch.rand(n, generator=generator, device=rays_o.device, dtype=rays_o.dtype) if perturb
                 else torch.full((n,), 0.5, device=rays_o.device, dtype=rays_o.dtype))
        samples = lattice(t0, t1, u, step)
        if use_occupancy and samples.n_samples:
            samples = samples.select(self.is_occupied(samples.points(rays_o, rays_d)))
        if sigma_fn is not None and samples.n_samples:
            sig = sigma_fn(samples.points(rays_o, rays_d), samples.ray_indices).float()
            _, trans, alphas = render_weights(sig, step, samples.ray_indices)
            keep = trans >= early_stop_eps
            if alpha_thre > 0:
                keep &= alphas >= alpha_thre
            samples = samples.select(keep)
        return samples
