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
  dataset's sparse points above its table), else as the cube around the scene's bounding
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

Outside the box rays see either the background colour the trainer passes, or (with
``learn_background``) the room: a learned colour per direction (spherical harmonics)
behind ``room_shells`` textured, semi-transparent spheres around the cameras
(:class:`~nerfkit.fields.background.RoomShells`), for captures whose surroundings are
not a flat colour. With ``table`` and a scene that
has a table plane (a tag capture), rays stop at the table, which shows a learned
texture (:class:`~nerfkit.fields.background.TablePlane`): the box then holds only the
object, not the table around it.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..cameras import Rays
from ..config import check_ranges
from ..data.validate import short_repr
from ..errors import fail
from ..estimators.occupancy import OccupancyEstimator, RefreshRule
from ..fields.background import RoomShells, TablePlane, composite_layers, layers_depth, sh16, table_doubt
from ..kernels import numba_kernels
from ..kernels import reference as ref
from ..kernels.ops import GradSink, GridGeom, MarchSpec, add_grid_tv, cell_density_max, render_grid, row_vertices
from ..kernels.optim import replace_param
from ..render.box import GridBox, ray_aabb
from ..render.volrend import sight_line_loss
from ..tabletop import TABLE_CUT, around_object, faces_reached, heights, table_cut_height
from .base import NerfModel, RenderOutput, SceneBounds, Schedule, StepState, rgb_loss
from .fast_config import BOX_FOLLOW, BOX_FOLLOW_OPACITY, BOX_FOLLOW_UNTIL, MAX_GRID_SIDE, MAX_GRID_VERTICES, FastConfig
from .packing import pack_grid, unpack_grid, vertices_touching

# A growth dips the held-out score until the finer grid has trained for a while (lego,
# 128 -> 192 at step 2000: 70 steps to be back level, +0.25 dB after 300, +0.45 after
# 600): a growth with fewer steps left than this fraction of the steps done only costs.
GROWTH_MIN_STEPS_LEFT = 0.05


def growth_too_late(s: StepState) -> bool:
    """Whether the run has too few steps left for a growth to pay off: fewer than
    ``GROWTH_MIN_STEPS_LEFT`` of the steps done, at the pace so far."""
    return s.progress > 1.0 / (1.0 + GROWTH_MIN_STEPS_LEFT)


# A sight line ends this far before its point and is stopped this far past it: SIGHT_MARGIN
# scene radii (a voxel or two of the finest grid), and at least SIGHT_VOXELS
# voxels of the grid (a vertex's density spreads over a voxel each way: at the coarse
# stages a thinner margin would ask one vertex to be empty and solid at once).
SIGHT_MARGIN = 0.01
SIGHT_VOXELS = 2.0
# Each drawn line aims within SIGHT_SPREAD margins of its point (a few pixels of a capture's
# photos). Aimed at the point itself the lines made specks a voxel or two wide, the fur
# between them thinner; 5 margins left the object paler (`--points-weight` in BENCHMARKS.md).
SIGHT_SPREAD = 2.5

# Model files store the grid sparsely (vertices of occupied cells) under this name, the
# density channel in this dtype; the other vertices get raw density EMPTY_RAW
# (softplus(-30) = 1e-13: no density).
PACKING = "fast-sparse-grid-1"
PACKED_DENSITY_DTYPE = torch.float16
EMPTY_RAW = -30.0


def check_grid_res(res, where: str, field: str, fix: str) -> tuple[int, int, int]:
    """A grid resolution (x, y, z vertex counts) small enough to allocate, as ints."""
    ok = (
        isinstance(res, (list, tuple))
        and len(res) == 3
        and all(isinstance(r, int) and not isinstance(r, bool) and 2 <= r <= MAX_GRID_SIDE for r in res)
    )
    if not ok or math.prod(res) > MAX_GRID_VERTICES:
        raise fail(
            where,
            f"'{field}' is {short_repr(res)}, expected 3 vertex counts from 2 to {MAX_GRID_SIDE}, "
            f"at most 512^3 vertices in all",
            fix,
        )
    return int(res[0]), int(res[1]), int(res[2])


