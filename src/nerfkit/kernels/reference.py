"""Pure-torch reference implementations of the fast grid field's operations.

These are the slow, obviously-correct versions: each compiled kernel in
:mod:`nerfkit.kernels.grid_numba` is tested against them (values and gradients), and
they are the path used on CUDA or when numba is missing.

The grid is a dense *vertex* grid over an axis-aligned box: vertex ``(ix, iy, iz)`` sits
at ``lo + voxel * (ix, iy, iz)`` and its ``C`` feature channels are row
``(iz * ry + iy) * rx + ix`` of a flat ``(rx * ry * rz, C)`` tensor. Channel 0 is raw
density, channels ``1 + c * K + j`` are the spherical-harmonic coefficient ``j`` of colour
channel ``c`` (``K = (degree + 1) ** 2``).

A *sparse* grid stores only some vertices: an ``index`` (rx * ry * rz,) int32 gives the
feature row of each vertex, and every vertex without storage shares one row that
holds no density (:mod:`nerfkit.models.fast` keeps it at row 0 and never updates it).
With ``index=None`` the row of a vertex is its flat number.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ..render.box import cell_of, grid_coords  # noqa: F401  (re-exported: the kernels' reference rules)
from ..render.volrend import composite, distortion, render_weights

# Real spherical-harmonic constants (as in Plenoxels / instant-ngp / INRIA 3DGS): the splats' too
from ..splat_constants import SH_C0, SH_C1, SH_C2


def sh_dim(degree: int) -> int:
    """Number of SH basis functions up to ``degree``: ``(degree + 1) ** 2``."""
    return (degree + 1) ** 2


def sh_basis(dirs: Tensor, degree: int) -> Tensor:
    """Real spherical-harmonic basis of unit directions.

    Args:
        dirs: (n, 3) unit vectors.
        degree: 0, 1 or 2.

    Returns:
        (n, (degree + 1) ** 2). Example: degree 0 gives the constant 0.2821 for every direction.
    """
    if degree not in (0, 1, 2):
        raise ValueError(f"SH degree must be 0, 1 or 2, got {degree}")
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        out += [
            SH_C2[0] * x * y,
            SH_C2[1] * y * z,
            SH_C2[2] * (2 * z * z - x * x - y * y),
            SH_C2[3] * x * z,
            SH_C2[4] * (x * x - y * y),
        ]
    return torch.stack(out, dim=-1)


def trilinear_corners(g: Tensor, res: tuple[int, int, int]) -> tuple[Tensor, Tensor]:
    """The 8 vertices around grid coordinates and their trilinear weights.

    Args:
        g: (n, 3) grid coordinates (clamped into the box).
        res: vertex counts ``(rx, ry, rz)``, each >= 2.

    Returns:
        ``(idx, w)``: (n, 8) long flat vertex rows and (n, 8) weights summing to 1,
        corners ordered ``dz, dy, dx`` (dx fastest).
    """
    rx, ry, _ = res
    hi = torch.tensor([r - 1 for r in res], dtype=g.dtype, device=g.device)
    gc = torch.minimum(torch.clamp(g, min=0.0), hi)
    i0 = torch.minimum(torch.floor(gc), hi - 1)
    f = gc - i0
    i0 = i0.long()
    base = (i0[:, 2] * ry + i0[:, 1]) * rx + i0[:, 0]
    idx, w = [], []
    for dz in (0, 1):
        wz = f[:, 2] if dz else 1 - f[:, 2]
        for dy in (0, 1):
            wy = f[:, 1] if dy else 1 - f[:, 1]
            for dx in (0, 1):
                wx = f[:, 0] if dx else 1 - f[:, 0]
                idx.append(base + (dz * ry + dy) * rx + dx)
                w.append(wz * wy * wx)
    return torch.stack(idx, -1), torch.stack(w, -1)


def grid_interp(grid: Tensor, g: Tensor, res: tuple[int, int, int], index: Tensor | None = None) -> Tensor:
    """Trilinear interpolation of a flat vertex grid (differentiable in ``grid``).

    Args:
        grid: (rx * ry * rz, C) vertex features, or (M, C) rows of a sparse grid.
        g: (n, 3) grid coordinates.
        res: ``(rx, ry, rz)``.
        index: (rx * ry * rz,) the row of each vertex (sparse grids), or None.

    Returns:
        (n, C) interpolated features. Example: at an integer coordinate it returns that
        vertex's row exactly.
    """
    idx, w = trilinear_corners(g, res)
    if index is not None:
        idx = index[idx].long()
    return (grid[idx] * w.unsqueeze(-1)).sum(dim=1)


def decode(feat: Tensor, sh: Tensor, density_scale: float) -> tuple[Tensor, Tensor]:
    """Interpolated features -> density and colour.

    ``sigma = density_scale * softplus(feat[:, 0])`` (world units, 1/length) and
    ``rgb_c = sigmoid(sum_j feat[:, 1 + c K + j] * sh_j)``.

    Args:
        feat: (n, 1 + 3 K) features.
        sh: (n, K) SH basis of each sample's view direction.

    Returns:
        ``(sigma (n,), rgb (n, 3))``.
    """
    n, K = sh.shape
    sigma = density_scale * F.softplus(feat[:, 0])
    coef = feat[:, 1 : 1 + 3 * K].reshape(n, 3, K)
    rgb = torch.sigmoid((coef * sh.unsqueeze(1)).sum(-1))
    return sigma, rgb


def near_damping(x: Tensor, t: Tensor, grad_near: float) -> Tensor:
    """``x`` unchanged, with its gradient scaled by ``min(1, (t / grad_near)^2)``
    ("Floaters No More": damp updates just in front of the cameras). ``t`` broadcasts
    against ``x``; ``grad_near <= 0`` returns ``x``."""
    if grad_near <= 0:
        return x
    s = torch.clamp((t / grad_near) ** 2, max=1.0).to(x.dtype)
    return x * s + (x * (1 - s)).detach()


def render_samples(
    grid: Tensor,
    res: tuple[int, int, int],
    lo: Tensor,
    voxel: float,
    rays_o: Tensor,
    rays_d: Tensor,
    sh: Tensor,
    t: Tensor,
    ray_indices: Tensor,
    step: float,
    density_scale: float,
    t_end: Tensor | None = None,
    grad_near: float = 0.0,
    index: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Volume-render packed samples of the grid field (the reference for the fused kernel).

    Uses exactly :func:`~nerfkit.render.volrend.render_weights` and
    :func:`~nerfkit.render.volrend.composite` with interval length ``step`` for every
    sample.

    Args:
        grid: (N, C) vertex features; res, lo, voxel: the grid's geometry; index: the
            row of each vertex of a sparse grid (:func:`grid_interp`).
        rays_o, rays_d: (n_rays, 3); sh: (n_rays, K) SH basis of the ray directions.
        t: (n_samples,) sample distances; ray_indices: (n_samples,) their rays, in the
            packed layout of :mod:`nerfkit.render.volrend`.
        t_end: optional (n_rays,) where the distortion loss puts the leftover weight.
        grad_near: damp the gradients of samples nearer than this (:func:`near_damping`).

    Returns:
        ``(rgb (n_rays, 3) without background, depth (n_rays,), acc (n_rays,),
        distortion (n_rays,))``.
    """
    n_rays = rays_o.shape[0]
    pts = rays_o[ray_indices] + t.unsqueeze(-1) * rays_d[ray_indices]
    feat = grid_interp(grid, grid_coords(pts, lo, voxel), res, index)
    sigmas, rgbs = decode(feat, sh[ray_indices], density_scale)
    sigmas = near_damping(sigmas, t, grad_near)
    rgbs = near_damping(rgbs, t.unsqueeze(-1), grad_near)
    weights, _, _ = render_weights(sigmas, step, ray_indices)
    rgb, depth, acc = composite(weights, rgbs, ray_indices, n_rays, t.to(weights.dtype))
    assert depth is not None  # composite returns a depth when given t
    return rgb, depth, acc, distortion(weights, t.to(weights.dtype), step, ray_indices, n_rays, t_end)


