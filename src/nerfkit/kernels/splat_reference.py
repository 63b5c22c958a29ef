"""3D Gaussian splatting in plain torch: the obviously-correct reference.

Conventions follow the INRIA 3DGS code (so a model exported to its PLY renders the same
in other viewers), in nerfkit's camera convention (OpenCV axes, pixel centres at +0.5):

* a Gaussian has a mean (3,), log-scales (3,), a rotation quaternion ``(w, x, y, z)``,
  an opacity logit and spherical-harmonic colour coefficients (INRIA's real SH, up to
  degree 3, colour = SH + 0.5 clamped at 0);
* EWA projection ``cov2d = J W Sigma W^T J^T + 0.3 I`` (the 0.3 px dilation), the
  view-space x/y clamped to 1.3 x the half field of view before computing ``J``;
* the screen footprint is 3 sigma of the larger eigenvalue, binned into 16 x 16 tiles;
* per pixel, front to back in depth order: ``alpha = min(0.99, opacity * exp(power))``,
  skipped below 1/255 (or when ``power > 0``), and compositing stops before a Gaussian
  that would bring the transmittance below 1e-4.

These numbers live in :mod:`nerfkit.splat_constants` (the compiled kernels import them too).

:func:`rasterize_reference` composites each tile densely (every Gaussian of the tile
against every pixel of it) with autograd; the compiled kernels in
:mod:`nerfkit.kernels.splat_numba` must match it in values and gradients.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from ..splat_constants import ALPHA_MAX, ALPHA_MIN, DILATION, FOV_CLIP, SH_C0, SH_C3, T_MIN, TILE
from . import reference as grid_reference

# SSIM (the training loss's D-SSIM): Gaussian window, its sigma, the stabilising constants
SSIM_WINDOW, SSIM_SIGMA = 11, 1.5
SSIM_C1, SSIM_C2 = 0.01**2, 0.03**2


def sh_coeffs(degree: int) -> int:
    """Coefficients per channel of SH up to ``degree``: (degree + 1)^2."""
    return (degree + 1) ** 2


def rgb_to_sh_dc(rgb: Tensor) -> Tensor:
    """The DC coefficient that shows colour ``rgb``: ``(rgb - 0.5) / C0``."""
    return (rgb - 0.5) / SH_C0


def sh_basis(dirs: Tensor, degree: int) -> Tensor:
    """INRIA's real SH basis at (n, 3) unit directions: (n, (degree + 1)^2), in the order of
    the coefficients: the grid's basis (:func:`nerfkit.kernels.reference.sh_basis`, the same
    signs: ``-C1 y, C1 z, -C1 x`` for degree one) up to degree 2, then degree 3's."""
    low = grid_reference.sh_basis(dirs, min(degree, 2))
    if degree < 3:
        return low
    x, y, z = dirs.unbind(-1)
    xx, yy, zz, xy = x * x, y * y, z * z, x * y
    third = [
        SH_C3[0] * y * (3 * xx - yy),
        SH_C3[1] * xy * z,
        SH_C3[2] * y * (4 * zz - xx - yy),
        SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
        SH_C3[4] * x * (4 * zz - xx - yy),
        SH_C3[5] * z * (xx - yy),
        SH_C3[6] * x * (xx - 3 * yy),
    ]
    return torch.cat([low, torch.stack(third, -1)], -1)


def sh_to_rgb(coeffs: Tensor, dirs: Tensor, degree: int) -> Tensor:
    """INRIA's SH colour: (n, K, 3) coefficients, (n, 3) unit directions -> (n, 3).

    Uses the first ``(degree + 1)^2`` coefficients; the result is ``max(SH + 0.5, 0)``.
    Example: only a DC of ``(c - 0.5) / C0`` gives colour ``c`` from every direction.
    The basis (:func:`sh_basis`) times the coefficients is one batched product: its
    gradient to the coefficients is one tensor (a term per coefficient, each indexing
    ``coeffs``, made autograd fill a zero tensor of the coefficients' size for each).
    """
    basis = sh_basis(dirs, degree).to(coeffs.dtype)
    out = torch.bmm(basis.unsqueeze(1), coeffs[:, : basis.shape[1]]).squeeze(1)
    return torch.clamp_min(out + 0.5, 0.0)


def quat_to_rotmat(q: Tensor) -> Tensor:
    """(n, 4) quaternions ``(w, x, y, z)`` (any length) -> (n, 3, 3) rotation matrices."""
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        -1,
    ).reshape(-1, 3, 3)


def covariance_3d(log_scales: Tensor, quats: Tensor) -> Tensor:
    """(n, 3) log-scales and (n, 4) quaternions -> (n, 3, 3) ``R S S^T R^T``."""
    M = quat_to_rotmat(quats) * torch.exp(log_scales).unsqueeze(-2)  # R @ diag(s)
    return M @ M.transpose(-1, -2)