class FastNeRF(NerfModel):
    """Grid field + occupancy grid + fused kernels (see the module docstring)."""

    vertex_rows: Tensor
    surface_pts: Tensor
    surface_count: Tensor
    bg_coef: nn.Parameter | None

    def __init__(self, config: FastConfig, bounds: SceneBounds):
        super().__init__(bounds)
        self.config = check_ranges(config)
        self.sizes, self.steps = config.stages()
        self.ray_factors = config.stage_ray_factors()
        self.K = ref.sh_dim(config.sh_degree)
        self.n_channels = 1 + 3 * self.K
        self.ndc = None
        self.isolated = False  # (isolate_object)
        if config.space == "ndc" or (config.space == "auto" and bounds.ndc is not None):
            if bounds.ndc is None:
                raise fail(
                    "--space ndc",
                    "the scene is not forward-facing (its cameras look different ways)",
                    "Use --space box (or auto)",
                )
            self.ndc = bounds.ndc
        c = np.asarray(bounds.center, np.float32)
        box = (c - bounds.radius, c + bounds.radius)
        if self.ndc is not None:
            e = self.ndc.extent
            box = (np.array([-e, -e, -1.0], np.float32), np.array([e, e, 1.0], np.float32))
        elif config.object_box and bounds.object_box is not None:
            box = bounds.object_box
        grid_box = GridBox.fit(box[0], box[1], self.sizes[0])
        # densities are in units of the first stage's voxel: sigma = softplus(raw) / voxel0
        self.density_scale = 1.0 / grid_box.voxel
        self.stage = 0
        n = grid_box.n_vertices
        # the occupancy grid (saved with the model, so that a resumed run samples as the
        # uninterrupted one would), refreshed after every occ_start steps until occ_warmup,
        # then every occ_every
        self.estimator = OccupancyEstimator(
            grid_box,
            RefreshRule(config.occ_start, config.occ_every, config.occ_start, config.occ_warmup),
            config.coarse_factor,
        )
        self._set_geometry(grid_box, torch.arange(1, n + 1, dtype=torch.int32))
        raw0 = self._raw_for_alpha(config.init_alpha, config.step_ratio * grid_box.voxel)
        grid = self._empty_rows(n + 1)
        grid[1:, 0] = raw0
        self.grid = nn.Parameter(grid)
        if config.learn_background:
            self.bg_coef = nn.Parameter(torch.zeros(3, 16))
        else:
            self.register_parameter("bg_coef", None)
        self.room = None
        if config.learn_background and config.room_shells:
            self.room = RoomShells(
                bounds.center,
                bounds.up,
                1.25 * max(bounds.reach, bounds.radius),
                config.room_shells,
                config.room_ratio,
                config.room_resolution,
            )
        self.table = None
        self.cover_prior_on = False  # set by the "table cover prior" schedule
        if config.table and bounds.table is not None:
            self.table = TablePlane(
                bounds.table, bounds.center, bounds.radius, config.table_resolution, gloss=config.table_gloss
            )
        self.floor = None
        if config.floor and self.table is not None and config.learn_background and bounds.floor is not None:
            self.floor = TablePlane(bounds.floor, bounds.center, bounds.reach, config.table_resolution)
        self.texture_sinks = self._texture_sinks(torch.device("cpu"))
        self.sink = self._grid_sink(torch.device("cpu"))
        # where opaque training rays ended (ring buffer), to shrink the box at the first growth
        self.register_buffer("surface_pts", torch.zeros(1 << 16, 3))
        self.register_buffer("surface_count", torch.zeros((), dtype=torch.long))

    # -- geometry --------------------------------------------------------------------
    def _set_geometry(self, box: GridBox, index: Tensor) -> None:
        """Install the grid's box and ``index`` (N,) int32: the feature row of each vertex
        (0: not stored). The occupancy moves to the box with every cell occupied."""
        device = self.grid.device if hasattr(self, "grid") else torch.device("cpu")
        self.register_buffer("vertex_rows", index.to(device=device, dtype=torch.int32).contiguous())
        self.box = box
        self.estimator.set_box(box)
        self._row_offset = GridGeom(self.estimator.lo, box.voxel, box.res, self.vertex_rows).row_offset()
        self.step_size = self.config.step_ratio * box.voxel

    @property
    def voxel(self) -> float:
        return self.box.voxel

    @property
    def res(self) -> tuple[int, int, int]:
        return self.box.res

    @property
    def geom(self) -> GridGeom:
        """The grid's layout (its box's corner on the grid's device, vertex rows)."""
        return GridGeom(
            self.estimator.lo, self.box.voxel, self.box.res, self.vertex_rows, dense_offset=self._row_offset
        )

    def _empty_rows(self, n: int, device=None) -> Tensor:
        """(n, C) rows of no density and no colour (row 0 of the grid is one forever)."""
        rows = torch.zeros((n, self.n_channels), device=device)
        rows[:, 0] = EMPTY_RAW
        return rows

    def _grid_sink(self, device) -> GradSink:
        return GradSink(self.grid.shape[0], self.n_channels, device, frozen=1)

    @property
    def stored_vertices(self) -> int:
        """How many vertices have their own feature row."""
        return self.grid.shape[0] - 1

    def _raw_for_alpha(self, alpha: float, step: float) -> float:
        sigma = -math.log1p(-alpha) / step
        x = sigma / self.density_scale
        return float(math.log(math.expm1(x))) if x < 20 else x

    def load_kernels(self) -> None:
        self._backend()

    def _backend(self) -> str:
        if self.config.kernels == "torch" or self.grid.device.type != "cpu":
            return "torch"
        if numba_kernels() is None:
            if self.config.kernels == "numba":
                raise fail("--kernels numba", "numba is not available", "pip install 'nerfkit[fast]' or use auto")
            return "torch"
        return "numba"

    @property
    def occupancy(self) -> OccupancyEstimator:
        """The occupancy estimator (for inspection and other samplers)."""
        return self.estimator

    @property
    def occupied_fraction(self) -> float:
        return self.estimator.occupied_fraction

    def _spec(self) -> MarchSpec:
        return self.estimator.march_spec(
            self.step_size, self.config.early_stop_eps, self.density_scale, self.config.near_grad * self.bounds.reach
        )

    def _texture_sinks(self, device) -> dict:
        """A one-lane gradient sink per table and room texture (its optimizer updates touched
        texels only)."""
        textures = [p for part in (self.table, self.floor, self.room) if part is not None for p in part.textures()]
        return {p: GradSink(p.shape[0], p.shape[1], device, lanes=1) for p, _ in textures}

    def _sinks_on_device(self) -> None:
        """Gradient sinks live beside the grid: rebuilt (empty) after the model moved."""
        if self.sink.grad.device != self.grid.device:
            self.sink = self._grid_sink(self.grid.device)
            self.texture_sinks = self._texture_sinks(self.grid.device)

    # -- rendering -------------------------------------------------------------------
    def _far(self, d: Tensor, background: Tensor | None) -> Tensor:
        """(n, 3) what is seen infinitely far along ``d``: the learned colour per direction,
        else the flat ``background``."""
        if self.bg_coef is not None:
            return torch.sigmoid(sh16(d) @ self.bg_coef.t())
        if background is None:
            return torch.zeros_like(d)
        return torch.as_tensor(background, dtype=torch.float32, device=d.device).expand_as(d)

    def _background(
        self, o: Tensor, d: Tensor, t_table: Tensor | None, background: Tensor | None
    ) -> tuple[Tensor, tuple[Tensor, Tensor] | None, Tensor | None]:
        """(n, 3) colour behind the box: the table (where rays meet it), the floor and the
        room shells, composited in order of distance, in front of what is infinitely far
        (:meth:`_far`). A glossy table also shows its map of the surroundings along the
        mirrored ray. Out of training, also the (n,) distance of the layer each ray meets
        and whether it meets one (:func:`layers_depth`); else, or with no layers, None.
        Last, for the table cover prior (in training, with its weight), the (n,) share of
        light the table lets through where a ray meets it (0 where it misses); else None."""
        bg = self._far(d, background)
        compiled = self._backend() == "numba"  # the textures follow the grid's kernels
        layers = [] if self.room is None else [self.room.layers(o, d, self.texture_sinks, compiled)]
        clear = None
        if t_table is not None:
            assert self.table is not None  # (t_table comes from the table)
            layers.append(self._plane_layer(self.table, o, d, t_table, self.config.table_gloss, compiled))
            if self.training and self.config.table_cover_weight:  # for the cover prior
                clear = torch.isfinite(t_table) * (1.0 - layers[-1][2][:, 0])
        if self.floor is not None:
            layers.append(self._plane_layer(self.floor, o, d, self.floor.hit(o, d), False, compiled))
        if not layers:
            return bg, None, None
        t, rgb, alpha = (torch.cat(parts, dim=1) for parts in zip(*layers))
        alpha = alpha.to(bg.dtype)
        depth = None if self.training else layers_depth(t.float(), alpha.float())
        return composite_layers(t, rgb.to(bg.dtype), alpha, bg), depth, clear

    def _plane_layer(
        self, plane: TablePlane, o: Tensor, d: Tensor, t_hit: Tensor, gloss: bool, compiled: bool
    ) -> tuple[Tensor, Tensor, Tensor]:
        """One textured plane as a compositing layer: ``t (n, 1)`` where each ray meets it
        (``inf``: misses), ``rgb (n, 1, 3)`` and coverage ``(n, 1)``."""
        hit = torch.isfinite(t_hit).nonzero()[:, 0]
        on_plane = o[hit] + d[hit] * t_hit[hit].unsqueeze(-1)
        seen, cover, shine = plane.look(on_plane, self.texture_sinks, gloss=gloss and len(hit) > 0, compiled=compiled)
        if shine is not None:
            n = plane.plane[:3].to(d)
            mirrored = d[hit] - 2.0 * (d[hit] @ n).unsqueeze(-1) * n
            seen = (1.0 - shine.unsqueeze(-1)) * seen + shine.unsqueeze(-1) * plane.reflection(mirrored)
        colour = torch.zeros_like(d).index_put((hit,), seen.to(d.dtype))
        cover = d.new_zeros(len(d)).index_put((hit,), cover.to(d.dtype))
        return t_hit.unsqueeze(1), colour.unsqueeze(1), cover.unsqueeze(1)

    def _volume_span(self, o: Tensor, d: Tensor) -> tuple[Tensor, Tensor, Tensor | None]:
        """``(t0, t1, t_table)`` (n,) each: where each ray enters and leaves the grid's box,
        ending at the table if it meets it first (nothing behind the table is seen), and
        where it meets the table (None without one)."""
        t0, t1 = ray_aabb(o, d, self.geom.lo, self.geom.hi, self.bounds.near, self.bounds.far)
        t_table = None
        if self.table is not None:
            t_table = self.table.hit(o, d)
            t1 = torch.minimum(t1, t_table)
        return t0, t1, t_table

    def render_rays(self, rays: Rays, background: Tensor, perturb: bool) -> RenderOutput:
        self._sinks_on_device()
        if self.ndc is not None:
            return self._render_ndc(rays, background, perturb)
        o = rays.origins.float()
        d = rays.directions.float()
        n = o.shape[0]
        t0, t1, t_table = self._volume_span(o, d)
        u = torch.rand(n, device=o.device) if perturb else torch.full((n,), 0.5, device=o.device)
        out = render_grid(
            self.grid,
            self.geom,
            self._spec(),
            o,
            d,
            t0,
            t1,
            u,
            self.config.sh_degree,
            self.sink,
            self._backend(),
            t_end=t_table if self.config.distortion_table else None,
            distortion=bool(self.config.distortion_weight),
        )
        bg, behind, clear = self._background(o, d, t_table, background)
        through = 1.0 - out.acc
        rgb = out.rgb + through.unsqueeze(-1) * bg
        extras = {"samples_per_ray": out.counts}
        if out.distortion is not None:
            extras["distortion"] = out.distortion
        if clear is not None:
            extras["table_doubt"] = through.detach() * table_doubt(clear)
        result = RenderOutput(rgb, out.depth, out.acc, out.n_samples, extras)
        if behind is not None:  # what the rays meet past the volume: the table, the room
            result.scene_depth = out.depth + through * behind[0]
            result.scene_acc = out.acc + through * behind[1]
        return result

    def _render_ndc(self, rays: Rays, background: Tensor, perturb: bool) -> RenderOutput:
        """Rays through the grid in NDC (``s`` in [0, 1) from the near plane to infinity);
        colour follows the world direction; depth is returned in world units."""
        ndc = self.ndc
        assert ndc is not None  # (only called in NDC)
        o_w, d_w = rays.origins.float(), rays.directions.float()
        o, d, forward = ndc.rays(o_w, d_w)
        t0, t1 = ray_aabb(o, d, self.geom.lo, self.geom.hi, 0.0, 1.0)
        t1 = torch.where(forward, t1, t0)
        u = torch.rand(o.shape[0], device=o.device) if perturb else torch.full((o.shape[0],), 0.5, device=o.device)
        out = render_grid(
            self.grid,
            self.geom,
            self._spec(),
            o,
            d,
            t0,
            t1,
            u,
            self.config.sh_degree,
            self.sink,
            self._backend(),
            distortion=bool(self.config.distortion_weight),
            view_dirs=d_w,
        )
        acc = out.acc
        s = out.depth / acc.clamp(min=1e-6)
        depth = ndc.distance(o_w, d_w, s) * acc  # (expected depth: what was hit, times acc)
        rgb = out.rgb + (1.0 - acc).unsqueeze(-1) * self._far(d_w, background)
        extras = {"samples_per_ray": out.counts}
        if out.distortion is not None:
            extras["distortion"] = out.distortion
        return RenderOutput(rgb, depth, acc, out.n_samples, extras)

    def _grid_points(self, points: Tensor) -> Tensor:
        """(n, 3) world points -> where they are in the grid's space (NDC or world)."""
        return points.float() if self.ndc is None else self.ndc.points(points.float())

    def query(self, points: Tensor, directions: Tensor) -> tuple[Tensor, Tensor]:
        """Density (per unit of the grid's space: NDC units for a forward-facing model) and colour."""
        pts = self._grid_points(points)
        inside = ((pts >= self.geom.lo) & (pts <= self.geom.hi)).all(-1)
        feat = ref.grid_interp(
            self.grid, ref.grid_coords(pts, self.geom.lo, self.geom.voxel), self.geom.res, self.geom.index
        )
        sigma, rgb = ref.decode(feat, ref.sh_basis(directions.float(), self.config.sh_degree), self.density_scale)
        return sigma * inside, rgb

    def density(self, points: Tensor) -> Tensor:
        pts = self._grid_points(points)
        inside = ((pts >= self.geom.lo) & (pts <= self.geom.hi)).all(-1)
        raw = ref.grid_interp(
            self.grid[:, :1], ref.grid_coords(pts, self.geom.lo, self.geom.voxel), self.geom.res, self.geom.index
        )
        return self.density_scale * F.softplus(raw[:, 0]) * inside

    def loss(self, out: RenderOutput, target_rgb: Tensor) -> Tensor:
        loss = rgb_loss(out.rgb, target_rgb, self.config.rgb_loss or "mse")
        if self.table is not None and self.config.opacity_weight > 0:
            loss = loss + self.config.opacity_weight * out.acc.float().mean()
        if self.cover_prior_on and "table_doubt" in out.extras:
            loss = loss + self.config.table_cover_weight * out.extras["table_doubt"].float().mean()
        weight = self.config.distortion_weight or 0.0
        if weight > 0 and "distortion" in out.extras:
            loss = loss + weight / self.bounds.radius * out.extras["distortion"].float().mean()
        return loss

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
            ``solid`` (inside the box by the margin, and above the table's cut: on the
            object, not on the table the box leaves to its texture), the opacity up to the
            margin past it. None for a forward-facing (NDC) model, whose grid is not in
            world units, or no lines.
        """
        if self.ndc is not None or len(distance) == 0:
            return None
        o, d = rays.origins.float(), rays.directions.float()
        t0, t1, _ = self._volume_span(o, d)
        margin = self.sight_margin()
        points = o + d * distance.unsqueeze(-1)
        solid = ((points >= self.geom.lo + margin) & (points <= self.geom.hi - margin)).all(-1)
        if self.table is not None:
            plane = self.table.plane.to(points)
            solid &= points @ plane[:3] + plane[3] > table_cut_height(self, TABLE_CUT)
        u = torch.rand(len(o), device=o.device)
        empty = self._opacity_between(o, d, t0, torch.minimum(t1, distance - margin).clamp(min=t0), u)
        s = solid.nonzero()[:, 0]
        stopped = self._opacity_between(o[s], d[s], t0[s], torch.minimum(t1[s], distance[s] + margin), u[s])
        return empty, stopped, solid

    def sight_margin(self) -> float:
        """How far before its point a sight line must be empty, and past it stopped (world units)."""
        return max(SIGHT_MARGIN * self.bounds.radius, SIGHT_VOXELS * float(self.geom.voxel))

    def sight_spread(self) -> float:
        """How far beside its point a drawn sight line may aim (world units; see
        :func:`~nerfkit.train.sight_lines.spread_lines`)."""
        return SIGHT_SPREAD * self.sight_margin()

    def _opacity_between(self, o: Tensor, d: Tensor, t0: Tensor, t1: Tensor, u: Tensor) -> Tensor:
        """(n,) the grid's opacity along each ray from ``t0`` to ``t1`` (differentiable)."""
        if len(o) == 0:
            return o.new_zeros(0)
        return render_grid(
            self.grid, self.geom, self._spec(), o, d, t0, t1, u, self.config.sh_degree, self.sink, self._backend()
        ).acc

    # -- optimisation ----------------------------------------------------------------
    def param_groups(self, lr: float) -> list[dict]:
        self._not_isolated()
        scale = [1.0] + [self.config.colour_lr_ratio] * (self.n_channels - 1)
        eps = self.config.adam_eps
        groups = [{"params": [self.grid], "lr": lr, "channel_lr_scale": scale, "eps": eps}]
        if self.bg_coef is not None:
            groups.append({"params": [self.bg_coef], "lr": 0.1 * lr, "eps": eps})
        if self.table is not None:
            groups.append({"params": list(self.table.parameters()), "lr": self.config.table_lr_ratio * lr, "eps": eps})
        if self.floor is not None:
            groups.append({"params": list(self.floor.parameters()), "lr": self.config.table_lr_ratio * lr, "eps": eps})
        if self.room is not None:
            groups.append({"params": list(self.room.parameters()), "lr": self.config.room_lr_ratio * lr, "eps": eps})
        return groups

    def grad_sinks(self) -> dict:
        self._sinks_on_device()
        return {self.grid: self.sink, **self.texture_sinks}

    def schedules(self) -> list[Schedule]:
        """Coarse-to-fine growth and the table cover prior's switch (before a step; the
        growth installs new grid parameters), the total variation (with the step's
        gradients), and after a step:
        where opaque rays ended (until the first growth, which shrinks the box around
        them) and occupancy refreshes (every ``occ_start`` steps until ``occ_warmup``, then
        every ``occ_every``)."""
        return [
            Schedule("grow", self._growth_due, self._grow_next),
            Schedule("total variation", lambda s: bool(self.tv_weights().any()), self._add_tv, phase="gradients"),
            Schedule("remember surfaces", self._surface_due, self._remember_surface, phase="after_step"),
            Schedule("occupancy", lambda s: True, self._occupancy_job, phase="after_step"),
            Schedule("table cover prior", lambda s: bool(self.config.table_cover_weight), self._switch_cover_prior),
        ]

    def _switch_cover_prior(self, s: StepState) -> None:
        """The table's cover prior applies from ``--table-cover-start`` of the run on."""
        self.cover_prior_on = s.progress >= self.config.table_cover_start

    def rays_per_step(self, batch_rays: int) -> int:
        return batch_rays * self.ray_factors[min(self.stage, len(self.ray_factors) - 1)]

    def _growth_due(self, s: StepState) -> bool:
        return self.stage < len(self.steps) and s.step >= self.steps[self.stage] and not growth_too_late(s)

    def _grow_next(self, s: StepState) -> str:
        notes = []
        while self._growth_due(s):  # (a resumed run catches up on every stage it passed)
            follow = (
                self.config.box_follows
                and self.stage > 0
                and s.progress < BOX_FOLLOW_UNTIL
                and self.table is not None
                and self.ndc is None
            )
            notes += self._grow(
                self.sizes[self.stage + 1],
                shrink=self.config.shrink_box and self.stage == 0,
                follow=follow,
                optimizer=s.optimizer,
            )
            self.stage += 1
        return "; ".join([self.stage_note(), *notes])

    def stage_note(self) -> str:
        rx, ry, rz = self.geom.res
        n, m = self.geom.n_vertices, self.stored_vertices
        mb = self.grid.numel() * 4 / 1e6
        return (
            f"grid {rx}x{ry}x{rz} vertices, {m / 1e6:.2f} M of {n / 1e6:.2f} M stored ({100 * m / n:.0f}%, "
            f"{mb:.0f} MB; {(2 + self.sink.lanes) * mb:.0f} MB more for Adam and gradients)"
        )

    def _occupancy_job(self, s: StepState) -> None:
        self.estimator.update_every_n_steps(s.step + 1, self.refresh_occupancy)

    @torch.no_grad()
    def refresh_occupancy(self) -> None:
        """Rebuild the occupancy grid from the current densities (exact per-cell bound)."""
        thr = self.occ_threshold()
        nb = numba_kernels() if self._backend() == "numba" else None
        if nb is not None:
            rx, ry, rz = self.geom.res
            occ = torch.empty((rz - 1, ry - 1, rx - 1), dtype=torch.uint8)
            cf = max(self.config.coarse_factor, 1)
            coarse = torch.zeros((-(-(rz - 1) // cf), -(-(ry - 1) // cf), -(-(rx - 1) // cf)), dtype=torch.uint8)
            nb.occupancy_from_grid(
                self.grid.detach().numpy(),
                self.vertex_rows.numpy(),
                self._row_offset,
                rx,
                ry,
                rz,
                self._raw_threshold(thr),
                occ.numpy(),
                coarse.numpy(),
                cf,
            )
            self.estimator.set_cells(occ, coarse)
            return
        self.estimator.set_from_cell_sigma(
            cell_density_max(self.grid, self.geom, self.density_scale), self.step_size, thr
        )

    def _raw_threshold(self, alpha: float) -> float:
        """The raw density above which one sample's opacity exceeds ``alpha``."""
        x = -math.log1p(-alpha) / (self.step_size * self.density_scale)  # softplus(raw) > x
        return float(math.log(math.expm1(x))) if x < 20 else x

    @torch.no_grad()
    def occ_threshold(self, n_probe: int = 1 << 14) -> float:
        """``min(occ_alpha, mean cell opacity)`` (as instant-ngp): early in training, when
        every density is still tiny, only the cells below average are skipped. The mean
        is estimated on ``n_probe`` random cells (fixed seed)."""
        rx, ry, rz = self.geom.res
        n_cells = (rx - 1) * (ry - 1) * (rz - 1)
        gen = torch.Generator().manual_seed(0)
        cells = torch.randint(0, n_cells, (min(n_probe, n_cells),), generator=gen).to(self.grid.device)
        x, y, z = cells % (rx - 1), (cells // (rx - 1)) % (ry - 1), cells // ((rx - 1) * (ry - 1))
        base = (z * ry + y) * rx + x
        offs = torch.tensor(
            [dz * rx * ry + dy * rx + dx for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)], device=self.grid.device
        )
        rows = self.vertex_rows[(base.unsqueeze(1) + offs).reshape(-1)].long()
        raw = self.grid.detach()[rows, 0].reshape(-1, 8).amax(1)
        alpha = -torch.expm1(-self.density_scale * F.softplus(raw) * self.step_size)
        return min(self.config.occ_alpha, float(alpha.mean()))

    def tv_weights(self) -> Tensor:
        """(n_channels,) the total variation's weight on each grid channel: the density
        ``tv_weight``, every colour coefficient ``tv_weight * tv_colour``, and the
        coefficients above degree 0 (channel ``1 + K * colour + k``, k > 0) ``tv_view_weight``
        more."""
        c = self.config
        weight = torch.full((self.n_channels,), c.tv_weight * c.tv_colour)
        weight[0] = c.tv_weight
        view = (torch.arange(self.n_channels) - 1) % self.K != 0  # (channel 1 + K * colour: degree 0)
        weight[1:] += (c.tv_view_weight or 0.0) * view[1:]
        return weight

    def _add_tv(self, s: StepState) -> None:
        """Add the grid's total variation gradient on the rows the step's rays touched."""
        weight = self.tv_weights()
        key = (id(self.vertex_rows), self.vertex_rows._version, self.grid.shape[0])
        if getattr(self, "_row_vertex_key", None) != key:
            self._row_vertex = row_vertices(self.geom, self.grid.shape[0]) if self._row_offset < 0 else None
            self._row_vertex_key = key
        add_grid_tv(self.grid, self.geom, weight, self.sink, self._backend(), self._row_vertex)

    def _surface_due(self, s: StepState) -> bool:
        return s.out is not None and self.config.shrink_box and self.stage == 0 and bool(self.steps)

    @torch.no_grad()
    def _remember_surface(self, s: StepState) -> None:
        """Keep (in a ring buffer) where the step's opaque rays ended, in the grid's space,
        for the box shrink at the first growth."""
        assert s.out is not None and s.rays is not None  # (due only with a step's output)
        acc, depth = s.out.acc.detach().float(), s.out.depth.detach().float()
        hit = acc > 0.5
        if not hit.any():
            return
        o, d = s.rays.origins[hit].float(), s.rays.directions[hit].float()
        pts = self._grid_points(o + d * (depth[hit] / acc[hit]).unsqueeze(-1)).to(self.surface_pts)
        cap = self.surface_pts.shape[0]
        pts = pts[-cap:]
        start = int(self.surface_count) % cap
        idx = (start + torch.arange(len(pts), device=pts.device)) % cap
        self.surface_pts[idx] = pts
        self.surface_count += len(pts)

    def density_box(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The grid's box (the object's, for a capture; shrunk to the content after the
        first growth), or None in NDC."""
        if self.ndc is not None:
            return None
        return self.geom.lo.cpu().numpy(), self.geom.hi.cpu().numpy()

    def table_plane(self) -> np.ndarray | None:
        return None if self.table is None else self.table.plane.cpu().numpy()

    def surroundings(self) -> list[str]:
        parts = {"table": self.table, "floor": self.floor, "room": self.room, "background": self.bg_coef}
        return [name for name, part in parts.items() if part is not None]

    @torch.no_grad()
    def isolate_object(self, cut: float, threshold: float) -> list[str]:
        left_out = self.surroundings()
        if not left_out:
            return []
        self.isolated = True
        if self.table is not None:
            sigma, axes, rows = self._density_volume()
            around = around_object(sigma, axes, self.table_plane(), cut, threshold, self.table_tags())
            cleared = rows[torch.from_numpy(around).to(rows.device)]
            self.grid[cleared[cleared > 0], 0] = EMPTY_RAW
            self.refresh_occupancy()
        self.table = self.floor = self.room = None
        self.bg_coef = None
        return left_out

    @torch.no_grad()
    def _density_volume(self) -> tuple[np.ndarray, list[np.ndarray], Tensor]:
        """The grid's density at its vertices as an (X, Y, Z) float32 array, the x, y and z
        positions of the vertices ((X,), (Y,), (Z,) float64), and the (X, Y, Z) feature rows."""
        rx, ry, rz = self.res
        lo = np.asarray(self.box.lo, np.float64)
        axes = [lo[a] + self.voxel * np.arange(r) for a, r in enumerate(self.res)]
        rows = self.vertex_rows.long().reshape(rz, ry, rx).permute(2, 1, 0)  # [x, y, z], as axes
        sigma = (self.density_scale * F.softplus(self.grid.detach()[:, 0]))[rows]
        return sigma.cpu().numpy(), axes, rows

    def _not_isolated(self) -> None:
        if self.isolated:
            raise RuntimeError("a model isolated for an object-only render can be neither trained nor saved")

    @torch.no_grad()
    def surface_box(self) -> tuple[np.ndarray, np.ndarray] | None:
        """A box (lo, hi) around where opaque training rays ended, or None with too few.

        The 0.1% and 99.9% quantiles per axis of the remembered end points, padded by
        ``box_pad`` voxels plus 5% of the extent (kept inside the current box).
        """
        n = min(int(self.surface_count), self.surface_pts.shape[0])
        if n < 1000:
            return None
        pts = self.surface_pts[:n].double()
        lo = torch.quantile(pts, 0.001, dim=0).cpu().numpy()
        hi = torch.quantile(pts, 0.999, dim=0).cpu().numpy()
        pad = self.config.box_pad * self.geom.voxel + 0.05 * (hi - lo)
        box_lo, box_hi = self.geom.lo.cpu().numpy(), self.geom.hi.cpu().numpy()
        return np.maximum(lo - pad, box_lo), np.minimum(hi + pad, box_hi)

    @torch.no_grad()
    def _grow(
        self, size: int, shrink: bool, follow: bool = False, optimizer: torch.optim.Optimizer | None = None
    ) -> list[str]:
        """Resample the grid at about ``size ** 3`` vertices over its box, first shrunk around
        where opaque rays ended (``shrink``) or moved out where the object reaches it
        (``follow``, :meth:`_follow_object`). The new grid takes the old one's place in
        ``optimizer`` with fresh moments; every other parameter keeps its own. Returns notes
        on what the box did."""
        old_geom, old_grid = replace(self.geom), self.grid.detach()
        old_occ = self.estimator.occ if self.estimator.active else None
        lo = old_geom.lo.cpu().numpy()
        hi = old_geom.hi.cpu().numpy()
        notes = []
        if shrink:
            surface = self.surface_box()
            if surface is not None:
                lo, hi = surface
        if follow:
            lo, hi, moved = self._follow_object(lo, hi)
            if moved:
                notes.append(f"the box moved out where the object reached it: {', '.join(moved)}")
        box = GridBox.fit(lo, hi, size)
        device = old_grid.device
        geom = GridGeom.of(box, device=device)
        if old_occ is not None and min(box.res) >= self.config.sparse_from:
            keep = vertices_touching(cells_near(old_occ, old_geom, geom, self.config.sparse_margin))
        else:
            keep = torch.ones(geom.n_vertices, dtype=torch.bool, device=device)
        index = torch.zeros(geom.n_vertices, dtype=torch.int32, device=device)
        index[keep] = torch.arange(1, int(keep.sum()) + 1, dtype=torch.int32, device=device)
        self._set_geometry(box, index)
        rows = torch.cat(
            [
                self._empty_rows(1, device),
                resample_grid(
                    old_grid, old_geom, geom.vertex_positions(torch.nonzero(keep)[:, 0]), backend=self._backend()
                ),
            ]
        )
        old_param, self.grid = self.grid, nn.Parameter(rows)
        self.sink = self._grid_sink(device)
        if optimizer is not None:
            replace_param(optimizer, old_param, self.grid, sink=self.sink)
        if self.estimator.active:
            self.refresh_occupancy()
        return notes

    def _follow_object(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """The box ``(lo, hi)`` with each face that the object reaches (:func:`faces_reached`:
        its largest solid piece above the table's paint) moved out by :data:`BOX_FOLLOW` of
        the box's size along that axis, within the scene's sphere; and the faces moved, as
        "x-" or "z+" with the distance. The grid's resampling extends what crosses a face
        outward (points outside the old box take its nearest value), so the object's
        cross-section starts the new space and training carves it."""
        c, r = np.asarray(self.bounds.center, np.float64), float(self.bounds.radius)
        lo, hi = np.array(lo, np.float64), np.array(hi, np.float64)
        size = hi - lo
        moved = []
        for axis, side in self._faces_reached():
            if side == 0:
                new = max(lo[axis] - BOX_FOLLOW * size[axis], c[axis] - r)
                by, lo[axis] = lo[axis] - new, min(new, lo[axis])
            else:
                new = min(hi[axis] + BOX_FOLLOW * size[axis], c[axis] + r)
                by, hi[axis] = new - hi[axis], max(new, hi[axis])
            if by > 0:
                moved.append(f"{'xyz'[axis]}{'-+'[side]} by {by:.3g}")
        return lo.astype(np.float32), hi.astype(np.float32), moved

    def _faces_reached(self) -> list[tuple[int, int]]:
        """The faces of the grid's box that the object reaches (:func:`faces_reached` over
        the vertices solid at :data:`BOX_FOLLOW_OPACITY`, above the table's paint)."""
        sigma, axes, _ = self._density_volume()
        solid = -np.expm1(-sigma * self.voxel) > BOX_FOLLOW_OPACITY
        solid &= heights(axes, self.table_plane()) > table_cut_height(self, TABLE_CUT)
        return faces_reached(solid)

    def finish_training(self) -> list[str]:
        """A note when the trained object reaches a face of a capture's box: what crosses
        it is cut off (the box follows the object only in the first half of a run)."""
        if self.table is None or self.ndc is not None or self.isolated:
            return []
        faces = [f"{'xyz'[axis]}{'-+'[side]}" for axis, side in self._faces_reached()]
        if not faces:
            return []
        return [
            f"the object reaches the {', '.join(faces)} face{'s' if len(faces) > 1 else ''} of the model's box "
            "at the end of training, so what reaches past it is cut off there. Look at the object video "
            "(`nerfkit render RUN --object`); if the object is cut, train again with --no-object-box: the box "
            "then starts from the scene's whole sphere, not from the sparse points (room for floaters too)"
        ]

    # -- checkpoints -----------------------------------------------------------------
    def extra_state(self) -> dict:
        self._not_isolated()
        return {
            "lo": [float(v) for v in self.geom.lo.cpu()],
            "voxel": self.geom.voxel,
            "res": list(self.geom.res),
            "rows": int(self.grid.shape[0]),
            "stage": self.stage,
            "occ_active": self.estimator.active,
            "density_scale": self.density_scale,
        }

    def load_extra_state(self, state: dict) -> None:
        device = self.grid.device
        res = check_grid_res(
            state["res"],
            "checkpoint 'model_extra'",
            "res",  # checked before allocating
            "The checkpoint is corrupt or not from nerfkit; delete it or re-train",
        )
        self.density_scale = float(state["density_scale"])
        self.stage = int(state["stage"])
        self.estimator.active = bool(state["occ_active"])
        n = res[0] * res[1] * res[2]
        rows = state.get("rows", n + 1)
        if not (isinstance(rows, int) and 1 <= rows <= n + 1):
            raise fail(
                "checkpoint 'model_extra'",
                f"'rows' is {short_repr(rows)}, expected 1 to {n + 1} for a grid of {n} vertices",
                "The checkpoint is corrupt or not from nerfkit; delete it or re-train",
            )
        lo = np.asarray(state["lo"], np.float32)
        voxel = float(state["voxel"])
        lo3 = lo.reshape(3).tolist()
        self._set_geometry(GridBox((lo3[0], lo3[1], lo3[2]), voxel, res), torch.zeros(n, dtype=torch.int32))
        self.grid = nn.Parameter(torch.zeros((rows, self.n_channels), device=device))
        self.sink = self._grid_sink(device)

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        grid = state_dict.get("grid")
        if isinstance(grid, Tensor) and grid.shape != self.grid.shape and grid.ndim == 2:
            # a model file holds fewer rows than the run had (occupied vertices only)
            self.grid = nn.Parameter(torch.zeros(grid.shape, device=self.grid.device))
            self.sink = self._grid_sink(self.grid.device)
        index = state_dict.get("vertex_rows")
        if (
            isinstance(index, Tensor)
            and index.numel()
            and not (int(index.min()) >= 0 and int(index.max()) < self.grid.shape[0])
        ):
            # the compiled kernels do not check bounds: a corrupt index must not reach them
            raise ValueError(
                f"vertex_rows holds rows {int(index.min())}..{int(index.max())}, outside the grid's "
                f"{self.grid.shape[0]} rows"
            )
        if "occ_cells" in state_dict:  # a checkpoint from before the occupancy estimator
            state_dict = {("estimator.occ" if k == "occ_cells" else k): v for k, v in state_dict.items()}
        result = super().load_state_dict(state_dict, strict=strict, assign=assign)
        self._row_offset = GridGeom(self.estimator.lo, self.voxel, self.res, self.vertex_rows).row_offset()
        self.estimator.set_cells(self.estimator.occ)
        return result

    def pack_state(self) -> tuple[str | None, dict]:
        """The grid's rows at corners of occupied cells only, in half precision
        (:mod:`nerfkit.models.packing`); the rest of the state as it is."""
        self._not_isolated()
        state = self.state_dict()
        keep = vertices_touching(self.estimator.occ) & (self.vertex_rows > 0)
        rows = state.pop("grid")[self.vertex_rows[keep].long()]
        state.pop("vertex_rows")
        packed = pack_grid(rows, keep, PACKED_DENSITY_DTYPE)
        return PACKING, {**state, **{f"grid_packed.{k}": v for k, v in packed.items()}}

    def unpack_state(self, packing: str, state: dict) -> dict:
        if packing != PACKING:
            raise ValueError(f"unknown model packing {packing!r} (this nerfkit reads {PACKING!r})")
        state = dict(state)
        packed = {k: state.pop(f"grid_packed.{k}", None) for k in ("mask", "density", "colour")}
        keep, rows = unpack_grid(packed, self.geom.n_vertices, self.n_channels)
        index = torch.zeros(self.geom.n_vertices, dtype=torch.int32)
        index[keep] = torch.arange(1, len(rows) + 1, dtype=torch.int32)
        state["grid"] = torch.cat([self._empty_rows(1), rows])
        state["vertex_rows"] = index
        return state


@torch.no_grad()
def resample_grid(grid: Tensor, geom: GridGeom, points: Tensor, chunk: int = 1 << 18, backend: str = "torch") -> Tensor:
    """Trilinearly interpolate a (sparse or dense) vertex grid at ``points`` (m, 3): (m, C).

    Points outside the grid's box take the value at the nearest point of the box
    (coordinates are clamped), as :func:`reference.grid_interp` does. ``backend``
    "numba": through the compiled kernel (a float32 CPU grid), else in torch.
    """
    nb = numba_kernels() if backend == "numba" and grid.device.type == "cpu" and grid.dtype == torch.float32 else None
    if nb is not None:
        values = np.empty((len(points), grid.shape[1]), np.float32)
        nb.grid_interp_points(
            grid.detach().contiguous().numpy(),
            geom.vertex_index().numpy(),
            geom.row_offset(),
            *geom.res,
            geom.lo.double().numpy(),
            1.0 / geom.voxel,
            points.double().contiguous().numpy(),
            values,
        )
        return torch.from_numpy(values)
    out = torch.empty((len(points), grid.shape[1]), dtype=grid.dtype, device=grid.device)
    lo = geom.lo.to(points)
    for i in range(0, len(points), chunk):
        g = ref.grid_coords(points[i : i + chunk], lo, geom.voxel)
        out[i : i + chunk] = ref.grid_interp(grid, g, geom.res, geom.index)
    return out


@torch.no_grad()
def cells_near(occ: Tensor, old: GridGeom, new: GridGeom, margin: int) -> Tensor:
    """Cells (rz-1, ry-1, rx-1) bool of the ``new`` grid whose centre lies within ``margin``
    cells of an occupied cell ``occ`` of the ``old`` grid (centres outside the old box
    take its nearest cell)."""
    cells = occ.float()[None, None]
    if margin:
        cells = F.max_pool3d(cells, kernel_size=2 * margin + 1, stride=1, padding=margin)
    cells = cells[0, 0] > 0
    nx, ny, nz = (r - 1 for r in new.res)
    dev = occ.device
    axes = [
        (new.lo[a].to(dev) + new.voxel * (torch.arange(n, device=dev) + 0.5) - old.lo[a].to(dev)) / old.voxel
        for a, n in enumerate((nx, ny, nz))
    ]
    ix, iy, iz = (torch.clamp(torch.floor(x), 0, r - 2).long() for x, r in zip(axes, old.res))
    return cells[iz[:, None, None], iy[None, :, None], ix[None, None, :]]
