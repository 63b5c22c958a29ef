"""Rendering the grid field and routing its sparse gradients, on either path.

* ``numba`` path (CPU): one fused kernel marches each ray through the occupancy grid,
  interpolates, shades and composites, keeping a compact record per sample; the
  backward kernel turns the upstream gradients into per-sample feature gradients and a
  race-free scatter adds them into a :class:`GradSink` (dense rows + touched flags),
  which :class:`~nerfkit.kernels.optim.GridAdam` consumes. The grid parameter itself
  gets no ``.grad``. When ``rays_o`` / ``rays_d`` require grad (camera-pose refinement)
  the same kernel also returns their gradients, and ``dL/dsh`` for torch to chain into
  ``rays_d``; the grid may then be frozen (no sink).
* ``torch`` path (CUDA, or no numba): :meth:`OccupancyGrid.sampling` +
  :func:`reference.render_samples` under autograd; the grid gets a dense ``.grad``.

Ray gradients on both paths hold each sample's ``t`` fixed.

Both paths produce the same samples (same lattice, same occupancy rule, same early
termination) and the same values; ``tests/test_kernels.py`` checks values and gradients.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor

from ..render.box import GridBox
from ..render.occupancy import occupied_samples
from . import numba_kernels
from . import reference as ref


@dataclass
class GridGeom:
    """Geometry of a vertex grid: box corner ``lo`` (3,), cubic ``voxel``, vertex counts
    ``res = (rx, ry, rz)``; the box is ``[lo, lo + voxel * (res - 1)]``.

    ``index`` (rx * ry * rz,) int32, for a sparse grid: the feature row of each vertex
    (vertices without storage share a row of no density); None: row = vertex number.
    ``dense_offset``: see :meth:`row_offset`.
    """

    lo: Tensor
    voxel: float
    res: tuple[int, int, int]
    index: Tensor | None = None
    dense_offset: int | None = field(default=None, compare=False)
    _offset_key: tuple | None = field(default=None, repr=False, compare=False)
    _offset: int = field(default=-1, repr=False, compare=False)

    def row_offset(self) -> int:
        """``c`` when every vertex ``v``'s row is ``v + c`` (a dense grid: the compiled
        kernels then skip the lookup), else -1. ``dense_offset``, when the owner of the
        index knows it; else found from the index and cached until the index changes."""
        if self.dense_offset is not None:
            return self.dense_offset
        if self.index is None:
            return 0
        key = (id(self.index), self.index._version)
        if key != self._offset_key:
            first = int(self.index[0]) if self.index.numel() else 0
            identity = torch.arange(first, first + self.index.numel(), dtype=self.index.dtype, device=self.index.device)
            self._offset = first if torch.equal(self.index, identity) else -1
            self._offset_key = key
        return self._offset

    def vertex_index(self) -> Tensor:
        """(rx * ry * rz,) int32 row of each vertex (the identity for a dense grid)."""
        if self.index is not None:
            return self.index
        return torch.arange(self.n_vertices, dtype=torch.int32, device=self.lo.device)

    @staticmethod
    def of(box: GridBox, index: Tensor | None = None, device=None, dense_offset: int | None = None) -> GridGeom:
        """The layout of a grid over ``box`` (its corner as a float32 tensor on ``device``)."""
        return GridGeom(box.lo_tensor(device), box.voxel, box.res, index, dense_offset=dense_offset)

    @property
    def box(self) -> GridBox:
        """The grid's :class:`GridBox` (corner rounded to float32, as the occupancy reads it)."""
        return GridBox(tuple(self.lo.detach().float().cpu().tolist()), self.voxel, self.res)

    @property
    def n_vertices(self) -> int:
        rx, ry, rz = self.res
        return rx * ry * rz

    @property
    def hi(self) -> Tensor:
        return self.lo + self.voxel * torch.tensor(
            [r - 1 for r in self.res], dtype=self.lo.dtype, device=self.lo.device
        )

    def vertex_positions(self, rows: Tensor | None = None) -> Tensor:
        """World positions (m, 3) of the given flat vertex rows (default: all)."""
        rx, ry, _ = self.res
        if rows is None:
            rows = torch.arange(self.n_vertices, device=self.lo.device)
        ijk = torch.stack([rows % rx, (rows // rx) % ry, rows // (rx * ry)], dim=-1)
        return self.lo + self.voxel * ijk.to(self.lo.dtype)


class GradSink:
    """Gradient of a (N, C) grid parameter, split into lanes, with per-row "touched" flags.

    The compiled backward adds into ``grad[lane]`` (one lane per worker, so no races) and
    marks ``touched``; the gradient is the sum over lanes. On the torch path the optimizer
    folds the parameter's dense ``.grad`` into lane 0 with :meth:`add_dense`.

    Attributes:
        grad: (lanes, N, C) float32; touched: (N,) uint8; dirty: anything to consume.
        frozen: the first ``frozen`` rows are constants (a sparse grid's empty row): the
            optimizer drops their gradient (:meth:`drop_frozen`).
    """

    def __init__(
        self,
        n_rows: int,
        n_channels: int,
        device: torch.device | str = "cpu",
        lanes: int | None = None,
        frozen: int = 0,
    ):
        if lanes is None:
            lanes = default_lanes() if torch.device(device).type == "cpu" else 1
        self.grad = torch.zeros((lanes, n_rows, n_channels), dtype=torch.float32, device=device)
        self.touched = torch.zeros(n_rows, dtype=torch.uint8, device=device)
        self.dirty = False
        self.frozen = int(frozen)

    def drop_frozen(self) -> None:
        """Forget the gradient of the frozen rows."""
        if self.frozen:
            self.grad[:, : self.frozen] = 0.0
            self.touched[: self.frozen] = 0

    @property
    def lanes(self) -> int:
        return self.grad.shape[0]

    def add_dense(self, g: Tensor) -> None:
        self.grad[0] += g
        self.touched |= (g != 0).any(dim=1).to(torch.uint8)
        self.dirty = True

    def touched_rows(self) -> Tensor:
        return torch.nonzero(self.touched, as_tuple=False).squeeze(1)

    def total(self, rows: Tensor) -> Tensor:
        """(m, C) gradient of the given rows, summed over lanes."""
        return self.grad[:, rows].sum(dim=0)

    def clear(self) -> None:
        if not self.dirty:
            return
        nb = numba_kernels() if self.grad.device.type == "cpu" else None
        if nb is not None:
            nb.clear_rows(self.grad.numpy(), nb.touched_rows(self.touched.numpy()), self.touched.numpy())
        else:
            rows = self.touched_rows()
            self.grad[:, rows] = 0.0
            self.touched.zero_()
        self.dirty = False


def default_lanes() -> int:
    """Gradient lanes for the compiled backward: one per numba thread, at most 8."""
    try:
        import numba

        return max(1, min(int(numba.get_num_threads()), 8))
    except Exception:
        return 1


class _Workspace:
    """Reusable per-sample buffers for the compiled training pass (grown as needed)."""

    def __init__(self):
        self.idx = np.zeros(0, np.int64)
        self.f = np.zeros(0, np.float32)
        self.busy = False

    def views(self, cap: int, n: int):
        from .grid_numba import N_FIELDS

        need = cap * n
        if self.idx.size < need:
            size = int(need * 1.25) + 1024
            self.idx = np.empty(size, np.int64)
            self.f = np.empty(size * N_FIELDS, np.float32)
        return self.idx[:need].reshape(cap, n), self.f[: need * N_FIELDS].reshape(cap, n, N_FIELDS)


class _Lease:
    """Holds a workspace for one forward/backward; frees it when released or collected."""

    def __init__(self, ws: _Workspace):
        ws.busy = True
        self.ws: _Workspace | None = ws

    def release(self) -> None:
        if self.ws is not None:
            self.ws.busy = False
            self.ws = None

    def __del__(self):
        self.release()


_POOL: list[_Workspace] = []


def _lease() -> _Lease:
    for ws in _POOL:
        if not ws.busy:
            return _Lease(ws)
    ws = _Workspace()
    _POOL.append(ws)
    return _Lease(ws)


@dataclass
class MarchSpec:
    """Everything the marcher needs besides rays.

    Attributes:
        occ: (rz-1, ry-1, rx-1) uint8 occupancy of the grid's cells.
        coarse: occupancy max-pooled by ``coarse_factor`` (uint8), for skipping empty blocks.
        step: sample spacing (= interval length); eps: early-termination transmittance.
        density_scale: ``sigma = density_scale * softplus(raw)``.
        grad_near: training only: gradients of samples nearer than this to the ray origin
            are scaled by ``(t / grad_near)^2`` (0: none; see :func:`reference.near_damping`).
    """

    occ: Tensor
    coarse: Tensor
    coarse_factor: int
    step: float
    eps: float
    density_scale: float
    grad_near: float = 0.0


# rays per work item of the compiled forward pass (dynamic scheduling)
RAY_CHUNK = 32


def _np64(x: Tensor) -> np.ndarray:
    return np.ascontiguousarray(x.detach().to("cpu", torch.float64).numpy())


def _np32(x: Tensor) -> np.ndarray:
    return np.ascontiguousarray(x.detach().to("cpu", torch.float32).numpy())


def _vertex_rows(geom: GridGeom) -> np.ndarray:
    return np.ascontiguousarray(geom.vertex_index().cpu().numpy().astype(np.int32, copy=False))


def _forward_numba(
    nb, grid: Tensor, geom: GridGeom, spec: MarchSpec, rays_o, rays_d, sh, t0, t1, u, store: bool, lease: _Lease | None
):
    n = rays_o.shape[0]
    rx, ry, rz = geom.res
    rgb = np.zeros((n, 3), np.float32)
    depth = np.zeros(n, np.float32)
    acc = np.zeros(n, np.float32)
    count = np.zeros(n, np.int32)
    t0n, t1n = _np64(t0), _np64(t1)
    if store:
        span = np.clip(t1n - t0n, 0.0, None)
        cap = int(math.ceil(float(span.max()) / spec.step)) + 2 if n else 1
        assert lease is not None and lease.ws is not None  # store=True comes with a live lease
        s_idx, s_f = lease.ws.views(cap, n)
    else:
        s_idx, s_f = np.zeros((0, n), np.int64), np.zeros((0, n, 9), np.float32)
    import numba

    # rays cost very different amounts: hand them out in small chunks, so that a thread
    # that finishes early (or a core the OS gives to another process) does not stall the rest
    with numba.parallel_chunksize(RAY_CHUNK):
        nb.render_forward(
            grid.detach().numpy(),
            _vertex_rows(geom),
            geom.row_offset(),
            rx,
            ry,
            rz,
            _np64(geom.lo),
            1.0 / geom.voxel,
            spec.occ.numpy(),
            spec.coarse.numpy(),
            int(spec.coarse_factor),
            _np64(rays_o),
            _np64(rays_d),
            _np32(sh),
            t0n,
            t1n,
            _np64(u),
            float(spec.step),
            float(spec.density_scale),
            float(spec.eps),
            rgb,
            depth,
            acc,
            count,
            store,
            s_idx,
            s_f,
        )
    return rgb, depth, acc, count, s_idx, s_f


class _NumbaRender(torch.autograd.Function):
    """The compiled training pass. Differentiable in ``grid`` (into ``sink``, not ``.grad``)
    and in ``rays_o``, ``rays_d`` and ``sh`` (with each sample's ``t`` fixed); the backward
    computes only the gradients asked for."""

    @staticmethod
    def forward(ctx, grid, rays_o, rays_d, sh, t0, t1, u, t_end, geom, spec, sink, nb, want_dist):
        lease = _lease()
        rgb, depth, acc, count, s_idx, s_f = _forward_numba(
            nb, grid, geom, spec, rays_o, rays_d, sh, t0, t1, u, True, lease
        )
        t_end = _np64(t_end)
        dist = np.zeros(len(count), np.float32)
        if want_dist:  # an extra pass over the samples, only when a loss uses it
            nb.distortion_forward(s_f, count, float(spec.step), t_end, dist)
        ctx.lease = lease
        ctx.saved = (rgb, depth, acc, count, s_idx, s_f, _np32(sh), grid.detach().numpy(), t_end)
        ctx.geom, ctx.spec, ctx.sink, ctx.nb = geom, spec, sink, nb
        ctx.ray_like = [torch.empty(0, dtype=x.dtype, device=x.device) for x in (rays_o, rays_d, sh)]
        ctx.n_samples = int(count.sum())
        out = [torch.from_numpy(a) for a in (rgb, depth, acc, count, dist)]
        ctx.mark_non_differentiable(out[3])
        return tuple(out)

    @staticmethod
    def backward(ctx, g_rgb, g_depth, g_acc, _g_count, g_dist):
        rgb, depth, acc, count, s_idx, s_f, sh, grid, t_end = ctx.saved
        n, K = sh.shape

        def arr(g, shape):
            return np.zeros(shape, np.float32) if g is None else _np32(g)

        need_grid, need_o, need_d, need_sh = ctx.needs_input_grad[:4]
        nb, sink, geom = ctx.nb, ctx.sink, ctx.geom
        if need_grid:
            grads, touched = sink.grad.numpy(), sink.touched.numpy()
        else:  # no grid gradient: empty lanes, still one per worker
            grads, touched = np.zeros((default_lanes(), 0, grid.shape[1]), np.float32), np.zeros(0, np.uint8)
        ray_grads = need_o or need_d or need_sh
        m = n if ray_grads else 0
        g_o, g_d, g_sh = np.zeros((m, 3)), np.zeros((m, 3)), np.zeros((m, K))
        nb.render_backward(
            s_idx,
            s_f,
            count,
            sh,
            grid,
            _vertex_rows(geom),
            geom.row_offset(),
            geom.res[0],
            geom.res[1],
            1.0 / geom.voxel,
            float(ctx.spec.step),
            float(ctx.spec.density_scale),
            rgb,
            depth,
            acc,
            arr(g_rgb, (n, 3)),
            arr(g_depth, (n,)),
            arr(g_acc, (n,)),
            arr(g_dist, (n,)),
            t_end,
            float(ctx.spec.grad_near),
            grads,
            touched,
            ray_grads,
            g_o,
            g_d,
            g_sh,
        )
        if need_grid:
            sink.dirty = True
        ctx.lease.release()
        ctx.saved = None
        ray_out = [
            torch.from_numpy(g).to(like) if need else None
            for g, like, need in zip((g_o, g_d, g_sh), ctx.ray_like, (need_o, need_d, need_sh))
        ]
        return (None, *ray_out) + (None,) * 9


@dataclass
class GridRender:
    """Output of :func:`render_grid`: foreground colour (n, 3) (no background), expected
    depth (n,), opacity (n,), samples per ray (n,), the total number of samples, and
    (when training) each ray's distortion loss (n,)
    (:func:`~nerfkit.render.volrend.distortion`)."""

    rgb: Tensor
    depth: Tensor
    acc: Tensor
    counts: Tensor
    n_samples: int
    distortion: Tensor | None = None


def render_grid(
    grid: Tensor,
    geom: GridGeom,
    spec: MarchSpec,
    rays_o: Tensor,
    rays_d: Tensor,
    t0: Tensor,
    t1: Tensor,
    u: Tensor,
    sh_degree: int,
    sink: GradSink | None,
    backend: str,
    t_end: Tensor | None = None,
    distortion: bool = False,
    view_dirs: Tensor | None = None,
) -> GridRender:
    """Render rays through the grid field, differentiable in whichever of ``grid``,
    ``rays_o`` and ``rays_d`` require grad.

    Ray gradients hold every sample's ``t`` fixed (the lattice ``t0 + (k + u) step`` and
    the choice of samples are constants, as in nerfacc): ``t0``, ``t1`` and ``u`` get no
    gradient even when computed from the rays.

    Args:
        grid: (N, C) vertex features, ``C >= 1 + 3 (sh_degree + 1)^2``.
        rays_o, rays_d: (n, 3); t0, t1: (n,) segment inside the box and [near, far];
        u: (n,) lattice jitter in [0, 1).
        sink: where the compiled backward puts the grid gradient (needed when the grid
            requires grad; may be None for a frozen grid).
        backend: ``"numba"`` or ``"torch"``.
        t_end: (n,) where the distortion loss puts each ray's leftover weight (e.g. the
            table behind the box; inf or None: nowhere).
        distortion: compute each ray's distortion loss (training only; the compiled path
            skips that pass otherwise and returns no distortion).
        view_dirs: (n, 3) the directions the colour depends on, when the rays are not in
            world space (NDC rays); default ``rays_d``.
    """
    sh = ref.sh_basis((rays_d if view_dirs is None else view_dirs).float(), sh_degree)
    nb = numba_kernels() if backend == "numba" else None
    if nb is not None and grid.device.type == "cpu":
        if torch.is_grad_enabled() and (grid.requires_grad or rays_o.requires_grad or rays_d.requires_grad):
            if grid.requires_grad and sink is None:
                raise ValueError("render_grid: a GradSink is needed to train the grid on the compiled path")
            ends = t_end if t_end is not None else torch.full_like(t0, math.inf)
            rgb, depth, acc, counts, dist = _NumbaRender.apply(
                grid, rays_o, rays_d, sh, t0, t1, u, ends, geom, spec, sink, nb, distortion
            )
            dist = dist if distortion else None
        else:
            out = _forward_numba(nb, grid, geom, spec, rays_o, rays_d, sh, t0, t1, u, False, None)
            rgb, depth, acc, counts = (torch.from_numpy(a) for a in out[:4])
            dist = None
        dev = rays_o.device
        return GridRender(
            rgb.to(dev),
            depth.to(dev),
            acc.to(dev),
            counts.to(dev),
            int(counts.sum()),
            None if dist is None else dist.to(dev),
        )
    out = render_grid_torch(grid, geom, spec, rays_o, rays_d, t0, t1, u, sh, t_end)
    return out if distortion else replace(out, distortion=None)


def render_grid_torch(
    grid, geom: GridGeom, spec: MarchSpec, rays_o, rays_d, t0, t1, u, sh, t_end: Tensor | None = None
) -> GridRender:
    """The pure-torch path of :func:`render_grid`: autograd gives the grid a dense grad and
    the rays (``rays_o``, ``rays_d``, ``sh``) their gradients with the sample ``t`` fixed."""
    dtype = rays_o.dtype
    lo = geom.lo.to(grid.device, dtype)

    def sigma_fn(points, _ray_indices):
        raw = ref.grid_interp(grid.detach()[:, :1], ref.grid_coords(points, lo, geom.voxel), geom.res, geom.index)[:, 0]
        return spec.density_scale * torch.nn.functional.softplus(raw)

    # sampling runs under no_grad, so the lattice t are constants (as in nerfacc and the
    # compiled backward): rays get gradients only through the points o + t d and the SH basis
    samples = occupied_samples(spec.occ, geom.box, rays_o, rays_d, t0, t1, u, spec.step, sigma_fn, spec.eps)
    rgb, depth, acc, dist = ref.render_samples(
        grid,
        geom.res,
        lo,
        geom.voxel,
        rays_o,
        rays_d,
        sh.to(grid.dtype),
        samples.t,
        samples.ray_indices,
        spec.step,
        spec.density_scale,
        t_end,
        spec.grad_near,
        geom.index,
    )
    counts = samples.counts().int()
    return GridRender(rgb, depth, acc, counts, int(counts.sum()), dist)


def row_vertices(geom: GridGeom, n_rows: int) -> Tensor:
    """(n_rows,) int64 vertex of each feature row (row 0, the empty row: vertex 0)."""
    index = geom.vertex_index().long()
    out = torch.zeros(n_rows, dtype=torch.int64, device=index.device)
    stored = torch.nonzero(index > 0)[:, 0]
    out[index[stored]] = stored
    return out


def add_grid_tv(
    grid: Tensor, geom: GridGeom, weight: Tensor, sink: GradSink, backend: str, row_vertex: Tensor | None = None
) -> int:
    """Add the total variation's gradient (:func:`reference.tv_grad`) on the rows that this
    step's rays touched (their gradient is in ``sink``, or on the torch path in
    ``grid.grad``). Only those rows: under Adam's per-row scaling a row that only the
    regulariser moved would move at full speed whatever the weight.

    Args:
        grid: (M, C) with row 0 the empty row; weight: (C,) per channel; row_vertex: from
            :func:`row_vertices` (needed by the compiled path for a sparse grid).

    Returns:
        how many rows were regularised.
    """
    nb = numba_kernels() if backend == "numba" and grid.device.type == "cpu" else None
    if nb is not None:
        rows = nb.touched_rows(sink.touched.numpy())
        rows = rows[rows > 0]
        off = geom.row_offset()
        if off >= 0:  # a dense grid: the kernel computes each row's vertex
            rv = torch.zeros(0, dtype=torch.int64)
        else:
            rv = row_vertex if row_vertex is not None else row_vertices(geom, grid.shape[0])
        rx, ry, rz = geom.res
        nb.tv_rows(
            grid.detach().numpy(),
            _vertex_rows(geom),
            off,
            rv.numpy(),
            rx,
            ry,
            rz,
            rows,
            _np32(weight),
            sink.grad[0].numpy(),
        )
        return len(rows)
    if grid.grad is None:
        return 0
    touched = grid.grad.ne(0).any(dim=1)
    touched[0] = False
    g = ref.tv_grad(grid, geom.vertex_index(), geom.res, weight.to(grid.device))
    grid.grad[touched] += g[touched]
    return int(touched.sum())


def cell_density_max(grid: Tensor, geom: GridGeom, density_scale: float) -> Tensor:
    """An exact upper bound of the density inside each cell: (rz-1, ry-1, rx-1).

    Trilinear interpolation never exceeds the largest of a cell's 8 vertex values, and
    softplus is increasing, so ``density_scale * softplus(max corner raw)`` bounds every
    sample in the cell.
    """
    rx, ry, rz = geom.res
    raw = grid.detach()[:, 0]
    if geom.index is not None:
        raw = raw[geom.index.long()]
    raw = raw.reshape(1, 1, rz, ry, rx)
    mx = torch.nn.functional.max_pool3d(raw, kernel_size=2, stride=1)[0, 0]
    return density_scale * torch.nn.functional.softplus(mx)
