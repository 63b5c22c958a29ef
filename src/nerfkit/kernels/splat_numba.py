"""Compiled (numba) CPU rasterizer of projected 3D Gaussians; importing this needs numba.

The reference is :func:`nerfkit.kernels.splat_reference.rasterize_reference`; the rules
(tiles, depth order, alpha thresholds, early termination) are the same, see there.

* :func:`project_forward` / :func:`project_backward`: every Gaussian's EWA projection,
  opacity and SH colour, and their gradients (one pass over the Gaussians each, per
  Gaussian in float64, on one thread; references: ``project_gaussians``,
  ``covariance_3d``, ``sh_to_rgb`` of :mod:`nerfkit.kernels.splat_reference`).
* :func:`depth_order`: the visible Gaussians nearest first (a stable radix sort: the
  reference's order exactly).
* :func:`bin_tiles`: per tile, the visible Gaussians in depth order (a bucket sort of
  the globally depth-sorted list, so each tile's list stays sorted).
* :func:`all_finite`: the training step's check of the gradients, in one pass.
* :func:`rasterize_forward`: tiles in parallel; per tile, Gaussians front to back each
  update the open pixels of their footprint (the box where alpha can reach 1/255; a tile
  is done when all its pixels are). Writes the final transmittance and the end of the
  contributing list per pixel for the backward.
* :func:`rasterize_backward`: back to front over the same lists (INRIA's recursion).
  Tiles are split into lanes (one per thread); each lane adds into its own gradient
  buffer, so no two threads write the same memory; the caller sums the lanes.

Gradient channels per Gaussian (``G_*``): 2D mean x/y, conic a/b/c, opacity, r, g, b.

The rasterizer's per-pixel arithmetic and SSIM's blurs and map run in the inputs' dtype
(float32 in training: a Python float or ``int + 0.5`` would make them float64, and
``math.exp`` the double exp), and the float kernels let the compiler fuse a multiply and
an add into an FMA (``fastmath={"contract"}``: one rounding instead of two; nothing is
reordered). ``tests/test_splat_kernels.py`` holds float32 gradients to a float64 run's.

* :func:`ssim_forward` / :func:`ssim_backward`: the training loss's SSIM and its gradient
  (reference: :func:`nerfkit.kernels.splat_reference.ssim_reference`), on (C, H, W) planes:
  the five Gaussian blurs of the forward and the three of the backward are separable
  passes over whole rows that the compiler vectorizes, on one thread (as torch's side of
  a step: on a loaded machine two threads spent more CPU time waiting than they saved).
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
from numba import njit, prange

from .. import splat_constants
from ..splat_constants import ALPHA_MAX, ALPHA_MIN, DILATION, FOV_CLIP, SH_C0, SH_C1, SH_C2, SH_C3, T_MIN, TILE

G_MX, G_MY, G_A, G_B, G_C, G_OP, G_R, G_G, G_BL = range(9)
N_GRAD = 9
INV_TILE = 1.0 / TILE


@njit(cache=True)
def depth_order(depths, rects):
    """Indices (m,) int64 of the visible Gaussians (non-empty ``rects``), nearest first, ties
    in index order: :func:`nerfkit.kernels.splat_reference.depth_order`'s stable sort, as an
    LSD radix sort (16 bits a pass) of the depths' float64 bits mapped to unsigned integers
    that order as the floats do (passes whose digit is the same for all are skipped: a
    float32 depth's low 29 bits are zero)."""
    n = depths.shape[0]
    idx = np.empty(n, np.int64)
    m = 0
    for g in range(n):
        if rects[g, 1] > rects[g, 0] and rects[g, 3] > rects[g, 2]:
            idx[m] = g
            m += 1
    vals = np.empty(m, np.float64)
    for k in range(m):
        d = np.float64(depths[idx[k]])
        vals[k] = 0.0 if d == 0.0 else d  # (-0 sorts as 0)
    bits = vals.view(np.uint64)
    sign = np.uint64(1) << np.uint64(63)
    keys = np.empty(m, np.uint64)
    for k in range(m):
        b = bits[k]
        keys[k] = ~b if b & sign else b | sign
    order = idx[:m].copy()
    tmp_keys = np.empty(m, np.uint64)
    tmp_order = np.empty(m, np.int64)
    count = np.empty(65537, np.int64)
    mask = np.uint64(0xFFFF)
    for p in range(4):
        shift = np.uint64(16 * p)
        count[:] = 0
        for k in range(m):
            count[((keys[k] >> shift) & mask) + 1] += 1
        if m == 0 or count[((keys[0] >> shift) & mask) + 1] == m:
            continue  # one digit for all: this pass keeps the order
        for j in range(65536):
            count[j + 1] += count[j]
        for k in range(m):
            digit = (keys[k] >> shift) & mask
            at = count[digit]
            count[digit] = at + 1
            tmp_keys[at] = keys[k]
            tmp_order[at] = order[k]
        keys, tmp_keys = tmp_keys, keys
        order, tmp_order = tmp_order, order
    return order


@njit(cache=True)
def bin_tiles(order, rects, n_tiles_x, n_tiles_y):
    """``order`` (m,) Gaussian ids nearest first; ``rects`` (n, 4) int32 ``x0, x1, y0, y1``.

    Returns ``(offsets (n_tiles + 1,) int64, ids (pairs,) int32)``: tile ``t`` (row-major)
    holds ``ids[offsets[t]:offsets[t + 1]]``, in depth order.
    """
    n_tiles = n_tiles_x * n_tiles_y
    counts = np.zeros(n_tiles + 1, np.int64)
    for k in range(order.shape[0]):
        g = order[k]
        for ty in range(rects[g, 2], rects[g, 3]):
            for tx in range(rects[g, 0], rects[g, 1]):
                counts[ty * n_tiles_x + tx + 1] += 1
    offsets = np.cumsum(counts)
    fill = offsets[:-1].copy()
    ids = np.empty(offsets[-1], np.int32)
    for k in range(order.shape[0]):
        g = order[k]
        for ty in range(rects[g, 2], rects[g, 3]):
            for tx in range(rects[g, 0], rects[g, 1]):
                t = ty * n_tiles_x + tx
                ids[fill[t]] = g
                fill[t] += 1
    return offsets, ids


@njit(cache=True, inline="always")
def _tile_box(t, n_tiles_x, width, height):
    """Pixels ``[x0, x1) x [y0, y1)`` of tile ``t`` (row-major tiles of TILE x TILE,
    clipped at the image's edge)."""
    x0, y0 = (t % n_tiles_x) * TILE, (t // n_tiles_x) * TILE
    return x0, min(x0 + TILE, width), y0, min(y0 + TILE, height)


@njit(cache=True, inline="always")
def _pixel_box(mx, my, ca, cb, cc, op, x0, x1, y0, y1):
    """Pixels ``[bx0, bx1) x [by0, by1)`` of the tile ``[x0, x1) x [y0, y1)`` where a Gaussian
    can reach alpha >= 1/255: the bounding box of the ellipse ``op * exp(power) = 1/255``
    (plus a pixel of margin), so skipping the pixels outside changes nothing."""
    s = 2.0 * math.log(op / ALPHA_MIN)  # d^T Q d <= s where alpha >= ALPHA_MIN
    det = ca * cc - cb * cb
    if s <= 0.0 or det <= 0.0 or ca <= 0.0:
        return x0, x0, y0, y0
    rx = math.sqrt(s * cc / det) + 1.0
    ry = math.sqrt(s * ca / det) + 1.0
    bx0 = max(x0, int(math.ceil(mx - rx - 0.5)))
    bx1 = min(x1, int(math.floor(mx + rx - 0.5)) + 1)
    by0 = max(y0, int(math.ceil(my - ry - 0.5)))
    by1 = min(y1, int(math.floor(my + ry - 0.5)) + 1)
    if bx1 < bx0:
        bx1 = bx0
    if by1 < by0:
        by1 = by0
    return bx0, bx1, by0, by1


@njit(cache=True, inline="always")
def _power_floor(op):
    """Below this power, ``op * exp(power) < 1/255`` for sure (a margin of 1e-3 keeps the
    exact test, after exp, for the borderline pixels): those skip the exp."""
    if op <= 0.0:
        return math.inf
    return math.log(ALPHA_MIN / op) - 1e-3


@njit(parallel=True, cache=True, fastmath={"contract"})
def rasterize_forward(
    offsets,
    ids,
    means2d,
    conics,
    colors,
    opac,
    depths,
    background,
    width,
    height,
    n_tiles_x,
    out_rgb,
    out_depth,
    out_alpha,
    final_T,
    n_contrib,
    lanes,
):
    """Composite every pixel; outputs (H, W, 3) / (H, W) are written in place.

    Per tile, Gaussians in depth order each update only the pixels of their footprint
    that are still open (per-pixel state in small arrays). ``n_contrib[y, x]`` is the index
    into ``ids`` just past the last Gaussian that contributed (the backward starts there).
    Lane ``l`` (one per thread) composites tiles ``l, l + lanes, ...``: the image's busy
    rows fall to every thread (the output does not depend on ``lanes``)."""
    n_tiles = offsets.shape[0] - 1
    f = means2d.dtype.type  # per-pixel arithmetic in the inputs' dtype (a Python float is a float64);
    # the thresholds ALPHA_MIN and T_MIN stay float64 compares, as before
    zero, half, one, alpha_max = f(0.0), f(0.5), f(1.0), f(ALPHA_MAX)
    for lane in prange(lanes):
        for t in range(lane, n_tiles, lanes):
            start, end = offsets[t], offsets[t + 1]
            x0, x1, y0, y1 = _tile_box(t, n_tiles_x, width, height)
            tw = x1 - x0
            P = tw * (y1 - y0)
            T = np.ones(P, means2d.dtype)
            acc = np.zeros((P, 4), means2d.dtype)
            last = np.full(P, start, np.int64)
            done = np.zeros(P, np.bool_)
            open_pixels = P
            for k in range(start, end):
                if open_pixels == 0:
                    break
                g = ids[k]
                mx, my = means2d[g, 0], means2d[g, 1]
                ca, cb, cc = conics[g, 0], conics[g, 1], conics[g, 2]
                op = opac[g]
                bx0, bx1, by0, by1 = _pixel_box(mx, my, ca, cb, cc, op, x0, x1, y0, y1)
                p_skip = f(_power_floor(op))
                for y in range(by0, by1):
                    dy = my - (f(y) + half)
                    for x in range(bx0, bx1):
                        p = (y - y0) * tw + (x - x0)
                        if done[p]:
                            continue
                        dx = mx - (f(x) + half)
                        power = -half * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                        if power > zero or power < p_skip:
                            continue
                        alpha = min(alpha_max, op * math.exp(power))
                        if alpha < ALPHA_MIN:
                            continue
                        test_T = T[p] * (one - alpha)
                        if test_T < T_MIN:
                            done[p] = True
                            open_pixels -= 1
                            continue
                        w = alpha * T[p]
                        acc[p, 0] += w * colors[g, 0]
                        acc[p, 1] += w * colors[g, 1]
                        acc[p, 2] += w * colors[g, 2]
                        acc[p, 3] += w * depths[g]
                        T[p] = test_T
                        last[p] = k + 1
            for y in range(y0, y1):
                for x in range(x0, x1):
                    p = (y - y0) * tw + (x - x0)
                    for ch in range(3):
                        out_rgb[y, x, ch] = acc[p, ch] + T[p] * background[y, x, ch]
                    out_depth[y, x] = acc[p, 3]
                    out_alpha[y, x] = one - T[p]
                    final_T[y, x] = T[p]
                    n_contrib[y, x] = last[p]


@njit(parallel=True, cache=True, fastmath={"contract"})
def rasterize_backward(
    offsets,
    ids,
    means2d,
    conics,
    colors,
    opac,
    depths,
    background,
    width,
    height,
    n_tiles_x,
    final_T,
    n_contrib,
    grad_rgb,
    grads,
):
    """Gradients of a loss w.r.t. each Gaussian's 2D mean, conic, opacity and colour.

    ``grad_rgb`` (H, W, 3) is dL/d(out_rgb); ``grads`` (lanes, n, 9) zeroed, written in place
    (lane ``l`` handles tiles ``l, l + lanes, ...``). Per tile, Gaussians back to front,
    each visiting its footprint's pixels (INRIA's recursion, per-pixel state in arrays)."""
    n_tiles = offsets.shape[0] - 1
    lanes = grads.shape[0]
    f = means2d.dtype.type  # per-pixel arithmetic in the inputs' dtype, as the forward
    zero, half, one, alpha_max = f(0.0), f(0.5), f(1.0), f(ALPHA_MAX)
    for lane in prange(lanes):
        for t in range(lane, n_tiles, lanes):
            start, end = offsets[t], offsets[t + 1]
            if end == start:
                continue
            x0, x1, y0, y1 = _tile_box(t, n_tiles_x, width, height)
            tw = x1 - x0
            P = tw * (y1 - y0)
            T = np.empty(P, means2d.dtype)
            behind = np.zeros((P, 3), means2d.dtype)  # colour composited behind, per unit transmittance
            last_alpha = np.zeros(P, means2d.dtype)
            last_col = np.zeros((P, 3), means2d.dtype)
            ncon = np.empty(P, np.int64)
            gpix = np.empty((P, 4), means2d.dtype)  # dL/drgb and background . dL/drgb
            k_end = start
            for y in range(y0, y1):
                for x in range(x0, x1):
                    p = (y - y0) * tw + (x - x0)
                    T[p] = final_T[y, x]
                    ncon[p] = n_contrib[y, x]
                    k_end = max(k_end, ncon[p])
                    for ch in range(3):
                        gpix[p, ch] = grad_rgb[y, x, ch]
                    gpix[p, 3] = (
                        background[y, x, 0] * grad_rgb[y, x, 0]
                        + background[y, x, 1] * grad_rgb[y, x, 1]
                        + background[y, x, 2] * grad_rgb[y, x, 2]
                    )
            for k in range(k_end - 1, start - 1, -1):
                g = ids[k]
                mx, my = means2d[g, 0], means2d[g, 1]
                ca, cb, cc = conics[g, 0], conics[g, 1], conics[g, 2]
                op = opac[g]
                cr, cg, cbl = colors[g, 0], colors[g, 1], colors[g, 2]
                bx0, bx1, by0, by1 = _pixel_box(mx, my, ca, cb, cc, op, x0, x1, y0, y1)
                p_skip = f(_power_floor(op))
                # sums over the footprint (<= 256 pixels) in the dtype (float32: as near a float64 run's)
                d_mx = zero
                d_my = zero
                d_a = zero
                d_b = zero
                d_c = zero
                d_op = zero
                d_r = zero
                d_g = zero
                d_bl = zero
                for y in range(by0, by1):
                    dy = my - (f(y) + half)
                    for x in range(bx0, bx1):
                        p = (y - y0) * tw + (x - x0)
                        if k >= ncon[p]:
                            continue
                        dx = mx - (f(x) + half)
                        power = -half * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                        if power > zero or power < p_skip:
                            continue
                        G = math.exp(power)
                        raw = op * G
                        alpha = min(alpha_max, raw)
                        if alpha < ALPHA_MIN:
                            continue
                        Tp = T[p] / (one - alpha)
                        T[p] = Tp
                        w = alpha * Tp
                        gr, gg, gb = gpix[p, 0], gpix[p, 1], gpix[p, 2]
                        d_r += w * gr
                        d_g += w * gg
                        d_bl += w * gb
                        la = last_alpha[p]
                        br = la * last_col[p, 0] + (one - la) * behind[p, 0]
                        bg_ = la * last_col[p, 1] + (one - la) * behind[p, 1]
                        bb = la * last_col[p, 2] + (one - la) * behind[p, 2]
                        behind[p, 0] = br
                        behind[p, 1] = bg_
                        behind[p, 2] = bb
                        last_alpha[p] = alpha
                        last_col[p, 0] = cr
                        last_col[p, 1] = cg
                        last_col[p, 2] = cbl
                        dl_dalpha = ((cr - br) * gr + (cg - bg_) * gg + (cbl - bb) * gb) * Tp
                        dl_dalpha -= final_T[y, x] / (one - alpha) * gpix[p, 3]
                        if raw > alpha_max:
                            continue  # alpha is clamped: no gradient to opacity, mean or conic
                        d_op += G * dl_dalpha
                        dl_dpower = raw * dl_dalpha
                        d_mx += dl_dpower * (-ca * dx - cb * dy)
                        d_my += dl_dpower * (-cc * dy - cb * dx)
                        d_a += dl_dpower * (-half * dx * dx)
                        d_b += dl_dpower * (-dx * dy)
                        d_c += dl_dpower * (-half * dy * dy)
                grads[lane, g, G_MX] += d_mx
                grads[lane, g, G_MY] += d_my
                grads[lane, g, G_A] += d_a
                grads[lane, g, G_B] += d_b
                grads[lane, g, G_C] += d_c
                grads[lane, g, G_OP] += d_op
                grads[lane, g, G_R] += d_r
                grads[lane, g, G_G] += d_g
                grads[lane, g, G_BL] += d_bl


@njit(cache=True, inline="always")
def _sh_basis(x, y, z, degree, out):
    """INRIA's real SH basis of the unit direction ``(x, y, z)`` into ``out[:(degree + 1)^2]``."""
    out[0] = SH_C0
    if degree >= 1:
        out[1] = -SH_C1 * y
        out[2] = SH_C1 * z
        out[3] = -SH_C1 * x
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out[4] = SH_C2[0] * x * y
        out[5] = SH_C2[1] * y * z
        out[6] = SH_C2[2] * (2.0 * zz - xx - yy)
        out[7] = SH_C2[3] * x * z
        out[8] = SH_C2[4] * (xx - yy)
    if degree >= 3:
        xx, yy, zz = x * x, y * y, z * z
        out[9] = SH_C3[0] * y * (3.0 * xx - yy)
        out[10] = SH_C3[1] * x * y * z
        out[11] = SH_C3[2] * y * (4.0 * zz - xx - yy)
        out[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
        out[13] = SH_C3[4] * x * (4.0 * zz - xx - yy)
        out[14] = SH_C3[5] * z * (xx - yy)
        out[15] = SH_C3[6] * x * (xx - 3.0 * yy)


@njit(cache=True, inline="always")
def _sh_basis_dir_grad(x, y, z, degree, g_basis):
    """``sum_k g_basis[k] d basis_k / d(x, y, z)`` of :func:`_sh_basis` at the unit direction
    ``(x, y, z)`` (the direction taken as free, not normalised), returned as a triple
    (INRIA's ``computeColorFromSH`` backward, dRGBdx/dy/dz)."""
    gx = gy = gz = 0.0
    if degree >= 1:
        gx -= SH_C1 * g_basis[3]
        gy -= SH_C1 * g_basis[1]
        gz += SH_C1 * g_basis[2]
    if degree >= 2:
        gx += SH_C2[0] * y * g_basis[4] - 2.0 * SH_C2[2] * x * g_basis[6]
        gx += SH_C2[3] * z * g_basis[7] + 2.0 * SH_C2[4] * x * g_basis[8]
        gy += SH_C2[0] * x * g_basis[4] + SH_C2[1] * z * g_basis[5]
        gy += -2.0 * SH_C2[2] * y * g_basis[6] - 2.0 * SH_C2[4] * y * g_basis[8]
        gz += SH_C2[1] * y * g_basis[5] + 4.0 * SH_C2[2] * z * g_basis[6] + SH_C2[3] * x * g_basis[7]
    if degree >= 3:
        xx, yy, zz = x * x, y * y, z * z
        gx += SH_C3[0] * 6.0 * x * y * g_basis[9] + SH_C3[1] * y * z * g_basis[10]
        gx += -2.0 * SH_C3[2] * x * y * g_basis[11] - 6.0 * SH_C3[3] * x * z * g_basis[12]
        gx += SH_C3[4] * (4.0 * zz - 3.0 * xx - yy) * g_basis[13] + 2.0 * SH_C3[5] * x * z * g_basis[14]
        gx += 3.0 * SH_C3[6] * (xx - yy) * g_basis[15]
        gy += 3.0 * SH_C3[0] * (xx - yy) * g_basis[9] + SH_C3[1] * x * z * g_basis[10]
        gy += SH_C3[2] * (4.0 * zz - xx - 3.0 * yy) * g_basis[11] - 6.0 * SH_C3[3] * y * z * g_basis[12]
        gy += -2.0 * SH_C3[4] * x * y * g_basis[13] - 2.0 * SH_C3[5] * y * z * g_basis[14]
        gy += -6.0 * SH_C3[6] * x * y * g_basis[15]
        gz += SH_C3[1] * x * y * g_basis[10] + 8.0 * SH_C3[2] * y * z * g_basis[11]
        gz += SH_C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy) * g_basis[12] + 8.0 * SH_C3[4] * x * z * g_basis[13]
        gz += SH_C3[5] * (xx - yy) * g_basis[14]
    return gx, gy, gz


@njit(cache=True, inline="always")
def _rotation(qw, qx, qy, qz, R):
    """The rotation matrix (3, 3) of the quaternion ``(w, x, y, z)`` (normalised here) into
    ``R``; returns the quaternion's length."""
    qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    inv = 1.0 / qn
    w, x, y, z = qw * inv, qx * inv, qy * inv, qz * inv
    R[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[0, 1] = 2.0 * (x * y - w * z)
    R[0, 2] = 2.0 * (x * z + w * y)
    R[1, 0] = 2.0 * (x * y + w * z)
    R[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[1, 2] = 2.0 * (y * z - w * x)
    R[2, 0] = 2.0 * (x * z - w * y)
    R[2, 1] = 2.0 * (y * z + w * x)
    R[2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return qn


@njit(cache=True, inline="always")
def _camera_jacobian(view, tx, ty, tz, fx, fy, limx, limy, near, T):
    """EWA's ``T = J W`` (2, 3) into ``T`` for the view-space centre ``(tx, ty, tz)``; returns
    ``(tzc, u, v, uc, vc)``: the clamped depth, ``tx / tzc``, ``ty / tzc`` and those two clamped
    to the field of view (as :func:`nerfkit.kernels.splat_reference.project_gaussians`)."""
    tzc = max(tz, near)
    iz = 1.0 / tzc
    u, v = tx * iz, ty * iz
    uc, vc = min(max(u, -limx), limx), min(max(v, -limy), limy)
    j00, j02 = fx * iz, -fx * uc * iz
    j11, j12 = fy * iz, -fy * vc * iz
    for k in range(3):
        T[0, k] = j00 * view[0, k] + j02 * view[2, k]
        T[1, k] = j11 * view[1, k] + j12 * view[2, k]
    return tzc, u, v, uc, vc


@njit(cache=True, inline="always")
def _view_point(view, m0, m1, m2):
    """The world point ``(m0, m1, m2)`` in view space: returns ``(tx, ty, tz)`` from ``view``
    (3, 4) the world-to-camera rows."""
    tx = view[0, 0] * m0 + view[0, 1] * m1 + view[0, 2] * m2 + view[0, 3]
    ty = view[1, 0] * m0 + view[1, 1] * m1 + view[1, 2] * m2 + view[1, 3]
    tz = view[2, 0] * m0 + view[2, 1] * m1 + view[2, 2] * m2 + view[2, 3]
    return tx, ty, tz


@njit(cache=True, inline="always")
def _screen_covariance(T, R, s0, s1, s2, tz, near, U):
    """EWA's 2D covariance ``U U^T + DILATION I`` of ``U = T R diag(s)`` (2, 3), written into
    ``U``, from :func:`_camera_jacobian`'s ``T`` (2, 3) and :func:`_rotation`'s ``R`` (3, 3).
    Returns ``(a, b, c, det, valid)``: ``a, b, c`` its entries (0, 0), (0, 1), (1, 1), ``det``
    its determinant, ``valid`` the centre ``tz`` beyond ``near`` and ``det > 0``."""
    for r in range(2):
        U[r, 0] = (T[r, 0] * R[0, 0] + T[r, 1] * R[1, 0] + T[r, 2] * R[2, 0]) * s0
        U[r, 1] = (T[r, 0] * R[0, 1] + T[r, 1] * R[1, 1] + T[r, 2] * R[2, 1]) * s1
        U[r, 2] = (T[r, 0] * R[0, 2] + T[r, 1] * R[1, 2] + T[r, 2] * R[2, 2]) * s2
    a = U[0, 0] * U[0, 0] + U[0, 1] * U[0, 1] + U[0, 2] * U[0, 2] + DILATION
    b = U[0, 0] * U[1, 0] + U[0, 1] * U[1, 1] + U[0, 2] * U[1, 2]
    c = U[1, 0] * U[1, 0] + U[1, 1] * U[1, 1] + U[1, 2] * U[1, 2] + DILATION
    det = a * c - b * b
    return a, b, c, det, tz > near and det > 0.0


@njit(cache=True, inline="always")
def _sh_colour(sh_dc, sh_rest, i, m0, m1, m2, cam, degree, basis, raw):
    """Gaussian ``i``'s SH colour seen from the camera centre ``cam`` (3,), the Gaussian at
    ``(m0, m1, m2)``: the basis of the unit direction into ``basis`` (16,) and per channel
    ``basis . coefficients`` (before INRIA's ``+ 0.5`` and the clamp at 0) into ``raw`` (3,);
    ``sh_dc`` (n, 1, 3), ``sh_rest`` (n, K - 1, 3) with ``(degree + 1)^2 <= K``."""
    d0, d1, d2 = m0 - cam[0], m1 - cam[1], m2 - cam[2]
    idn = 1.0 / max(math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), 1e-12)
    _sh_basis(d0 * idn, d1 * idn, d2 * idn, degree, basis)
    n_basis = (degree + 1) * (degree + 1)
    for ch in range(3):
        acc = basis[0] * sh_dc[i, 0, ch]
        for k in range(1, n_basis):
            acc += basis[k] * sh_rest[i, k - 1, ch]
        raw[ch] = acc


@njit(cache=True)
def project_forward(
    means,
    log_scales,
    quats,
    opacity_logits,
    sh_dc,
    sh_rest,
    degree,
    view,
    cam,
    intr,
    width,
    height,
    near,
    means2d,
    conics,
    colors,
    opac,
    depths,
    radii,
    rects,
):
    """Projection, opacity and SH colour of every Gaussian, as the torch reference
    (``project_gaussians(means, covariance_3d(log_scales, quats), ...)``, ``sigmoid``,
    ``sh_to_rgb`` along the direction from the camera centre ``cam``), per Gaussian in
    float64, written into the outputs (``means2d`` (n, 2), ``conics`` (n, 3), ``colors`` (n, 3),
    ``opac`` (n,), ``depths`` (n,), ``radii`` (n,) int32, ``rects`` (n, 4) int32).

    ``view`` (3, 4) float64 the world-to-camera rows; ``intr`` (4,) ``fx, fy, cx, cy``;
    ``sh_dc`` (n, 1, 3), ``sh_rest`` (n, K - 1, 3) with ``(degree + 1)^2 <= K``."""
    n = means.shape[0]
    fx, fy, cx, cy = intr[0], intr[1], intr[2], intr[3]
    limx, limy = FOV_CLIP * 0.5 * width / fx, FOV_CLIP * 0.5 * height / fy
    tw, th = -(-width // TILE), -(-height // TILE)
    T = np.empty((2, 3))
    R = np.empty((3, 3))
    U = np.empty((2, 3))
    basis = np.empty(16)
    raw = np.empty(3)
    for i in range(n):
        m0, m1, m2 = float(means[i, 0]), float(means[i, 1]), float(means[i, 2])
        tx, ty, tz = _view_point(view, m0, m1, m2)
        tzc, _, _, _, _ = _camera_jacobian(view, tx, ty, tz, fx, fy, limx, limy, near, T)
        _rotation(float(quats[i, 0]), float(quats[i, 1]), float(quats[i, 2]), float(quats[i, 3]), R)
        s0, s1, s2 = math.exp(log_scales[i, 0]), math.exp(log_scales[i, 1]), math.exp(log_scales[i, 2])
        a, b, c, det, valid = _screen_covariance(T, R, s0, s1, s2, tz, near, U)
        ids = 1.0 / det if valid else 1.0
        conics[i, 0] = c * ids
        conics[i, 1] = -b * ids
        conics[i, 2] = a * ids
        iz = 1.0 / tzc
        mx, my = fx * tx * iz + cx, fy * ty * iz + cy
        means2d[i, 0] = mx
        means2d[i, 1] = my
        depths[i] = tz
        opac[i] = 1.0 / (1.0 + math.exp(-float(opacity_logits[i])))
        # the screen rectangle (tiles), as the reference
        mid = 0.5 * (a + c)
        lam = mid + math.sqrt(max(mid * mid - det, 0.1))
        r = np.ceil(3.0 * math.sqrt(max(lam, 0.0)))
        px, py = mx - 0.5, my - 0.5
        x0 = min(max(np.floor((px - r) * INV_TILE), 0.0), tw)
        x1 = min(max(np.floor((px + r + TILE - 1) * INV_TILE), 0.0), tw)
        y0 = min(max(np.floor((py - r) * INV_TILE), 0.0), th)
        y1 = min(max(np.floor((py + r + TILE - 1) * INV_TILE), 0.0), th)
        if valid and math.isfinite(r) and x1 > x0 and y1 > y0:
            radii[i] = int(r)
            rects[i, 0], rects[i, 1], rects[i, 2], rects[i, 3] = int(x0), int(x1), int(y0), int(y1)
        else:
            radii[i] = 0
            rects[i, 0], rects[i, 1], rects[i, 2], rects[i, 3] = 0, 0, 0, 0
        # SH colour along the direction from the camera centre
        _sh_colour(sh_dc, sh_rest, i, m0, m1, m2, cam, degree, basis, raw)
        for ch in range(3):
            colors[i, ch] = max(raw[ch] + 0.5, 0.0)


@njit(cache=True)
def project_backward(
    means,
    log_scales,
    quats,
    opacity_logits,
    sh_dc,
    sh_rest,
    degree,
    view,
    cam,
    intr,
    width,
    height,
    near,
    dir_grad,
    g_means2d,
    g_conics,
    g_colors,
    g_opac,
    g_depths,
    d_means,
    d_log_scales,
    d_quats,
    d_logits,
    d_sh_dc,
    d_sh_rest,
):
    """The gradients of :func:`project_forward`'s differentiable outputs (``g_*``, the
    loss's gradient with respect to each) to its inputs (``d_*``, written in place, every
    row: zero where nothing depends on it, as autograd gives the reference; ``d_sh_rest``
    zero past the active degree). Per Gaussian in float64, recomputing the forward. With
    ``dir_grad`` the colour's view direction ``normalize(mean - cam)`` passes its gradient to
    the means too (as INRIA's and gsplat's); without, it is held fixed."""
    n = means.shape[0]
    fx, fy = intr[0], intr[1]
    limx, limy = FOV_CLIP * 0.5 * width / fx, FOV_CLIP * 0.5 * height / fy
    n_basis = (degree + 1) * (degree + 1)
    n_rest = sh_rest.shape[1]
    T = np.empty((2, 3))
    R = np.empty((3, 3))
    U = np.empty((2, 3))
    dU = np.empty((2, 3))
    dR = np.empty((3, 3))
    basis = np.empty(16)
    g_basis = np.empty(16)
    raw = np.empty(3)
    for i in range(n):
        m0, m1, m2 = float(means[i, 0]), float(means[i, 1]), float(means[i, 2])
        tx, ty, tz = _view_point(view, m0, m1, m2)
        tzc, u, v, uc, vc = _camera_jacobian(view, tx, ty, tz, fx, fy, limx, limy, near, T)
        qw, qx, qy, qz = float(quats[i, 0]), float(quats[i, 1]), float(quats[i, 2]), float(quats[i, 3])
        qn = _rotation(qw, qx, qy, qz, R)
        s = (math.exp(log_scales[i, 0]), math.exp(log_scales[i, 1]), math.exp(log_scales[i, 2]))
        a, b, c, det, valid = _screen_covariance(T, R, s[0], s[1], s[2], tz, near, U)
        ids = 1.0 / det if valid else 1.0
        # conic (c, -b, a) / ds -> a, b, c (and ds = det when valid)
        gA, gB, gC = float(g_conics[i, 0]), float(g_conics[i, 1]), float(g_conics[i, 2])
        ga, gb, gc = gC * ids, -gB * ids, gA * ids
        if valid:
            g_det = -(gA * c - gB * b + gC * a) * (ids * ids)
            ga += g_det * c
            gc += g_det * a
            gb -= 2.0 * g_det * b
        # cov2d = U U^T with a = cov2d[0, 0], b = cov2d[0, 1], c = cov2d[1, 1]: dU = (G + G^T) U
        for j in range(3):
            dU[0, j] = 2.0 * ga * U[0, j] + gb * U[1, j]
            dU[1, j] = gb * U[0, j] + 2.0 * gc * U[1, j]
        # U = T M, M = R diag(s): dM = T^T dU, dT = dU M^T
        for k in range(3):
            for j in range(3):
                dR[k, j] = (T[0, k] * dU[0, j] + T[1, k] * dU[1, j]) * s[j]  # dM[k, j] s_j
        for j in range(3):
            dsj = 0.0
            for k in range(3):
                dsj += dR[k, j] * R[k, j]  # (dM[k, j] s_j) R[k, j] = dM[k, j] M[k, j]
            d_log_scales[i, j] = dsj
        iq = 1.0 / qn
        w, x, y, z = qw * iq, qx * iq, qy * iq, qz * iq
        gw = 2.0 * (-z * dR[0, 1] + y * dR[0, 2] + z * dR[1, 0] - x * dR[1, 2] - y * dR[2, 0] + x * dR[2, 1])
        gx = 2.0 * (
            y * dR[0, 1]
            + z * dR[0, 2]
            + y * dR[1, 0]
            - 2.0 * x * dR[1, 1]
            - w * dR[1, 2]
            + z * dR[2, 0]
            + w * dR[2, 1]
            - 2.0 * x * dR[2, 2]
        )
        gy = 2.0 * (
            -2.0 * y * dR[0, 0]
            + x * dR[0, 1]
            + w * dR[0, 2]
            + x * dR[1, 0]
            + z * dR[1, 2]
            - w * dR[2, 0]
            + z * dR[2, 1]
            - 2.0 * y * dR[2, 2]
        )
        gz = 2.0 * (
            -2.0 * z * dR[0, 0]
            - w * dR[0, 1]
            + x * dR[0, 2]
            + w * dR[1, 0]
            - 2.0 * z * dR[1, 1]
            + y * dR[1, 2]
            + x * dR[2, 0]
            + y * dR[2, 1]
        )
        dot = w * gw + x * gx + y * gy + z * gz
        d_quats[i, 0] = (gw - w * dot) * iq
        d_quats[i, 1] = (gx - x * dot) * iq
        d_quats[i, 2] = (gy - y * dot) * iq
        d_quats[i, 3] = (gz - z * dot) * iq
        # dT = dU M^T, then T = J W: the four non-zero entries of J
        dj00 = dj02 = dj11 = dj12 = 0.0
        for k in range(3):
            dT0 = dU[0, 0] * R[k, 0] * s[0] + dU[0, 1] * R[k, 1] * s[1] + dU[0, 2] * R[k, 2] * s[2]
            dT1 = dU[1, 0] * R[k, 0] * s[0] + dU[1, 1] * R[k, 1] * s[1] + dU[1, 2] * R[k, 2] * s[2]
            dj00 += dT0 * view[0, k]
            dj02 += dT0 * view[2, k]
            dj11 += dT1 * view[1, k]
            dj12 += dT1 * view[2, k]
        # J00 = fx / z, J02 = -fx txc / z^2 (txc = uc z), J11 and J12 alike; z = tzc
        iz = 1.0 / tzc
        iz2 = iz * iz
        txc, tyc = uc * tzc, vc * tzc
        g_tzc = -fx * iz2 * dj00 + 2.0 * fx * txc * iz2 * iz * dj02
        g_tzc += -fy * iz2 * dj11 + 2.0 * fy * tyc * iz2 * iz * dj12
        g_txc, g_tyc = -fx * iz2 * dj02, -fy * iz2 * dj12
        g_uc, g_vc = g_txc * tzc, g_tyc * tzc
        g_tzc += g_txc * uc + g_tyc * vc
        g_tx = g_ty = 0.0
        if -limx <= u <= limx:  # u = tx / z, clamped
            g_tx += g_uc * iz
            g_tzc -= g_uc * tx * iz2
        if -limy <= v <= limy:
            g_ty += g_vc * iz
            g_tzc -= g_vc * ty * iz2
        gmx, gmy = float(g_means2d[i, 0]), float(g_means2d[i, 1])
        g_tx += gmx * fx * iz
        g_ty += gmy * fy * iz
        g_tzc -= (gmx * fx * tx + gmy * fy * ty) * iz2
        g_tz = float(g_depths[i]) + (g_tzc if tz >= near else 0.0)
        for j in range(3):
            d_means[i, j] = view[0, j] * g_tx + view[1, j] * g_ty + view[2, j] * g_tz
        op = 1.0 / (1.0 + math.exp(-float(opacity_logits[i])))
        d_logits[i] = g_opac[i] * op * (1.0 - op)
        # SH: d colour / d coefficient is the basis where the colour is not clamped
        _sh_colour(sh_dc, sh_rest, i, m0, m1, m2, cam, degree, basis, raw)
        for ch in range(3):
            g = float(g_colors[i, ch]) if raw[ch] + 0.5 >= 0.0 else 0.0
            d_sh_dc[i, 0, ch] = basis[0] * g
            for k in range(1, n_rest + 1):
                d_sh_rest[i, k - 1, ch] = basis[k] * g if k < n_basis else 0.0
        if dir_grad and degree > 0:
            # dL/dbasis_k = sum over the unclamped channels of g . coefficient_k; then through the
            # basis to the unit direction d, and d = v / |v| (v = mean - cam): (I - d d^T) / |v|
            for k in range(1, n_basis):
                acc = 0.0
                for ch in range(3):
                    if raw[ch] + 0.5 >= 0.0:
                        acc += float(g_colors[i, ch]) * float(sh_rest[i, k - 1, ch])
                g_basis[k] = acc
            v0, v1, v2 = m0 - cam[0], m1 - cam[1], m2 - cam[2]
            norm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            if norm > 1e-12:  # (below, the reference's clamp: no gradient)
                inv = 1.0 / norm
                ux, uy, uz = v0 * inv, v1 * inv, v2 * inv
                gx, gy, gz = _sh_basis_dir_grad(ux, uy, uz, degree, g_basis)
                radial = ux * gx + uy * gy + uz * gz
                d_means[i, 0] += (gx - ux * radial) * inv
                d_means[i, 1] += (gy - uy * radial) * inv
                d_means[i, 2] += (gz - uz * radial) * inv


@njit(cache=True, fastmath={"reassoc"})
def all_finite(x):
    """Whether every value of the flat array ``x`` is finite: ``x - x`` is 0 for a finite
    value and NaN for an infinite or NaN one, and their sum is NaN when one is (in any order:
    the compiler may reorder the sum into vector lanes, nothing else)."""
    acc = x.dtype.type(0.0)
    for i in range(x.shape[0]):
        acc += x[i] - x[i]
    return acc == 0.0


@njit(cache=True, inline="always")
def _blur_plane(src, g, tmp, out):
    """``out = `` (H, W) ``src`` blurred by the 1D kernel ``g`` (odd length) along W, then
    along H, zero-padded ('same' size); ``tmp`` (H, W) scratch. The blur is symmetric
    in ``g``, so it is its own adjoint."""
    H, W = src.shape
    r = g.shape[0] // 2
    tmp[:, :] = 0.0
    for h in range(H):
        for k in range(g.shape[0]):
            gk = g[k]
            lo, hi = max(0, r - k), min(W, W + r - k)  # tmp[h, w] takes src[h, w + k - r]
            trow, srow = tmp[h, lo:hi], src[h, lo + k - r : hi + k - r]
            for i in range(hi - lo):  # (indices from 0: no negative-index wraparound, so it vectorizes)
                trow[i] += gk * srow[i]
    out[:, :] = 0.0
    for h in range(H):
        for k in range(max(0, r - h), min(g.shape[0], H + r - h)):
            gk = g[k]
            orow, trow = out[h], tmp[h + k - r]
            for w in range(W):
                orow[w] += gk * trow[w]


@njit(cache=True, fastmath={"contract"})
def ssim_forward(x, y, g, c1, c2, dmaps):
    """Mean SSIM of images ``x``, ``y`` (C, H, W) with the blur ``g`` (window,), and in
    ``dmaps`` (3, C, H, W) each pixel's derivative of its SSIM term with respect to its
    blurred ``x``, blurred ``x^2`` and blurred ``x y`` (for :func:`ssim_backward`)."""
    C, H, W = x.shape
    blurred = np.empty((5, C, H, W), x.dtype)  # x, y, x^2, y^2, x y
    for j in range(5 * C):
        m, c = j // C, j % C
        if m == 0:
            src = x[c].copy()
        elif m == 1:
            src = y[c].copy()
        elif m == 2:
            src = x[c] * x[c]
        elif m == 3:
            src = y[c] * y[c]
        else:
            src = x[c] * y[c]
        _blur_plane(src, g, np.empty((H, W), x.dtype), blurred[m, c])
    f = x.dtype.type  # per-pixel arithmetic in the images' dtype
    two, k1, k2 = f(2.0), f(c1), f(c2)
    rows = np.zeros(C * H)
    for j in range(C * H):
        c, h = j // H, j % H
        mx, my = blurred[0, c, h], blurred[1, c, h]
        sxx, syy, sxy = blurred[2, c, h], blurred[3, c, h], blurred[4, c, h]
        d_mu, d_xx, d_xy = dmaps[0, c, h], dmaps[1, c, h], dmaps[2, c, h]
        total = 0.0
        for w in range(W):
            a1 = two * mx[w] * my[w] + k1
            a2 = two * (sxy[w] - mx[w] * my[w]) + k2
            b1 = mx[w] * mx[w] + my[w] * my[w] + k1
            b2 = (sxx[w] - mx[w] * mx[w]) + (syy[w] - my[w] * my[w]) + k2
            inv = f(1.0) / (b1 * b2)
            s = a1 * a2 * inv
            total += s
            # d s / d blur(x), d blur(x^2), d blur(x y) (the variances hold the means' squares)
            d_mu[w] = two * inv * (my[w] * (a2 - a1) - mx[w] * s * (b2 - b1))
            d_xx[w] = -s * b1 * inv
            d_xy[w] = two * a1 * inv
        rows[j] = total
    return rows.sum() / (C * H * W)


@njit(cache=True, fastmath={"contract"})
def ssim_backward(x, y, g, dmaps, scale, grad_x):
    """``grad_x`` (C, H, W) = ``scale`` x d(sum of SSIM terms)/dx, from :func:`ssim_forward`'s
    ``dmaps``: the blurred derivative maps (the blur is its own adjoint) times 1, 2x, y."""
    _, C, H, W = dmaps.shape
    back = np.empty((3, C, H, W), x.dtype)
    for j in range(3 * C):
        m, c = j // C, j % C
        _blur_plane(dmaps[m, c], g, np.empty((H, W), x.dtype), back[m, c])
    for j in range(C * H):
        c, h = j // H, j % H
        for w in range(W):
            grad_x[c, h, w] = scale * (
                back[0, c, h, w] + 2.0 * x[c, h, w] * back[1, c, h, w] + y[c, h, w] * back[2, c, h, w]
            )


def warm_up() -> None:
    """Compile (or load from the on-disk cache) every kernel for float32, the dtype training
    and rendering run in. Other dtypes' versions (the tests' float64) compile, or load, on
    their first call: eagerly they doubled the first compile into an empty cache and every
    process's load from it."""
    dt = np.float32
    n = 2
    means2d = np.array([[4.0, 4.0], [6.0, 5.0]], dt)
    conics = np.array([[0.5, 0.0, 0.5]] * n, dt)
    colors = np.full((n, 3), 0.5, dt)
    opac = np.full(n, 0.5, dt)
    depths = np.array([1.0, 2.0], dt)
    rects = np.array([[0, 1, 0, 1]] * n, np.int32)
    offsets, ids = bin_tiles(depth_order(depths, rects), rects, 1, 1)
    H = W = 8
    bg = np.zeros((H, W, 3), dt)
    rgb, dep, alp, T = np.zeros((H, W, 3), dt), np.zeros((H, W), dt), np.zeros((H, W), dt), np.zeros((H, W), dt)
    nc = np.zeros((H, W), np.int64)
    rasterize_forward(offsets, ids, means2d, conics, colors, opac, depths, bg, W, H, 1, rgb, dep, alp, T, nc, 2)
    grads = np.zeros((2, n, N_GRAD), dt)
    rasterize_backward(offsets, ids, means2d, conics, colors, opac, depths, bg, W, H, 1, T, nc, rgb, grads)
    x, gw = np.ascontiguousarray(rgb.transpose(2, 0, 1)), np.full(3, 1 / 3, dt)
    dmaps = np.empty((3, *x.shape), dt)
    ssim_forward(x, x, gw, 1e-4, 9e-4, dmaps)
    ssim_backward(x, x, gw, dmaps, 1.0, np.empty_like(x))
    m = 3
    params = (
        np.zeros((m, 3), dt),
        np.zeros((m, 3), dt),
        np.ones((m, 4), dt),
        np.zeros(m, dt),
        np.zeros((m, 1, 3), dt),
        np.zeros((m, 15, 3), dt),
    )
    view, cam, intr = np.eye(4)[:3].copy(), np.zeros(3), np.array([8.0, 8.0, 4.0, 4.0])
    view[2, 3] = 3.0
    outs = (np.zeros((m, 2), dt), np.zeros((m, 3), dt), np.zeros((m, 3), dt), np.zeros(m, dt), np.zeros(m, dt))
    ints = (np.zeros(m, np.int32), np.zeros((m, 4), np.int32))
    project_forward(*params, 3, view, cam, intr, W, H, 0.01, *outs, *ints)
    # the forward's five float outputs stand in for their incoming gradients
    project_backward(*params, 3, view, cam, intr, W, H, 0.01, False, *outs, *(np.empty_like(p) for p in params))
    all_finite(outs[0].reshape(-1))


def constants_fingerprint() -> str:
    """A digest of :mod:`nerfkit.splat_constants`' values (its upper-case names)."""
    values = sorted((k, v) for k, v in vars(splat_constants).items() if k.isupper())
    return hashlib.sha256(repr(values).encode()).hexdigest()


def drop_kernels_of_other_constants() -> None:
    """numba keys its on-disk cache on this file's source alone, but the kernels bake in the
    values of :mod:`nerfkit.splat_constants`: edited there, they would load stale. So the
    constants' fingerprint is kept beside numba's cache files (``splat_numba.constants``);
    when it differs, this module's cache files are deleted (its kernels compile anew)."""
    path = getattr(getattr(depth_order, "_cache", None), "cache_path", None)  # every kernel's folder
    if path is None:  # no on-disk cache
        return
    try:
        cache_dir = Path(path)
        stamp = cache_dir / "splat_numba.constants"
        fingerprint = constants_fingerprint()
        if stamp.is_file() and stamp.read_text() == fingerprint:
            return
        for old in [*cache_dir.glob("splat_numba.*.nbi"), *cache_dir.glob("splat_numba.*.nbc")]:
            old.unlink(missing_ok=True)
        cache_dir.mkdir(parents=True, exist_ok=True)
        stamp.write_text(fingerprint)
    except OSError:  # a cache folder that cannot be written: numba caches nothing there either
        pass


drop_kernels_of_other_constants()  # at import: before any kernel loads from the cache
