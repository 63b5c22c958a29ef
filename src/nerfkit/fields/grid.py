"""A sparse vertex grid as a radiance field (Plenoxels/DVGO style: no network).

Per vertex a raw density and spherical-harmonic colour coefficients, trilinearly
interpolated, then ``sigma = density_scale * softplus(raw)`` and ``rgb = sigmoid(SH(dir) .
coef)``. The grid stores feature rows only for some vertices: an int32 index maps every
vertex to its row, and the vertices without storage share row 0, which holds no density
and is never updated. Gradients gather in a :class:`~nerfkit.kernels.ops.GradSink` (the
optimizer updates touched rows only).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..data.validate import short_repr
from ..errors import fail
from ..kernels import numba_kernels, numba_refused
from ..kernels import reference as ref
from ..kernels.ops import GradSink, GridGeom, GridRender, MarchSpec, cell_density_max, render_grid
from ..render.box import GridBox

# Largest grid: each side and the vertex count (512^3 vertices of 4+ float32 channels: 2+ GB).
MAX_GRID_SIDE = 4096
MAX_GRID_VERTICES = 512**3
# the raw density of a vertex without storage (softplus(-30) = 1e-13: no density)
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


def softplus_inverse(x: float) -> float:
    """The raw value whose softplus is ``x`` (``x`` itself from 20 on, where they agree)."""
    return float(math.log(math.expm1(x))) if x < 20 else x


class GridField(nn.Module):
    """The grid's parameters and layout, and the field they hold.

    Args:
        box: the grid's box (its vertex counts: every vertex stored, densities empty).
        sh_degree: degree of the colour's spherical harmonics.
        kernels: "auto" (the compiled CPU kernels when numba is there), "numba" or "torch".

    Attributes:
        grid: (rows, 1 + 3 K) parameter; row 0 holds no density, forever.
        vertex_rows: (rx * ry * rz,) int32 buffer, the row of each vertex (0: not stored).
        density_scale: ``sigma = density_scale * softplus(raw)``; the first box's 1 / voxel.
    """

    grid: nn.Parameter
    vertex_rows: Tensor
    lo: Tensor

    def __init__(self, box: GridBox, sh_degree: int, kernels: str = "auto"):
        super().__init__()
        self.sh_degree = sh_degree
        self.K = ref.sh_dim(sh_degree)
        self.n_channels = 1 + 3 * self.K
        self.kernels = kernels
        self.density_scale = 1.0 / box.voxel
        n = box.n_vertices
        self.grid = nn.Parameter(self.empty_rows(n + 1))
        self.set_geometry(box, torch.arange(1, n + 1, dtype=torch.int32))
        self.sink = self.new_sink()

    # -- layout ----------------------------------------------------------------------
    def set_geometry(self, box: GridBox, index: Tensor) -> None:
        """Install the grid's box and ``index`` (N,) int32: the feature row of each vertex
        (0: not stored)."""
        device = self.grid.device
        self.register_buffer("vertex_rows", index.to(device=device, dtype=torch.int32).contiguous())
        self.register_buffer("lo", box.lo_tensor(device), persistent=False)
        self.box = box
        self.row_offset = GridGeom(self.lo, box.voxel, box.res, self.vertex_rows).row_offset()

    def set_rows(self, rows: Tensor) -> nn.Parameter:
        """Install ``rows`` (m, C) as the grid (a fresh gradient sink); returns the old parameter."""
        old, self.grid = self.grid, nn.Parameter(rows)
        self.sink = self.new_sink()
        return old

    @property
    def voxel(self) -> float:
        return self.box.voxel

    @property
    def res(self) -> tuple[int, int, int]:
        return self.box.res

    @property
    def geom(self) -> GridGeom:
        """The grid's layout (its corner on the grid's device, the vertex rows)."""
        return GridGeom(self.lo, self.box.voxel, self.box.res, self.vertex_rows, dense_offset=self.row_offset)

    @property
    def stored_vertices(self) -> int:
        """How many vertices have their own feature row."""
        return self.grid.shape[0] - 1

    def empty_rows(self, n: int, device=None) -> Tensor:
        """(n, C) rows of no density and no colour."""
        rows = torch.zeros((n, self.n_channels), device=device)
        rows[:, 0] = EMPTY_RAW
        return rows

    def new_sink(self) -> GradSink:
        return GradSink(self.grid.shape[0], self.n_channels, self.grid.device, frozen=1)

    def sink_on_device(self) -> bool:
        """Rebuild the (empty) gradient sink beside the grid after the model moved; whether it was."""
        if self.sink.grad.device == self.grid.device:
            return False
        self.sink = self.new_sink()
        return True

    def raw_for_alpha(self, alpha: float, step: float) -> float:
        """The raw density at which one sample of length ``step`` is ``alpha`` opaque."""
        return softplus_inverse(-math.log1p(-alpha) / step / self.density_scale)

    def backend(self) -> str:
        """ "numba" (the compiled CPU kernels) or "torch"."""
        if self.kernels == "torch" or self.grid.device.type != "cpu":
            return "torch"
        if numba_kernels() is None:
            if self.kernels == "numba":
                raise numba_refused()
            return "torch"
        return "numba"

    # -- the field -------------------------------------------------------------------
    def inside(self, pts: Tensor) -> Tensor:
        """(n,) bool: grid-space points ``pts`` (n, 3) within the box."""
        geom = self.geom
        return ((pts >= geom.lo) & (pts <= geom.hi)).all(-1)

    def query(self, pts: Tensor, directions: Tensor) -> tuple[Tensor, Tensor]:
        """Grid-space points (n, 3) and view directions -> (n,) density (0 outside the box), (n, 3) colour."""
        geom = self.geom
        feat = ref.grid_interp(self.grid, ref.grid_coords(pts, geom.lo, geom.voxel), geom.res, geom.index)
        sigma, rgb = ref.decode(feat, ref.sh_basis(directions.float(), self.sh_degree), self.density_scale)
        return sigma * self.inside(pts), rgb

    def density(self, pts: Tensor) -> Tensor:
        """Grid-space points (n, 3) -> (n,) density (0 outside the box)."""
        geom = self.geom
        raw = ref.grid_interp(self.grid[:, :1], ref.grid_coords(pts, geom.lo, geom.voxel), geom.res, geom.index)
        return self.density_scale * F.softplus(raw[:, 0]) * self.inside(pts)

    def render(self, spec: MarchSpec, o: Tensor, d: Tensor, t0: Tensor, t1: Tensor, u: Tensor, **kw) -> GridRender:
        """:func:`~nerfkit.kernels.ops.render_grid` of this grid (differentiable)."""
        return render_grid(self.grid, self.geom, spec, o, d, t0, t1, u, self.sh_degree, self.sink, self.backend(), **kw)

    @torch.no_grad()
    def density_volume(self) -> tuple[np.ndarray, list[np.ndarray], Tensor]:
        """The density at the vertices as an (X, Y, Z) float32 array, the x, y and z positions
        of the vertices ((X,), (Y,), (Z,) float64), and the (X, Y, Z) feature rows."""
        rx, ry, rz = self.res
        lo = np.asarray(self.box.lo, np.float64)
        axes = [lo[a] + self.voxel * np.arange(r) for a, r in enumerate(self.res)]
        rows = self.vertex_rows.long().reshape(rz, ry, rx).permute(2, 1, 0)  # [x, y, z], as axes
        sigma = (self.density_scale * F.softplus(self.grid.detach()[:, 0]))[rows]
        return sigma.cpu().numpy(), axes, rows

    @torch.no_grad()
    def clear(self, vertices: np.ndarray) -> None:
        """Empty the density of the vertices ``vertices`` ((X, Y, Z) bool, as :meth:`density_volume`)."""
        rows = self.density_volume()[2][torch.from_numpy(vertices).to(self.grid.device)]
        self.grid[rows[rows > 0], 0] = EMPTY_RAW

    # -- occupancy -------------------------------------------------------------------
    @torch.no_grad()
    def alpha_threshold(self, alpha_max: float, step: float, n_probe: int = 1 << 14) -> float:
        """``min(alpha_max, mean cell opacity)`` (as instant-ngp): early in training, when
        every density is still tiny, only the cells below average are skipped. The mean
        is estimated on ``n_probe`` random cells (fixed seed)."""
        rx, ry, rz = self.res
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
        alpha = -torch.expm1(-self.density_scale * F.softplus(raw) * step)
        return min(alpha_max, float(alpha.mean()))

    @torch.no_grad()
    def occupancy(self, step: float, alpha: float, coarse_factor: int) -> tuple[Tensor, Tensor] | Tensor:
        """The cells where one sample of length ``step`` may be more than ``alpha`` opaque
        (an exact bound per cell): ``(occ, coarse)`` uint8 from the compiled kernel, else
        the (rz - 1, ry - 1, rx - 1) maximum density per cell, for the estimator to threshold."""
        nb = numba_kernels() if self.backend() == "numba" else None
        if nb is None:
            return cell_density_max(self.grid, self.geom, self.density_scale)
        rx, ry, rz = self.res
        occ = torch.empty((rz - 1, ry - 1, rx - 1), dtype=torch.uint8)
        cf = max(coarse_factor, 1)
        coarse = torch.zeros((-(-(rz - 1) // cf), -(-(ry - 1) // cf), -(-(rx - 1) // cf)), dtype=torch.uint8)
        raw = softplus_inverse(-math.log1p(-alpha) / (step * self.density_scale))
        nb.occupancy_from_grid(
            self.grid.detach().numpy(), self.vertex_rows.numpy(), self.row_offset, rx, ry, rz, raw, occ.numpy(),
            coarse.numpy(), cf,
        )  # fmt: skip
        return occ, coarse

    # -- checkpoints -----------------------------------------------------------------
    def layout(self) -> dict:
        """The grid's layout as JSON-able values (a checkpoint's, beside its tensors)."""
        geom = self.geom
        return {
            "lo": [float(v) for v in geom.lo.cpu()],
            "voxel": geom.voxel,
            "res": list(geom.res),
            "rows": int(self.grid.shape[0]),
            "density_scale": self.density_scale,
        }

    def load_layout(self, state: dict, where: str) -> GridBox:
        """Take the :meth:`layout` ``state`` (read from ``where``), checked before allocating:
        the grid gets its box and an (empty) grid of its rows, for the tensors to fill."""
        fix = "The checkpoint is corrupt or not from nerfkit; delete it or re-train"
        res = check_grid_res(state["res"], where, "res", fix)
        n = res[0] * res[1] * res[2]
        rows = state.get("rows", n + 1)
        if not (isinstance(rows, int) and 1 <= rows <= n + 1):
            raise fail(where, f"'rows' is {short_repr(rows)}, expected 1 to {n + 1} for a grid of {n} vertices", fix)
        self.density_scale = float(state["density_scale"])
        lo = np.asarray(state["lo"], np.float32).reshape(3).tolist()
        box = GridBox((lo[0], lo[1], lo[2]), float(state["voxel"]), res)
        self.set_geometry(box, torch.zeros(n, dtype=torch.int32))
        self.set_rows(torch.zeros((rows, self.n_channels), device=self.grid.device))
        return box

    def check_index(self, index: Tensor, rows: int) -> None:
        """Refuse a vertex index with rows outside ``rows`` (the compiled kernels do not check bounds)."""
        if index.numel() and not (int(index.min()) >= 0 and int(index.max()) < rows):
            raise ValueError(
                f"vertex_rows holds rows {int(index.min())}..{int(index.max())}, outside the grid's {rows} rows"
            )


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
