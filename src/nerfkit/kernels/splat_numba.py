"""Compiled (numba) CPU rasterizer of projected 3D Gaussians; importing this needs numba.

The reference is :func:`nerfkit.kernels.splat_reference.rasterize_reference`; the rules
(tiles, depth order, alpha thresholds, early termination) are the same, see there.

* :func:`bin_tiles`: per tile, the visible Gaussians in depth order (a bucket sort of
  the globally depth-sorted list, so each tile's list stays sorted).
* :func:`rasterize_forward`: tiles in parallel; per tile the Gaussians' data is gathered
  into contiguous arrays first, then each pixel composites front to back. Writes the
  final transmittance and the end of the contributing list per pixel for the backward.
* :func:`rasterize_backward`: back to front over the same lists (INRIA's recursion).
  Tiles are split into lanes (one per thread); each lane adds into its own gradient
  buffer, so no two threads write the same memory; the caller sums the lanes.

Gradient channels per Gaussian (``G_*``): 2D mean x/y, conic a/b/c, opacity, r, g, b.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

TILE = 16
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
G_MX, G_MY, G_A, G_B, G_C, G_OP, G_R, G_G, G_BL = range(9)
N_GRAD = 9


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
def _gather(ids, start, end, means2d, conics, colors, opac, depths, buf):
    """Copy the tile's Gaussians into ``buf`` (m, 10): mx, my, a, b, c, op, r, g, b, depth."""
    for k in range(end - start):
        g = ids[start + k]
        buf[k, 0] = means2d[g, 0]
        buf[k, 1] = means2d[g, 1]
        buf[k, 2] = conics[g, 0]
        buf[k, 3] = conics[g, 1]
        buf[k, 4] = conics[g, 2]
        buf[k, 5] = opac[g]
        buf[k, 6] = colors[g, 0]
        buf[k, 7] = colors[g, 1]
        buf[k, 8] = colors[g, 2]
        buf[k, 9] = depths[g]


@njit(parallel=True, cache=True, fastmath=False)
def rasterize_forward(offsets, ids, means2d, conics, colors, opac, depths, background, width, height,
                      n_tiles_x, out_rgb, out_depth, out_alpha, final_T, n_contrib):
    """Composite every pixel; outputs (H, W, 3) / (H, W) are written in place.

    ``n_contrib[y, x]`` is the index into ``ids`` just past the last Gaussian that
    contributed (the backward pass starts there)."""
    n_tiles = offsets.shape[0] - 1
    for t in prange(n_tiles):
        start, end = offsets[t], offsets[t + 1]
        ty, tx = t // n_tiles_x, t % n_tiles_x
        x0, y0 = tx * TILE, ty * TILE
        x1, y1 = min(x0 + TILE, width), min(y0 + TILE, height)
        m = end - start
        buf = np.empty((max(m, 1), 10), means2d.dtype)
        _gather(ids, start, end, means2d, conics, colors, opac, depths, buf)
        for y in range(y0, y1):
            py = y + 0.5
            for x in range(x0, x1):
                px = x + 0.5
                T = 1.0
                r = 0.0
                g_ = 0.0
                b_ = 0.0
                d_ = 0.0
                last = start
                for k in range(m):
                    dx = buf[k, 0] - px
                    dy = buf[k, 1] - py
                    power = -0.5 * (buf[k, 2] * dx * dx + buf[k, 4] * dy * dy) - buf[k, 3] * dx * dy
                    if power > 0.0:
                        continue
                    alpha = min(ALPHA_MAX, buf[k, 5] * math.exp(power))
                    if alpha < ALPHA_MIN:
                        continue
                    test_T = T * (1.0 - alpha)
                    if test_T < T_MIN:
                        break
                    w = alpha * T
                    r += w * buf[k, 6]
                    g_ += w * buf[k, 7]
                    b_ += w * buf[k, 8]
                    d_ += w * buf[k, 9]
                    T = test_T
                    last = start + k + 1
                out_rgb[y, x, 0] = r + T * background[y, x, 0]
                out_rgb[y, x, 1] = g_ + T * background[y, x, 1]
                out_rgb[y, x, 2] = b_ + T * background[y, x, 2]
                out_depth[y, x] = d_
                out_alpha[y, x] = 1.0 - T
                final_T[y, x] = T
                n_contrib[y, x] = last


