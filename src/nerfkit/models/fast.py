"""``fast``: a grid radiance field that trains in about a minute on a CPU.

The field is a dense vertex grid over a box around the scene (a "Plenoxels/DVGO"-style
explicit field, no MLP): per vertex a raw density and spherical-harmonic colour
coefficients, trilinearly interpolated, then ``sigma = scale * softplus(raw)`` and
``rgb = sigmoid(SH(dir) . coef)``. It stays a true NeRF: view-dependent colour and the
volume-rendering math of :func:`~nerfkit.render.volrend.render_weights` /
:func:`~nerfkit.render.volrend.composite`.

Speed comes from counting samples, not steps:

* an occupancy grid (:mod:`nerfkit.estimators.occupancy`) built from an exact upper bound
  of the density in each cell skips empty space; rays stop once their transmittance
  falls below ``early_stop_eps``;
* coarse-to-fine growth of the grid; the box starts around the object (from the
  dataset's sparse points on the object, ``SceneBounds.object_box``), else as the cube around the scene's bounding
  sphere, which is loose; at the first growth it shrinks around where opaque training
  rays ended, and a capture's box follows its object out at later growths;
* memory that follows the content (as Plenoxels): from ``--sparse-from`` vertices a side,
  a grown grid stores feature rows only for the vertices near cells that were occupied
  before the growth; an int32 index maps every vertex to its row, and vertices without
  storage share row 0, which holds no density and is never updated. Adam's moments and
  the gradient buffers have the size of the stored rows, not of the cube;
* on the CPU one fused compiled kernel (numba, :mod:`nerfkit.kernels.grid_numba`) per
  ray, and Adam updating only the vertices a step touched
  (:class:`~nerfkit.kernels.optim.GridAdam`). On CUDA, or without numba, the same math
  runs in pure torch.

A forward-facing scene (``--space auto``/``ndc``: every camera looking about the same way,
as LLFF captures) puts the grid in the normalised device coordinates of the mean camera
(:mod:`nerfkit.render.ndc`), from the near plane to infinity: its rays are straight
there, so the same kernels march them; colour still follows the world direction.

The model composes three parts: the grid field (:mod:`nerfkit.fields.grid`), the occupancy
estimator, and, outside the box, either the background colour the trainer passes or the
capture's surroundings (:mod:`nerfkit.surroundings`: a learned room, and a surface where rays
stop, so that the box holds only the object). Growth and the box's moves are in
:mod:`nerfkit.models.grid_growth`, the loss terms in :mod:`nerfkit.losses`.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .. import losses
from ..cameras import Rays
from ..config import check_ranges
from ..errors import fail
from ..estimators.occupancy import OccupancyEstimator, RefreshRule
from ..fields.grid import EMPTY_RAW, GridField, check_grid_res, resample_grid
from ..kernels.ops import GridRender
from ..losses import robust
from ..losses.tv import GridTV, tv_weights
from ..render.box import GridBox, ray_aabb
from ..render.ndc import grid_scale, to_grid
from ..render.volrend import sight_line_loss
from ..surroundings import Surroundings, flat_background, renamed_keys
from . import grid_growth as growth
from .base import NerfModel, RenderOutput, SceneBounds, Schedule, StepState, rgb_errors, rgb_loss
from .fast_config import FastConfig
from .packing import pack_grid, unpack_grid, vertices_touching

__all__ = ["EMPTY_RAW", "FastNeRF", "check_grid_res", "resample_grid"]

# A sight line ends this far before its point and is stopped this far past it (and the spread,
# below): SIGHT_MARGIN
# scene radii (a voxel or two of the finest grid), and at least SIGHT_VOXELS
# voxels of the grid (a vertex's density spreads over a voxel each way: at the coarse
# stages a thinner margin would ask one vertex to be empty and solid at once).
SIGHT_MARGIN = 0.01
SIGHT_VOXELS = 2.0
# Each drawn line aims within SIGHT_SPREAD margins of its point (a few pixels of a capture's
# photos). Aimed at the point itself the lines made specks a voxel or two wide, the fur
# between them thinner; 5 margins left the object paler (`--points-weight` in BENCHMARKS.md).
# A drawn line must stop by as far past its spot as it was turned aside, not just the margin:
# beside a point on a curved surface (a can near its outline) the surface lies deeper than the
# point, and a stop held to the point's depth grew shards in front of it.
SIGHT_SPREAD = 2.5

# Model files store the grid sparsely (vertices of occupied cells) under this name, the
# density channel in this dtype; the other vertices get raw density EMPTY_RAW.
PACKING = "fast-sparse-grid-1"
PACKED_DENSITY_DTYPE = torch.float16
# state_dict keys of model files from before the grid field was a module of its own -> today's
RENAMED = {
    "grid": "field.grid",
    "vertex_rows": "field.vertex_rows",
    "occ_cells": "estimator.occ",
    "surface_pts": "surfaces.pts",
    "surface_count": "surfaces.count",
}


def renamed(state: dict) -> dict:
    """``state`` with the keys of an older model file (:data:`RENAMED`, and the surroundings'
    :func:`~nerfkit.surroundings.renamed_keys`) under today's names."""
    return renamed_keys({RENAMED.get(k, k): v for k, v in state.items()})