def adam_rows(
    param: Tensor,
    g: Tensor,
    rows: Tensor,
    exp_avg: Tensor,
    exp_avg_sq: Tensor,
    lr: Tensor,
    beta1: float,
    beta2: float,
    eps: float,
    step: int,
) -> int:
    """Adam applied in place to the given rows only (lazy/sparse Adam).

    Args:
        param, exp_avg, exp_avg_sq: (N, C).
        g: (m, C) gradient of those rows.
        rows: (m,) long rows to update; other rows (and their moments) stay untouched.
        lr: (C,) per-channel learning rate.
        step: the (global) step count after this update, for bias correction.

    Returns:
        how many rows had a non-finite gradient; those rows are left as they were.
    """
    finite = torch.isfinite(g).all(dim=1)
    skipped = int((~finite).sum())
    if skipped:
        rows, g = rows[finite], g[finite]
    m = exp_avg[rows].mul_(beta1).add_(g, alpha=1 - beta1)
    v = exp_avg_sq[rows].mul_(beta2).addcmul_(g, g, value=1 - beta2)
    exp_avg[rows] = m
    exp_avg_sq[rows] = v
    bc1 = 1 - beta1**step
    bc2 = 1 - beta2**step
    denom = (v / bc2).sqrt_().add_(eps)
    param[rows] -= lr * (m / bc1) / denom
    return skipped


def tv_grad(grid: Tensor, index: Tensor, res: tuple[int, int, int], weight: Tensor) -> Tensor:
    """(M, C) gradient of the grid's total variation ``0.5 * sum over pairs of neighbour
    vertices (along x, y and z, both stored) of weight[c] * (grid[a, c] - grid[b, c])^2``.

    Args:
        grid: (M, C); index: (N,) int feature row of each vertex (0: not stored; a dense
            grid's is ``arange(N) + 1`` over a grid whose row 0 is unused); res: (rx, ry,
            rz) vertex counts; weight: (C,).
    """
    rx, ry, rz = res
    rows = index.long().reshape(rz, ry, rx)
    g = grid.detach().clone().requires_grad_(True)
    energy = g.new_zeros(())
    for axis in range(3):  # pairs along x, y, z: the last tensor axis is x
        dim = 2 - axis
        a, b = rows.narrow(dim, 0, rows.shape[dim] - 1), rows.narrow(dim, 1, rows.shape[dim] - 1)
        both = (a > 0) & (b > 0)
        diff = g[a[both]] - g[b[both]]
        energy = energy + 0.5 * (weight.to(g) * diff * diff).sum()
    (grad,) = torch.autograd.grad(energy, g)
    return grad