@njit(parallel=True, cache=True, fastmath=False)
def rasterize_backward(offsets, ids, means2d, conics, colors, opac, depths, background, width, height,
                       n_tiles_x, final_T, n_contrib, grad_rgb, grads):
    """Gradients of a loss w.r.t. each Gaussian's 2D mean, conic, opacity and colour.

    ``grad_rgb`` (H, W, 3) is dL/d(out_rgb); ``grads`` (lanes, n, 9) zeroed, written in place
    (lane ``l`` handles tiles ``l, l + lanes, ...``)."""
    n_tiles = offsets.shape[0] - 1
    lanes = grads.shape[0]
    for lane in prange(lanes):
        for t in range(lane, n_tiles, lanes):
            start, end = offsets[t], offsets[t + 1]
            m = end - start
            if m == 0:
                continue
            ty, tx = t // n_tiles_x, t % n_tiles_x
            x0, y0 = tx * TILE, ty * TILE
            x1, y1 = min(x0 + TILE, width), min(y0 + TILE, height)
            buf = np.empty((m, 10), means2d.dtype)
            _gather(ids, start, end, means2d, conics, colors, opac, depths, buf)
            acc = np.zeros((m, N_GRAD), means2d.dtype)
            for y in range(y0, y1):
                py = y + 0.5
                for x in range(x0, x1):
                    px = x + 0.5
                    T_final = final_T[y, x]
                    T = T_final
                    gr, gg, gb = grad_rgb[y, x, 0], grad_rgb[y, x, 1], grad_rgb[y, x, 2]
                    bg_dot = background[y, x, 0] * gr + background[y, x, 1] * gg + background[y, x, 2] * gb
                    acc_r = 0.0
                    acc_g = 0.0
                    acc_b = 0.0
                    last_alpha = 0.0
                    last_r = 0.0
                    last_g = 0.0
                    last_b = 0.0
                    for k in range(n_contrib[y, x] - start - 1, -1, -1):
                        dx = buf[k, 0] - px
                        dy = buf[k, 1] - py
                        ca, cb, cc = buf[k, 2], buf[k, 3], buf[k, 4]
                        power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                        if power > 0.0:
                            continue
                        G = math.exp(power)
                        raw = buf[k, 5] * G
                        alpha = min(ALPHA_MAX, raw)
                        if alpha < ALPHA_MIN:
                            continue
                        T = T / (1.0 - alpha)
                        w = alpha * T
                        acc[k, G_R] += w * gr
                        acc[k, G_G] += w * gg
                        acc[k, G_BL] += w * gb
                        acc_r = last_alpha * last_r + (1.0 - last_alpha) * acc_r
                        acc_g = last_alpha * last_g + (1.0 - last_alpha) * acc_g
                        acc_b = last_alpha * last_b + (1.0 - last_alpha) * acc_b
                        last_alpha = alpha
                        last_r, last_g, last_b = buf[k, 6], buf[k, 7], buf[k, 8]
                        dl_dalpha = ((last_r - acc_r) * gr + (last_g - acc_g) * gg + (last_b - acc_b) * gb) * T
                        dl_dalpha -= T_final / (1.0 - alpha) * bg_dot
                        if raw > ALPHA_MAX:
                            continue  # alpha is clamped: no gradient to opacity, mean or conic
                        acc[k, G_OP] += G * dl_dalpha
                        dl_dpower = buf[k, 5] * G * dl_dalpha
                        acc[k, G_MX] += dl_dpower * (-ca * dx - cb * dy)
                        acc[k, G_MY] += dl_dpower * (-cc * dy - cb * dx)
                        acc[k, G_A] += dl_dpower * (-0.5 * dx * dx)
                        acc[k, G_B] += dl_dpower * (-dx * dy)
                        acc[k, G_C] += dl_dpower * (-0.5 * dy * dy)
            for k in range(m):
                g = ids[start + k]
                for j in range(N_GRAD):
                    grads[lane, g, j] += acc[k, j]


def warm_up() -> None:
    """Compile (or load from the on-disk cache) the kernels for float32 and float64."""
    for dt in (np.float32, np.float64):
        n = 2
        means2d = np.array([[4.0, 4.0], [6.0, 5.0]], dt)
        conics = np.array([[0.5, 0.0, 0.5]] * n, dt)
        colors = np.full((n, 3), 0.5, dt)
        opac = np.full(n, 0.5, dt)
        depths = np.array([1.0, 2.0], dt)
        rects = np.array([[0, 1, 0, 1]] * n, np.int32)
        offsets, ids = bin_tiles(np.arange(n, dtype=np.int64), rects, 1, 1)
        H = W = 8
        bg = np.zeros((H, W, 3), dt)
        rgb, dep, alp, T = np.zeros((H, W, 3), dt), np.zeros((H, W), dt), np.zeros((H, W), dt), np.zeros((H, W), dt)
        nc = np.zeros((H, W), np.int64)
        rasterize_forward(offsets, ids, means2d, conics, colors, opac, depths, bg, W, H, 1, rgb, dep, alp, T, nc)
        grads = np.zeros((2, n, N_GRAD), dt)
        rasterize_backward(offsets, ids, means2d, conics, colors, opac, depths, bg, W, H, 1, T, nc, rgb, grads)