def grid_start(config: FastConfig, bounds: SceneBounds) -> tuple[np.ndarray, np.ndarray]:
    """The first box of the grid: NDC's slab, else the object's box, else the scene's cube."""
    if config.space == "ndc" and bounds.ndc is None:
        raise fail(
            "--space ndc",
            "the scene is not forward-facing (its cameras look different ways)",
            "Use --space box (or auto)",
        )
    if bounds.ndc is not None and config.space != "box":
        half = bounds.ndc.extent * np.array(ndc_grid_scale(config, bounds.ndc), np.float32)
        half[2] = config.ndc_depth_scale  # (Z spans [-1, 1] in NDC whatever the extent)
        return -half, half
    c = np.asarray(bounds.center, np.float32)
    if config.object_box and bounds.object_box is not None:
        return widened(bounds.object_box, config.object_box_margin, c, bounds.radius)
    return c - bounds.radius, c + bounds.radius


def widened(box, margin: float, center: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """``box`` ``(lo, hi)`` (3,) each, widened on every side by ``margin`` times its size
    along that axis, within the cube of half-side ``radius`` about ``center``."""
    lo, hi = (np.asarray(b, np.float32) for b in box)
    if margin <= 0:
        return lo, hi
    pad = margin * (hi - lo)
    return np.maximum(lo - pad, center - radius), np.minimum(hi + pad, center + radius)


def ndc_grid_scale(config: FastConfig, ndc) -> tuple[float, float, float]:
    """The factors (X, Y, Z) from NDC to the grid's space: :func:`~nerfkit.render.ndc.grid_scale`
    of the reference photo with ``--ndc-depth-scale`` and ``--ndc-square-pixels``."""
    return grid_scale(ndc.width, ndc.height, config.ndc_depth_scale, bool(config.ndc_square_pixels))


class FastNeRF(NerfModel):
    """Grid field + occupancy estimator + surroundings (see the module docstring)."""

    def __init__(self, config: FastConfig, bounds: SceneBounds):
        super().__init__(bounds)
        self.config = c = check_ranges(config)
        self.sizes, self.steps = c.stages()
        self.ray_factors = c.stage_ray_factors()
        box = GridBox.fit(*grid_start(c, bounds), self.sizes[0])
        self.ndc = bounds.ndc if c.space != "box" else None
        self.ndc_scale = None if self.ndc is None else ndc_grid_scale(c, self.ndc)
        self.stage = 0
        # the occupancy grid (saved with the model, so that a resumed run samples as the
        # uninterrupted one would), refreshed after every occ_start steps until occ_warmup,
        # then every occ_every
        rule = RefreshRule(c.occ_start, c.occ_every, c.occ_start, c.occ_warmup)
        self.estimator = OccupancyEstimator(box, rule, c.coarse_factor)
        self.field = GridField(box, c.sh_degree, c.kernels)  # densities per voxel of the first box
        with torch.no_grad():
            self.field.grid[1:, 0] = self.field.raw_for_alpha(c.init_alpha, c.step_ratio * box.voxel)
        self.surroundings = Surroundings.build(c, bounds)
        self.surfaces = growth.SurfaceMemory()
        weights = tv_weights(self.field.n_channels, self.field.K, c.tv_weight, c.tv_colour, c.tv_view_weight or 0.0)
        self.tv = GridTV(weights)
        # --transient-quantile: the step's pixels (see_batch) and the photos' cells (training_state)
        self._batch: tuple | None = None
        self._transients: robust.TransientMemory | None = None

    @property
    def step_size(self) -> float:
        return self.config.step_ratio * self.field.voxel

    @property
    def occupied_fraction(self) -> float:
        return self.estimator.occupied_fraction

    def load_kernels(self) -> None:
        self.field.backend()

    def _sinks_on_device(self) -> None:
        if self.field.sink_on_device() and self.surroundings is not None:
            self.surroundings.texture_sinks = self.surroundings.new_sinks(self.field.grid.device)

    def _march(self, o: Tensor, d: Tensor, t0: Tensor, t1: Tensor, u: Tensor, **kw) -> GridRender:
        """The grid's render of rays ``o + t d`` from ``t0`` to ``t1`` (lattice jitter ``u``)."""
        c, scale = self.config, self.field.density_scale
        spec = self.estimator.march_spec(self.step_size, c.early_stop_eps, scale, c.near_grad * self.bounds.reach)
        return self.field.render(spec, o, d, t0, t1, u, **kw)

    # -- rendering -------------------------------------------------------------------
    def _volume_span(self, o: Tensor, d: Tensor) -> tuple[Tensor, Tensor, Tensor | None]:
        """``(t0, t1, t_stop)`` (n,) each: where each ray enters and leaves the grid's box,
        ending where the surroundings stop it if it meets that first (a capture's ground:
        nothing behind it is seen), and where they stop it (None: nowhere)."""
        geom = self.field.geom
        t0, t1 = ray_aabb(o, d, geom.lo, geom.hi, self.bounds.near, self.bounds.far)
        t_stop = None if self.surroundings is None else self.surroundings.stop(o, d)
        return t0, t1 if t_stop is None else torch.minimum(t1, t_stop), t_stop

    def render_rays(self, rays: Rays, background: Tensor, perturb: bool) -> RenderOutput:
        self._sinks_on_device()
        o, d = rays.origins.float(), rays.directions.float()
        u = torch.rand(len(o), device=o.device) if perturb else torch.full((len(o),), 0.5, device=o.device)
        if self.ndc is not None:
            return self._render_ndc(o, d, u, background)
        s = self.surroundings
        t0, t1, t_stop = self._volume_span(o, d)
        t_end = None if s is None else s.distortion_end(t_stop)
        out = self._march(o, d, t0, t1, u, t_end=t_end, distortion=bool(self.config.distortion_weight))
        through = 1.0 - out.acc
        extras = {"samples_per_ray": out.counts} | ({} if out.distortion is None else {"distortion": out.distortion})
        if s is None:
            bg, behind = flat_background(d, background), None
        else:
            bg, behind, more = s.behind(o, d, t_stop, background, through, self.field.backend() == "numba")
            extras.update(more)
        result = RenderOutput(out.rgb + through.unsqueeze(-1) * bg, out.depth, out.acc, out.n_samples, extras)
        if behind is not None:  # what the rays meet past the volume (the surroundings' layers)
            result.scene_depth = out.depth + through * behind[0]
            result.scene_acc = out.acc + through * behind[1]
        return result

    def _render_ndc(self, o_w: Tensor, d_w: Tensor, u: Tensor, background: Tensor) -> RenderOutput:
        """Rays through the grid in NDC (``s`` in [0, 1) from the near plane to infinity);
        colour follows the world direction; depth is returned in world units."""
        ndc = self.ndc
        assert ndc is not None  # (only called in NDC)
        o, d, forward = ndc.rays(o_w, d_w)
        assert self.ndc_scale is not None  # (set with ndc)
        o, d = to_grid(o, self.ndc_scale), to_grid(d, self.ndc_scale)
        t0, t1 = ray_aabb(o, d, self.field.geom.lo, self.field.geom.hi, 0.0, 1.0)
        dist = bool(self.config.distortion_weight)
        out = self._march(o, d, t0, torch.where(forward, t1, t0), u, distortion=dist, view_dirs=d_w)
        acc = out.acc
        depth = ndc.distance(o_w, d_w, out.depth / acc.clamp(min=1e-6)) * acc  # (expected depth: hit, times acc)
        s = self.surroundings
        far = flat_background(d_w, background) if s is None else s.far(d_w, background)
        extras = {"samples_per_ray": out.counts} | ({} if out.distortion is None else {"distortion": out.distortion})
        return RenderOutput(out.rgb + (1.0 - acc).unsqueeze(-1) * far, depth, acc, out.n_samples, extras)

    def _grid_points(self, points: Tensor) -> Tensor:
        """(n, 3) world points -> where they are in the grid's space (NDC or world)."""
        if self.ndc is None:
            return points.float()
        assert self.ndc_scale is not None  # (set with ndc)
        return to_grid(self.ndc.points(points.float()), self.ndc_scale)

    def query(self, points: Tensor, directions: Tensor) -> tuple[Tensor, Tensor]:
        """Density (per unit of the grid's space: for a forward-facing model NDC units, each
        axis scaled by :attr:`ndc_scale`) and colour."""
        return self.field.query(self._grid_points(points), directions)

    def density(self, points: Tensor) -> Tensor:
        return self.field.density(self._grid_points(points))

    def loss(self, out: RenderOutput, target_rgb: Tensor) -> Tensor:
        terms = [] if self.surroundings is None else self.surroundings.loss_terms()
        terms.append(losses.distortion(self.config.distortion_weight or 0.0, self.distortion_unit))
        return losses.total(self._photometric(out.rgb, target_rgb), terms, out)

    @property
    def distortion_unit(self) -> float:
        """The length the distortion loss measures its distances in: the scene radius, or in
        NDC 1, the span of a ray's fraction ``s`` from the near plane to infinity (mip-NeRF
        360's normalised distance), so that a weight means the same in either space."""
        return self.bounds.radius if self.ndc is None else 1.0

    def see_batch(self, progress: float, image_index: Tensor, uv: Tensor, shape: tuple[int, int, int]) -> None:
        self._batch = (progress, image_index, uv, shape) if self.config.transient_quantile else None

    def _photometric(self, rgb: Tensor, target: Tensor) -> Tensor:
        """``--rgb-loss`` of the step's rays; with ``--transient-quantile``, of a ray batch the
        trainer said the pixels of (:meth:`see_batch`), weighted by
        :func:`~nerfkit.losses.robust.robust_weights`."""
        kind, batch = self.config.rgb_loss or "mse", self._batch
        self._batch = None
        if batch is None or rgb.ndim != 2 or len(rgb) != len(batch[1]):
            return rgb_loss(rgb, target, kind)
        progress, image_index, uv, (n, w, h) = batch
        memory = self._transients
        if memory is None or memory.shape != (n, w, h):
            memory = self._transients = robust.TransientMemory(n, w, h, rgb.device)
        per_ray = rgb_errors(rgb, target, kind).mean(-1)
        trimming = progress >= (self.config.transient_start or 0.0)
        q = self.config.transient_quantile
        weights = robust.robust_weights(rgb - target, memory, image_index, uv, q, trimming)
        return robust.weighted_mean(per_ray, weights)

    @property
    def uses_sight_lines(self) -> bool:
        return (self.config.points_weight or 0.0) > 0

    def sight_loss(self, rays: Rays, distance: Tensor) -> Tensor | None:
        """The sparse points' sight lines in the loss: :func:`sight_line_loss` of
        :meth:`sight_opacities`, weighted by ``--points-weight``; None when it takes no
        part (no weight, or a forward-facing model)."""
        weight = self.config.points_weight or 0.0
        lines = self.sight_opacities(rays, distance) if weight > 0 else None
        return None if lines is None else weight * sight_line_loss(lines[0], lines[1])

    def sight_opacities(self, rays: Rays, distance: Tensor) -> tuple[Tensor, Tensor, Tensor] | None:
        """What the grid puts on sight lines, each from a training camera to a point that
        camera saw, ``distance`` (n,) along its unit direction.

        Returns:
            ``(empty (n,), stopped (m,), solid (n,) bool)``: each line's opacity up to
            :meth:`sight_margin` before its point; for the ``m`` lines whose point is
            ``solid`` (inside the box by the margin, and on the object, not on what the
            surroundings draw: :meth:`~nerfkit.surroundings.Surroundings.above_paint`), the
            opacity up to the margin and :meth:`sight_spread` past it (a line drawn beside its
            point meets a surface that slopes away from the camera up to that much deeper).
            None for a forward-facing (NDC) model, whose grid is not in world units, or no
            lines.
        """
        if self.ndc is not None or len(distance) == 0:
            return None
        o, d = rays.origins.float(), rays.directions.float()
        t0, t1, _ = self._volume_span(o, d)
        margin, geom = self.sight_margin(), self.field.geom
        points = o + d * distance.unsqueeze(-1)
        solid = ((points >= geom.lo + margin) & (points <= geom.hi - margin)).all(-1)
        above = None if self.surroundings is None else self.surroundings.above_paint(points, self.density_box())
        solid = solid if above is None else solid & above
        u = torch.rand(len(o), device=o.device)
        empty = self._opacity_between(o, d, t0, torch.minimum(t1, distance - margin).clamp(min=t0), u)
        s = solid.nonzero()[:, 0]
        past = distance[s] + margin + self.sight_spread()
        stopped = self._opacity_between(o[s], d[s], t0[s], torch.minimum(t1[s], past), u[s])
        return empty, stopped, solid

    def sight_margin(self) -> float:
        """How far before its point a sight line must be empty, and past it (with
        :meth:`sight_spread`) stopped (world units)."""
        return max(SIGHT_MARGIN * self.bounds.radius, SIGHT_VOXELS * float(self.field.voxel))

    def sight_spread(self) -> float:
        """How far beside its point a drawn sight line may aim (world units; see
        :func:`~nerfkit.train.sight_lines.spread_lines`)."""
        return SIGHT_SPREAD * self.sight_margin()

    def _opacity_between(self, o: Tensor, d: Tensor, t0: Tensor, t1: Tensor, u: Tensor) -> Tensor:
        """(n,) the grid's opacity along each ray from ``t0`` to ``t1`` (differentiable)."""
        return o.new_zeros(0) if len(o) == 0 else self._march(o, d, t0, t1, u).acc

    # -- optimisation ----------------------------------------------------------------
    def param_groups(self, lr: float) -> list[dict]:
        self._not_isolated()
        scale = [1.0] + [self.config.colour_lr_ratio] * (self.field.n_channels - 1)
        eps = self.config.adam_eps
        groups = [{"params": [self.field.grid], "lr": lr, "channel_lr_scale": scale, "eps": eps}]
        return groups + ([] if self.surroundings is None else self.surroundings.param_groups(lr, eps))

    def grad_sinks(self) -> dict:
        self._sinks_on_device()
        textures = {} if self.surroundings is None else self.surroundings.texture_sinks
        return {self.field.grid: self.field.sink, **textures}

    def schedules(self) -> list[Schedule]:
        """Coarse-to-fine growth (before a step; it installs new grid parameters), the total
        variation (with the step's gradients), and after a step: where opaque rays ended
        (until the first growth, which shrinks the box around them) and occupancy refreshes
        (every ``occ_start`` steps until ``occ_warmup``, then every ``occ_every``); then the
        surroundings' own jobs."""
        jobs = [
            Schedule("grow", lambda s: growth.growth_due(self, s), lambda s: growth.grow_next(self, s)),
            Schedule("total variation", lambda s: self.tv.on, self._add_tv, phase="gradients"),
            Schedule("remember surfaces", self._surface_due, self._remember_surface, phase="after_step"),
            Schedule("occupancy", lambda s: True, self._occupancy_job, phase="after_step"),
        ]
        return jobs + [Schedule(*job) for job in ([] if self.surroundings is None else self.surroundings.jobs())]

    def _add_tv(self, s: StepState) -> None:
        self.tv(self.field)

    def rays_per_step(self, batch_rays: int) -> int:
        return batch_rays * self.ray_factors[min(self.stage, len(self.ray_factors) - 1)]

    def _occupancy_job(self, s: StepState) -> None:
        self.estimator.update_every_n_steps(s.step + 1, self.refresh_occupancy)

    @torch.no_grad()
    def refresh_occupancy(self) -> None:
        """Rebuild the occupancy grid from the current densities (exact per-cell bound)."""
        alpha = self.field.alpha_threshold(self.config.occ_alpha, self.step_size)
        cells = self.field.occupancy(self.step_size, alpha, self.config.coarse_factor)
        if isinstance(cells, tuple):
            self.estimator.set_cells(*cells)
        else:
            self.estimator.set_from_cell_sigma(cells, self.step_size, alpha)

    def _surface_due(self, s: StepState) -> bool:
        return s.out is not None and self.config.shrink_box and self.stage == 0 and bool(self.steps)

    @torch.no_grad()
    def _remember_surface(self, s: StepState) -> None:
        """Remember where the step's opaque rays ended, in the grid's space (for the box
        shrink at the first growth)."""
        assert s.out is not None and s.rays is not None  # (due only with a step's output)
        acc, depth = s.out.acc.detach().float(), s.out.depth.detach().float()
        hit = acc > 0.5
        if hit.any():
            o, d = s.rays.origins[hit].float(), s.rays.directions[hit].float()
            self.surfaces.remember(self._grid_points(o + d * (depth[hit] / acc[hit]).unsqueeze(-1)))

    def density_box(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The grid's box (the object's, for a capture; shrunk to the content after the
        first growth), or None in NDC."""
        geom = self.field.geom
        return None if self.ndc is not None else (geom.lo.cpu().numpy(), geom.hi.cpu().numpy())

    @torch.no_grad()
    def clear_density(self, where) -> None:
        sigma, axes, _ = self.field.density_volume()
        self.field.clear(where(sigma, axes))
        self.refresh_occupancy()

    def finish_training(self) -> list[str]:
        return growth.faces_note(self)

    # -- checkpoints -----------------------------------------------------------------
    def extra_state(self) -> dict:
        self._not_isolated()
        return {**self.field.layout(), "stage": self.stage, "occ_active": self.estimator.active}

    def load_extra_state(self, state: dict) -> None:
        box = self.field.load_layout(state, "checkpoint 'model_extra'")
        self.stage = int(state["stage"])
        self.estimator.active = bool(state["occ_active"])
        self.estimator.set_box(box)

    def training_state(self) -> dict:
        memory = self._transients
        return {} if memory is None else {f"transients.{k}": v for k, v in memory.state().items()}

    def load_training_state(self, state: dict) -> None:
        memory = {k.split(".", 1)[1]: v for k, v in state.items() if k.startswith("transients.")}
        self._transients = robust.TransientMemory.from_state(memory, self.field.grid.device) if memory else None

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        state_dict = renamed(state_dict)
        grid = state_dict.get("field.grid")
        if isinstance(grid, Tensor) and grid.shape != self.field.grid.shape and grid.ndim == 2:
            if grid.shape[1] != self.field.grid.shape[1]:  # (another --sh-degree: other channels, not rows)
                raise RuntimeError(
                    f"size mismatch for field.grid: {grid.shape[1]} channels a vertex, the model's settings "
                    f"give {self.field.grid.shape[1]}"
                )
            # a model file holds fewer rows than the run had (occupied vertices only)
            self.field.set_rows(torch.zeros(grid.shape, device=self.field.grid.device))
        index = state_dict.get("field.vertex_rows")
        if isinstance(index, Tensor):
            self.field.check_index(index, self.field.grid.shape[0])
        result = super().load_state_dict(state_dict, strict=strict, assign=assign)
        self.field.set_geometry(self.field.box, self.field.vertex_rows)
        self.estimator.set_cells(self.estimator.occ)
        return result

    def pack_state(self) -> tuple[str | None, dict]:
        """The grid's rows at corners of occupied cells only, in half precision
        (:mod:`nerfkit.models.packing`); the rest of the state as it is."""
        self._not_isolated()
        state = self.state_dict()
        index = state.pop("field.vertex_rows")
        keep = vertices_touching(self.estimator.occ) & (index > 0)
        packed = pack_grid(state.pop("field.grid")[index[keep].long()], keep, PACKED_DENSITY_DTYPE)
        return PACKING, {**state, **{f"grid_packed.{k}": v for k, v in packed.items()}}

    def unpack_state(self, packing: str, state: dict) -> dict:
        if packing != PACKING:
            raise ValueError(f"unknown model packing {packing!r} (this nerfkit reads {PACKING!r})")
        state = dict(state)
        packed = {k: state.pop(f"grid_packed.{k}", None) for k in ("mask", "density", "colour")}
        n = self.field.geom.n_vertices
        keep, rows = unpack_grid(packed, n, self.field.n_channels)
        index = torch.zeros(n, dtype=torch.int32)
        index[keep] = torch.arange(1, len(rows) + 1, dtype=torch.int32)
        return {**state, "field.grid": torch.cat([self.field.empty_rows(1), rows]), "field.vertex_rows": index}
