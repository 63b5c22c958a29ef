"""An occupancy grid as an estimator module (nerfacc's ``OccGridEstimator``).

The estimator owns everything about empty-space skipping: its cells' occupancy (buffers,
saved in the model's ``state_dict`` so that a resumed run samples as the uninterrupted
one would), when it refreshes (:meth:`OccupancyEstimator.update_every_n_steps`: the
model calls it every step, the estimator decides), how it refreshes (from an exact bound
of each cell's density, or from a decayed running maximum of the density measured at a
random point per cell) and the sampling (:meth:`OccupancyEstimator.sampling`, and the
:class:`~nerfkit.kernels.ops.MarchSpec` the compiled marcher reads).

It never sees a model: only functions of points (``occ_eval_fn``, ``sigma_fn``) or cell
arrays the caller computed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..kernels.ops import MarchSpec
from ..render.box import GridBox, ray_aabb
from ..render.occupancy import RaySamples, is_occupied, occupied_samples


@dataclass(frozen=True)
class RefreshRule:
    """When an estimator refreshes, counted in steps done ``n``: from ``first`` on, every
    ``warmup_every`` steps while ``n <= warmup_until``, then every ``every`` steps.

    Example: ``RefreshRule(first=16, every=16)`` refreshes at 16, 32, 48, ...
    """

    first: int
    every: int
    warmup_every: int | None = None
    warmup_until: int = -1

    def due(self, n: int) -> bool:
        every = self.warmup_every if (self.warmup_every is not None and n <= self.warmup_until) else self.every
        return n >= self.first and n % max(every, 1) == 0


def coarse_cells(occ: Tensor, factor: int) -> Tensor:
    """Occupancy (cz, cy, cx) max-pooled by ``factor`` (ceil) per axis, for skipping big
    empty blocks: (ceil(cz / f), ceil(cy / f), ceil(cx / f)) bool."""
    if factor <= 1:
        return occ.bool()
    x = occ.float()[None, None]
    return F.max_pool3d(x, factor, factor, ceil_mode=True)[0, 0] > 0


class OccupancyEstimator(nn.Module):
    """A binary occupancy grid over the cells of a :class:`GridBox`.

    Args:
        box: the grid's box (cells ``res - 1`` per axis).
        rule: when :meth:`update_every_n_steps` refreshes (None: never by itself).
        coarse_factor: block size of the coarse occupancy the compiled marcher skips by.
        running_max: keep a per-cell density estimate (``cell_sigma``, inf until measured)
            refreshed as a decayed running maximum (:meth:`measure`); the occupancy is then
            derived from it and not saved itself.

    Buffers:
        occ: (rz - 1, ry - 1, rx - 1) uint8, 1 = occupied (every cell until a refresh).
        coarse: :func:`coarse_cells` of ``occ`` (uint8, derived, not saved).
        cell_sigma: (rz - 1, ry - 1, rx - 1) float32 (``running_max`` only).
    """

    lo: Tensor
    occ: Tensor
    coarse: Tensor
    cell_sigma: Tensor

    def __init__(
        self,
        box: GridBox,
        rule: RefreshRule | None = None,
        coarse_factor: int = 1,
        running_max: bool = False,
        device: torch.device | str | None = None,
    ):
        super().__init__()
        self.rule = rule
        self.coarse_factor = int(coarse_factor)
        self.running_max = running_max
        self.active = False  # whether a refresh ran (before it, every cell is occupied)
        self.box = box
        self.register_buffer("lo", box.lo_tensor(device), persistent=False)
        self.register_buffer(
            "occ", torch.ones(box.cell_shape, dtype=torch.uint8, device=device), persistent=not running_max
        )
        self.register_buffer("coarse", torch.ones(1, dtype=torch.uint8, device=device), persistent=False)
        if running_max:
            self.register_buffer("cell_sigma", torch.full(box.cell_shape, float("inf"), device=device))
        self.set_cells(self.occ)

    # -- the box ---------------------------------------------------------------------
    def set_box(self, box: GridBox) -> None:
        """Move to a new box; every cell is occupied until the next refresh."""
        device = self.occ.device
        self.box = box
        self.lo = box.lo_tensor(device)
        self.set_cells(torch.ones(box.cell_shape, dtype=torch.uint8, device=device))

    @property
    def hi(self) -> Tensor:
        return self.box.hi_tensor(self.lo.device)

    @property
    def occupied_fraction(self) -> float:
        return float(self.occ.float().mean())

    @property
    def measured(self) -> bool:
        """Whether a running-max estimator has measured every cell once."""
        return not self.running_max or not bool(torch.isinf(self.cell_sigma).any())

    # -- refreshing ------------------------------------------------------------------
    def update_every_n_steps(self, steps_done: int, refresh: Callable[[], None]) -> bool:
        """Run ``refresh`` (one of :meth:`set_cells`, :meth:`set_from_cell_sigma`,
        :meth:`measure`, bound to the caller's field) when :attr:`rule` says a refresh is
        due after ``steps_done`` steps. Returns whether it ran."""
        if self.rule is None or not self.rule.due(steps_done):
            return False
        refresh()
        self.active = True
        return True

    def set_cells(self, occ: Tensor, coarse: Tensor | None = None) -> None:
        """Install a cell occupancy (rz - 1, ry - 1, rx - 1) (nonzero = occupied), and its
        block max-pool when the caller computed it."""
        if tuple(occ.shape) != self.box.cell_shape:
            raise ValueError(
                f"occupancy has shape {tuple(occ.shape)}, expected {self.box.cell_shape} for {self.box.res} vertices"
            )
        self.occ = occ.to(torch.uint8).contiguous()
        if coarse is None:
            coarse = coarse_cells(self.occ, self.coarse_factor)
        self.coarse = coarse.to(torch.uint8).contiguous()

    def set_from_cell_sigma(self, sigma_max: Tensor, step: float, alpha_thre: float) -> None:
        """Mark cells whose largest density gives ``alpha = 1 - exp(-sigma step) > alpha_thre``.

        Args:
            sigma_max: (rz - 1, ry - 1, rx - 1) an upper bound of the density inside each cell.
        """
        if tuple(sigma_max.shape) != self.box.cell_shape:
            raise ValueError(f"sigma_max has shape {tuple(sigma_max.shape)}, expected {self.box.cell_shape}")
        self.set_cells((-torch.expm1(-sigma_max * step)) > alpha_thre)

    @torch.no_grad()
    def measure(
        self, occ_eval_fn: Callable[[Tensor], Tensor], step: float, alpha_thre: float, decay: float, chunk: int = 65536
    ) -> None:
        """Re-measure each cell's density at a random point inside it, as a running maximum
        decayed by ``decay`` per refresh (instant-ngp), then threshold it
        (:meth:`set_from_cell_sigma`). ``occ_eval_fn``: (m, 3) points -> (m,) density."""
        cz, cy, cx = self.box.cell_shape
        device = self.cell_sigma.device
        idx = torch.stack(
            torch.meshgrid(
                torch.arange(cz, device=device),
                torch.arange(cy, device=device),
                torch.arange(cx, device=device),
                indexing="ij",
            ),
            -1,
        ).reshape(-1, 3)
        xyz = idx.flip(-1).float() + torch.rand(idx.shape, device=device)  # (z, y, x) index -> x, y, z
        pts = self.lo + xyz * self.box.voxel
        sigma = torch.cat([occ_eval_fn(part) for part in pts.split(chunk)]).reshape(cz, cy, cx)
        old = torch.where(torch.isinf(self.cell_sigma), torch.zeros_like(sigma), self.cell_sigma)
        self.cell_sigma.copy_(torch.maximum(old * decay, sigma.float()))
        self.refresh_from_running_max(step, alpha_thre)

    def refresh_from_running_max(self, step: float, alpha_thre: float) -> None:
        """The occupancy from the saved running maximum (after loading a state)."""
        self.set_from_cell_sigma(self.cell_sigma, step, alpha_thre)

    # -- sampling --------------------------------------------------------------------
    def is_occupied(self, points: Tensor) -> Tensor:
        """(m, 3) world points -> (m,) bool: is the cell holding each point occupied."""
        return is_occupied(self.occ, self.box, points)

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
        """Samples along rays that skip empty cells (and, with ``sigma_fn``, stop early):
        :func:`~nerfkit.render.occupancy.occupied_samples` over ``[t0, t1)`` (default
        :meth:`ray_bounds`), the jitter ``u`` random with ``perturb`` else 0.5;
        ``use_occupancy`` False samples every lattice point (the reference for tests)."""
        n = rays_o.shape[0]
        t0, t1 = t_bounds if t_bounds is not None else self.ray_bounds(rays_o, rays_d, near, far)
        if u is None:
            u = (
                torch.rand(n, generator=generator, device=rays_o.device, dtype=rays_o.dtype)
                if perturb
                else torch.full((n,), 0.5, device=rays_o.device, dtype=rays_o.dtype)
            )
        return occupied_samples(
            self.occ if use_occupancy else None,
            self.box,
            rays_o,
            rays_d,
            t0,
            t1,
            u,
            step,
            sigma_fn,
            early_stop_eps,
            alpha_thre,
        )

    def march_spec(self, step: float, eps: float, density_scale: float, grad_near: float = 0.0) -> MarchSpec:
        """What the compiled marcher needs besides the rays and the field."""
        return MarchSpec(self.occ, self.coarse, self.coarse_factor, step, eps, density_scale, grad_near)


__all__ = ["OccupancyEstimator", "RefreshRule", "coarse_cells"]