def project_gaussians(
    means: Tensor, cov3d: Tensor, w2c: Tensor, K: Tensor, width: int, height: int, near_plane: float
) -> dict:
    """EWA projection of Gaussians into one camera (OpenCV axes).

    Args:
        means: (n, 3) world; cov3d: (n, 3, 3); w2c: (4, 4) world-to-camera; K: (3, 3).
        near_plane: Gaussians whose centre is nearer than this (view z) are culled.

    Returns a dict of
        ``means2d`` (n, 2) pixel coordinates (pixel centres at +0.5), ``conics`` (n, 3)
        the inverse 2D covariance ``(a, b, c)`` with ``power = -a dx^2 / 2 - b dx dy - c dy^2 / 2``,
        ``depths`` (n,) view z, ``radii`` (n,) int pixels (0: culled) and ``rects`` (n, 4)
        int32 tile rectangle ``[x0, x1) x [y0, y1)`` (empty when culled). Differentiable in
        means, cov3d (radii and rects are not).
    """
    R, t = w2c[:3, :3].to(means), w2c[:3, 3].to(means)
    p = means @ R.T + t
    tx, ty, tz = p.unbind(-1)
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    tzc = tz.clamp_min(near_plane)
    limx, limy = FOV_CLIP * 0.5 * width / fx, FOV_CLIP * 0.5 * height / fy
    txc = (tx / tzc).clamp(-limx, limx) * tzc
    tyc = (ty / tzc).clamp(-limy, limy) * tzc
    zero = torch.zeros_like(tz)
    J = torch.stack([fx / tzc, zero, -fx * txc / (tzc * tzc), zero, fy / tzc, -fy * tyc / (tzc * tzc)], -1).reshape(
        -1, 2, 3
    )
    T = J @ R
    cov2d = T @ cov3d @ T.transpose(-1, -2)
    a = cov2d[:, 0, 0] + DILATION
    b = cov2d[:, 0, 1]
    c = cov2d[:, 1, 1] + DILATION
    det = a * c - b * b
    valid = (tz > near_plane) & (det > 0)
    det_safe = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c / det_safe, -b / det_safe, a / det_safe], -1)
    means2d = torch.stack([fx * tx / tzc + cx, fy * ty / tzc + cy], -1)
    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam = mid + torch.sqrt(torch.clamp_min(mid * mid - det, 0.1))
        radii = torch.ceil(3.0 * torch.sqrt(lam.clamp_min(0)))
        px, py = means2d[:, 0] - 0.5, means2d[:, 1] - 0.5  # INRIA's pixel coordinates
        tw, th = -(-width // TILE), -(-height // TILE)
        x0 = torch.floor((px - radii) / TILE).clamp(0, tw)
        x1 = torch.floor((px + radii + TILE - 1) / TILE).clamp(0, tw)
        y0 = torch.floor((py - radii) / TILE).clamp(0, th)
        y1 = torch.floor((py + radii + TILE - 1) / TILE).clamp(0, th)
        valid = valid & torch.isfinite(radii) & (x1 > x0) & (y1 > y0)
        rects = torch.stack([x0, x1, y0, y1], -1).nan_to_num(0)
        rects = torch.where(valid.unsqueeze(-1), rects, torch.zeros_like(rects)).to(torch.int32)
        radii = torch.where(valid, radii, torch.zeros_like(radii)).to(torch.int32)
    return {"means2d": means2d, "conics": conics, "depths": tz, "radii": radii, "rects": rects}


def depth_order(depths: Tensor, rects: Tensor) -> Tensor:
    """Indices of the visible Gaussians (non-empty rect), nearest first (stable)."""
    visible = (rects[:, 1] > rects[:, 0]) & (rects[:, 3] > rects[:, 2])
    idx = torch.nonzero(visible).squeeze(1)
    order = torch.sort(depths.detach()[idx], stable=True).indices
    return idx[order]


def rasterize_reference(
    means2d: Tensor,
    conics: Tensor,
    colors: Tensor,
    opacities: Tensor,
    depths: Tensor,
    rects: Tensor,
    background: Tensor,
    width: int,
    height: int,
) -> tuple[Tensor, Tensor, Tensor]:
    """Front-to-back alpha compositing of projected Gaussians, tile by tile (autograd).

    Args:
        means2d (n, 2), conics (n, 3), colors (n, 3), opacities (n,) in [0, 1], depths (n,),
        rects (n, 4) int tile rectangles from :func:`project_gaussians`;
        background: (H, W, 3) colour behind everything.

    Returns:
        ``rgb`` (H, W, 3), ``depth`` (H, W) the weighted sum of depths (unnormalised),
        ``alpha`` (H, W) = 1 - final transmittance.
    """
    order = depth_order(depths, rects)
    tw, th = -(-width // TILE), -(-height // TILE)
    rgb = torch.zeros((height, width, 3), dtype=colors.dtype, device=colors.device)
    depth = torch.zeros((height, width), dtype=colors.dtype, device=colors.device)
    alpha_out = torch.zeros((height, width), dtype=colors.dtype, device=colors.device)
    r = rects[order].long()
    rgb_rows, dep_rows, acc_rows = [], [], []
    for ty in range(th):
        rgb_row, dep_row, acc_row = [], [], []
        for tx in range(tw):
            x0, y0 = tx * TILE, ty * TILE
            x1, y1 = min(x0 + TILE, width), min(y0 + TILE, height)
            ids = order[(r[:, 0] <= tx) & (tx < r[:, 1]) & (r[:, 2] <= ty) & (ty < r[:, 3])]
            ys, xs = torch.meshgrid(
                torch.arange(y0, y1, device=colors.device), torch.arange(x0, x1, device=colors.device), indexing="ij"
            )
            pix = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1).to(colors.dtype) + 0.5  # (P, 2)
            bg = background[y0:y1, x0:x1].reshape(-1, 3)
            if len(ids) == 0:
                c, d, a = bg, pix.new_zeros(len(pix)), pix.new_zeros(len(pix))
            else:
                c, d, a = composite_pixels(pix, means2d[ids], conics[ids], colors[ids], opacities[ids], depths[ids], bg)
            rgb_row.append(c.reshape(y1 - y0, x1 - x0, 3))
            dep_row.append(d.reshape(y1 - y0, x1 - x0))
            acc_row.append(a.reshape(y1 - y0, x1 - x0))
        rgb_rows.append(torch.cat(rgb_row, 1))
        dep_rows.append(torch.cat(dep_row, 1))
        acc_rows.append(torch.cat(acc_row, 1))
    if rgb_rows:
        rgb, depth, alpha_out = torch.cat(rgb_rows, 0), torch.cat(dep_rows, 0), torch.cat(acc_rows, 0)
    return rgb, depth, alpha_out


def composite_pixels(
    pix: Tensor, means2d: Tensor, conics: Tensor, colors: Tensor, opacities: Tensor, depths: Tensor, bg: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """Composite ``m`` Gaussians (already in depth order) over ``P`` pixels ``pix`` (P, 2).

    Returns ``(rgb (P, 3), depth (P,), alpha (P,))``. See the module docstring for the rules.
    """
    d = means2d.unsqueeze(0) - pix.unsqueeze(1)  # (P, m, 2)
    dx, dy = d[..., 0], d[..., 1]
    power = -0.5 * (conics[:, 0] * dx * dx + conics[:, 2] * dy * dy) - conics[:, 1] * dx * dy
    alpha = torch.clamp(opacities * torch.exp(power), max=ALPHA_MAX)
    alpha = torch.where((power > 0) | (alpha < ALPHA_MIN), torch.zeros_like(alpha), alpha)
    keep = torch.cumprod(1 - alpha.detach(), dim=1) >= T_MIN  # stop before T would fall below T_MIN
    alpha = alpha * keep
    one_minus = 1 - alpha
    T = torch.cat([torch.ones_like(alpha[:, :1]), torch.cumprod(one_minus, dim=1)[:, :-1]], 1)
    w = alpha * T
    T_final = T[:, -1] * one_minus[:, -1]
    rgb = w @ colors + T_final.unsqueeze(-1) * bg
    return rgb, w @ depths, 1 - T_final


def logit(p: float) -> float:
    return math.log(p / (1 - p))


def ssim_reference(img: Tensor, target: Tensor, window: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> Tensor:
    """Mean SSIM of two (H, W, 3) images in [0, 1] (Gaussian window, separable, 'valid' area
    as 'same' with zero padding, as 3DGS)."""
    x = img.permute(2, 0, 1).unsqueeze(0)
    y = target.permute(2, 0, 1).unsqueeze(0)
    g = ssim_window(window, sigma, x)
    C = x.shape[1]
    kx = g.reshape(1, 1, 1, window).expand(C, 1, 1, window)
    ky = g.reshape(1, 1, window, 1).expand(C, 1, window, 1)

    def blur(t: Tensor) -> Tensor:
        t = F.conv2d(t, kx, padding=(0, window // 2), groups=C)
        return F.conv2d(t, ky, padding=(window // 2, 0), groups=C)

    mu_x, mu_y = blur(x), blur(y)
    sxx = blur(x * x) - mu_x * mu_x
    syy = blur(y * y) - mu_y * mu_y
    sxy = blur(x * y) - mu_x * mu_y
    c1, c2 = SSIM_C1, SSIM_C2
    s = ((2 * mu_x * mu_y + c1) * (2 * sxy + c2)) / ((mu_x * mu_x + mu_y * mu_y + c1) * (sxx + syy + c2))
    return s.mean()


def ssim_window(window: int, sigma: float, like: Tensor) -> Tensor:
    """(window,) the normalised 1D Gaussian of SSIM's blur, in ``like``'s dtype and device."""
    g = torch.exp(-((torch.arange(window, dtype=like.dtype, device=like.device) - window // 2) ** 2) / (2 * sigma**2))
    return g / g.sum()
