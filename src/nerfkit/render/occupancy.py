"""Empty-space skipping: ray marching through a binary occupancy grid over a box (pure functions).

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
(:func:`nerfkit.render.box.cell_of`), the same rule the fused kernels use. The estimator that
owns an occupancy grid and its refresh is :mod:`nerfkit.estimators.occupancy`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .box import GridBox, cell_of, grid_coords, ray_aabb
from .volrend import render_weights


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

    def select(self, keep: Tensor) -> RaySamples:
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


def is_occupied(occ: Tensor, box: GridBox, points: Tensor) -> Tensor:
    """(m, 3) world points -> (m,) bool: is the cell of ``box`` holding each point set in
    ``occ`` ((rz - 1, ry - 1, rx - 1), nonzero = occupied)."""
    c = cell_of(grid_coords(points, box.lo_tensor(points.device, points.dtype), box.voxel), box.res)
    return occ[c[:, 2], c[:, 1], c[:, 0]].bool()


@torch.no_grad()
def occupied_samples(
    occ: Tensor | None,
    box: GridBox,
    rays_o: Tensor,
    rays_d: Tensor,
    t0: Tensor,
    t1: Tensor,
    u: Tensor,
    step: float,
    sigma_fn=None,
    early_stop_eps: float = 1e-4,
    alpha_thre: float = 0.0,
) -> RaySamples:
    """The lattice samples of each ray's segment ``[t0, t1)`` that lie in occupied cells
    (``occ`` None: every cell) and, with ``sigma_fn``, in front of opaque matter.

    Args:
        occ: (rz - 1, ry - 1, rx - 1) cell occupancy of ``box`` (nonzero = occupied), or None.
        rays_o, rays_d: (n, 3); t0, t1, u: (n,) segment and lattice jitter in [0, 1).
        step: lattice spacing (the interval of every sample).
        sigma_fn: optional ``(points (m, 3), ray_indices (m,)) -> (m,)`` density, used
            (without gradient) to drop samples behind opaque matter (transmittance
            below ``early_stop_eps``) and samples with alpha below ``alpha_thre``.

    Returns:
        :class:`RaySamples` (packed), samples in increasing ``t`` per ray.
    """
    samples = lattice(t0, t1, u, step)
    if occ is not None and samples.n_samples:
        samples = samples.select(is_occupied(occ, box, samples.points(rays_o, rays_d)))
    if sigma_fn is not None and samples.n_samples:
        sig = sigma_fn(samples.points(rays_o, rays_d), samples.ray_indices).float()
        _, trans, alphas = render_weights(sig, step, samples.ray_indices)
        keep = trans >= early_stop_eps
        if alpha_thre > 0:
            keep &= alphas >= alpha_thre
        samples = samples.select(keep)
    return samples


__all__ = ["GridBox", "RaySamples", "is_occupied", "lattice", "occupied_samples", "ray_aabb"]
