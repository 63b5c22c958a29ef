"""Compiled (numba) CPU kernels of the grid field; importing this module needs numba.

Each kernel has a pure-torch reference in :mod:`nerfkit.kernels.reference` (or in
:mod:`nerfkit.render.occupancy` for the marching) and tests comparing the two. All
kernels take numpy views of contiguous CPU tensors (no copies) and write their outputs
in place. ``cache=True`` keeps the machine code on disk, so only the first run on a
machine pays the compile time.

Per-ray loops run over both cores with ``prange``. The backward pass adds gradients
into one dense buffer per lane (a fixed split of the rays), so no two threads ever add
into the same memory (deterministic, no atomics); the optimizer sums the lanes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

# Per-sample record written by the training forward pass (sample-major: [k, ray, field]).
F_FX, F_FY, F_FZ, F_RAW, F_SIGMA, F_R, F_G, F_B, F_T = range(9)
N_FIELDS = 9
# the base vertex row of a stored sample is ``s_idx & ROW_MASK``; the bits above hold, per
# axis, how the clamp into the box passes d(coordinate) on (see :func:`_edge_code`)
EDGE_SHIFT = 56
ROW_MASK = (1 << EDGE_SHIFT) - 1
# how many samples ahead along the ray to prefetch grid rows
PREFETCH_AHEAD = 4
# a sparse grid's vertex rows (where a vertex's grid row is) are prefetched this many samples
# before the grid rows: the grid rows' prefetch reads them, and stalled on their misses
VERTEX_ROWS_AHEAD = 4
# when only rendering (no backward pass), samples of smaller weight skip their colour
SKIP_COLOUR_BELOW = 1e-7


def _prefetch_codegen(context, builder, signature, args):
    """A cache-line prefetch of the array element ``args[0][args[1:]]`` (read, high locality)."""
    from llvmlite import binding, ir

    name = "llvm.prefetch.p0" if binding.llvm_version_info[0] >= 15 else "llvm.prefetch.p0i8"
    arrty = signature.args[0]
    ary = context.make_array(arrty)(context, builder, args[0])
    ij = [context.cast(builder, v, t, types.intp) for v, t in zip(args[1:], signature.args[1:])]
    ptr = cgutils.get_item_pointer(context, builder, arrty, ary, ij, wraparound=False)
    i8p = ir.PointerType(ir.IntType(8))
    i32 = ir.IntType(32)
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]), name)
    builder.call(fn, [builder.bitcast(ptr, i8p), i32(0), i32(3), i32(1)])
    return context.get_dummy_value()


@intrinsic
def prefetch(typingctx, arr, row, col):
    """``prefetch(arr2d, row, col)``: a hint to pull ``arr2d[row, col]``'s cache line in.

    Gathers from the grid are latency-bound; prefetching the cell a few samples ahead
    along the ray overlaps those misses with the shading of the current sample.
    """
    return types.void(arr, row, col), _prefetch_codegen


@intrinsic
def prefetch1(typingctx, arr, i):
    """``prefetch1(arr1d, i)``: :func:`prefetch` of ``arr1d[i]`` (a sparse grid's vertex
    rows: the grid rows a sample reads are found through them, so they are fetched earlier)."""
    return types.void(arr, i), _prefetch_codegen


@njit(cache=True, fastmath=False, inline="always")
def _softplus(x):
    # log(1 + e^x): log1p is ~3x slower than log here, and for x < -15 the result is
    # e^x to within 2e-7 (relative), far below float32 resolution of the inputs
    if x > 20.0:
        return x
    e = math.exp(x)
    if x < -15.0:
        return e
    return math.log(1.0 + e)


@njit(cache=True, fastmath=False, inline="always")
def _softplus_grad(x):
    # torch's softplus backward: 1 above the threshold, sigmoid(x) below it
    if x > 20.0:
        return 1.0
    e = math.exp(x)
    return e / (1.0 + e)


@njit(cache=True, fastmath=False, inline="always")
def _sigmoid(x):
    if x >= 0:
        return 1.0 / (1.0 + math.exp(-x))
    e = math.exp(x)
    return e / (1.0 + e)


@njit(cache=True, fastmath=False, inline="always")
def _cell(g, r):
    """Clamped cell index and fraction along one axis (matches reference.cell_of)."""
    hi = r - 1.0
    if g < 0.0:
        g = 0.0
    if g > hi:
        g = hi
    i = float(math.floor(g))
    if i > hi - 1.0:
        i = hi - 1.0
    return int(i), g - i


@njit(cache=True, fastmath=False, inline="always")
def _edge_code(g, r):
    """How :func:`_cell`'s clamp passes a derivative along one axis, as torch's autograd
    of ``minimum(clamp(g, min=0), r - 1)`` does: 0 inside ``[0, r-1)`` (slope 1), 1 outside
    (slope 0), 2 exactly on the upper face (slope 1/2)."""
    hi = r - 1.0
    if g < 0.0 or g > hi:
        return 1
    if g == hi:
        return 2
    return 0


@njit(cache=True, fastmath=False, inline="always")
def _edge_bits(gx, gy, gz, rx, ry, rz):
    """The three axes' :func:`_edge_code` packed above ``EDGE_SHIFT`` (0 for a point
    strictly inside the box)."""
    code = _edge_code(gx, rx) | (_edge_code(gy, ry) << 2) | (_edge_code(gz, rz) << 4)
    return code << EDGE_SHIFT


@njit(cache=True, fastmath=False, inline="always")
def _edge_slope(bits, axis):
    """d(clamped coordinate)/d(coordinate) along ``axis`` from a stored sample's bits."""
    code = (bits >> (EDGE_SHIFT + 2 * axis)) & 3
    return 1.0 if code == 0 else (0.0 if code == 1 else 0.5)


@njit(cache=True, fastmath=False, inline="always")
def _leap(k, ta, tb, ur, inv_step, ox, oy, oz, idx, idy, idz, x0, y0, z0, size):
    """Index of the next lattice point to look at after finding the cube
    ``[x0, x0 + size] x [y0, ...] x [z0, ...]`` (grid units) empty at lattice point ``k``.

    That is the first lattice point at or beyond where the ray leaves the cube, less a
    tolerance of 1e-6 steps (a point that close to the exit is looked at again rather
    than risk skipping a point of the next cell), and always at least ``k + 1``.
    ``idx, idy, idz`` are the inverse ray directions in grid units (inf for 0).
    """
    t_exit = 1e30
    if idx > 0:
        t_exit = min(t_exit, (x0 + size - ox) * idx)
    elif idx < 0:
        t_exit = min(t_exit, (x0 - ox) * idx)
    if idy > 0:
        t_exit = min(t_exit, (y0 + size - oy) * idy)
    elif idy < 0:
        t_exit = min(t_exit, (y0 - oy) * idy)
    if idz > 0:
        t_exit = min(t_exit, (z0 + size - oz) * idz)
    elif idz < 0:
        t_exit = min(t_exit, (z0 - oz) * idz)
    kn = int(math.ceil((min(t_exit, tb) - ta) * inv_step - ur - 1e-6))
    return max(k + 1, kn)


@njit(cache=True, fastmath=False, inline="always")
def _row(vidx, v, voff):
    """Feature row of vertex ``v``: ``v + voff`` for a dense grid (``voff >= 0``, no lookup),
    else ``vidx[v]``."""
    if voff >= 0:
        return v + voff
    return vidx[v]


@njit(cache=True, parallel=True, fastmath=False)
def render_forward(
    grid,
    vidx,
    voff,
    rx,
    ry,
    rz,
    lo,
    inv_voxel,
    occ,
    coarse,
    cf,
    rays_o,
    rays_d,
    sh,
    t0,
    t1,
    u,
    step,
    dscale,
    eps,
    out_rgb,
    out_depth,
    out_acc,
    out_count,
    store,
    s_idx,
    s_f,
):
    """March, shade and composite every ray (foreground only: no background term).

    Args:
        grid: (M, C) float32 feature rows; vidx: (rx * ry * rz,) int32, the row of each
            vertex (a sparse grid maps unallocated vertices to one row of no density);
            voff: when >= 0, ``vidx[v] == v + voff`` for all v and is not read (dense grids);
            rx, ry, rz: vertex counts.
        lo: (3,) float64 box corner; inv_voxel: 1 / voxel.
        occ: (rz-1, ry-1, rx-1) uint8 cell occupancy; coarse: occupancy max-pooled by cf.
        rays_o, rays_d: (n, 3) float64; sh: (n, K) float32 SH basis of the directions.
        t0, t1, u: (n,) float64 ray segment in the box and per-ray lattice jitter.
        step: sample spacing = interval length; dscale: density scale; eps: stop when
            the transmittance falls below it.
        out_rgb (n, 3), out_depth (n,), out_acc (n,) float32; out_count (n,) int32.
        store: keep per-sample records for the backward pass in s_idx (cap, n) int64
            (base vertex row, and edge bits: see ``ROW_MASK``) and s_f (cap, n, 9) float32.
    """
    n = rays_o.shape[0]
    C = grid.shape[1]
    K = sh.shape[1]
    sxy = rx * ry
    cap = s_idx.shape[0]
    inv_step = 1.0 / step
    cshift = -1  # log2(cf) when cf is a power of two: blocks by a shift, not a division
    for b in range(31):
        if (1 << b) == cf:
            cshift = b
    for r in prange(n):
        ta = t0[r]
        tb = t1[r]
        ur = u[r]
        ox = (rays_o[r, 0] - lo[0]) * inv_voxel
        oy = (rays_o[r, 1] - lo[1]) * inv_voxel
        oz = (rays_o[r, 2] - lo[2]) * inv_voxel
        dx = rays_d[r, 0] * inv_voxel
        dy = rays_d[r, 1] * inv_voxel
        dz = rays_d[r, 2] * inv_voxel
        idx = 1.0 / dx if dx != 0.0 else 0.0
        idy = 1.0 / dy if dy != 0.0 else 0.0
        idz = 1.0 / dz if dz != 0.0 else 0.0
        T = 1.0
        cr = 0.0
        cg = 0.0
        cb = 0.0
        dep = 0.0
        cnt = 0
        k = 0
        while True:
            t = ta + (k + ur) * step
            if t >= tb or eps > T:
                break
            gx = ox + t * dx
            gy = oy + t * dy
            gz = oz + t * dz
            ix, fx = _cell(gx, rx)
            iy, fy = _cell(gy, ry)
            iz, fz = _cell(gz, rz)
            if cf > 1:
                if cshift >= 0:
                    bx, by, bz = ix >> cshift, iy >> cshift, iz >> cshift
                else:
                    bx, by, bz = ix // cf, iy // cf, iz // cf
                if coarse[bz, by, bx] == 0:
                    k = _leap(k, ta, tb, ur, inv_step, ox, oy, oz, idx, idy, idz, bx * cf, by * cf, bz * cf, cf)
                    continue
            if occ[iz, iy, ix] == 0:
                k = _leap(k, ta, tb, ur, inv_step, ox, oy, oz, idx, idy, idz, ix, iy, iz, 1)
                continue
            if voff < 0:
                tv = t + (PREFETCH_AHEAD + VERTEX_ROWS_AHEAD) * step
                if tv < tb:
                    jx, _ = _cell(ox + tv * dx, rx)
                    jy, _ = _cell(oy + tv * dy, ry)
                    jz, _ = _cell(oz + tv * dz, rz)
                    qb = (jz * ry + jy) * rx + jx
                    for q in range(4):
                        prefetch1(vidx, qb + (q >> 1) * sxy + (q & 1) * rx)
            tp = t + PREFETCH_AHEAD * step
            if tp < tb:
                jx, _ = _cell(ox + tp * dx, rx)
                jy, _ = _cell(oy + tp * dy, ry)
                jz, _ = _cell(oz + tp * dz, rz)
                qb = (jz * ry + jy) * rx + jx
                for q in range(4):
                    qrow = qb + (q >> 1) * sxy + (q & 1) * rx
                    prefetch(grid, _row(vidx, qrow, voff), 0)
                    prefetch(grid, _row(vidx, qrow + 1, voff), C - 1)
            if store and cnt >= cap:
                break
            base = (iz * ry + iy) * rx + ix
            raw = 0.0
            zr = 0.0
            zg = 0.0
            zb = 0.0
            for cz in range(2):
                wz = fz if cz else 1.0 - fz
                for cy in range(2):
                    wzy = wz * (fy if cy else 1.0 - fy)
                    row0 = base + cz * sxy + cy * rx
                    for cx in range(2):
                        w = wzy * (fx if cx else 1.0 - fx)
                        row = _row(vidx, row0 + cx, voff)
                        raw += w * grid[row, 0]
                        sr = 0.0
                        sg = 0.0
                        sb = 0.0
                        for j in range(K):
                            shj = sh[r, j]
                            sr += grid[row, 1 + j] * shj
                            sg += grid[row, 1 + K + j] * shj
                            sb += grid[row, 1 + 2 * K + j] * shj
                        zr += w * sr
                        zg += w * sg
                        zb += w * sb
            sigma = dscale * _softplus(raw)
            tau = sigma * step
            e = math.exp(-tau)
            wgt = T * (1.0 - e)
            if store or wgt > SKIP_COLOUR_BELOW:
                colr = _sigmoid(zr)
                colg = _sigmoid(zg)
                colb = _sigmoid(zb)
                cr += wgt * colr
                cg += wgt * colg
                cb += wgt * colb
            else:  # rendering only: a sample this faint changes no colour channel by 1e-7
                colr = colg = colb = 0.5
            dep += wgt * t
            if store:
                s_idx[cnt, r] = base | _edge_bits(gx, gy, gz, rx, ry, rz)
                s_f[cnt, r, 0] = fx
                s_f[cnt, r, 1] = fy
                s_f[cnt, r, 2] = fz
                s_f[cnt, r, 3] = raw
                s_f[cnt, r, 4] = sigma
                s_f[cnt, r, 5] = colr
                s_f[cnt, r, 6] = colg
                s_f[cnt, r, 7] = colb
                s_f[cnt, r, 8] = t
            cnt += 1
            T = T * e
            k += 1
        out_rgb[r, 0] = cr
        out_rgb[r, 1] = cg
        out_rgb[r, 2] = cb
        out_depth[r] = dep
        out_acc[r] = 1.0 - T
        out_count[r] = cnt


@njit(cache=True, fastmath=False, inline="always")
def _distortion_sums(s_f, r, cnt, step, te):
    """Over ray ``r``'s stored samples (plus the leftover weight at ``te`` when finite):
    ``(sum w, sum w t, sum_ij w_i w_j |t_i - t_j|, sum w^2 of the real samples)``."""
    T = 1.0
    w_sum = 0.0
    wt_sum = 0.0
    pairs = 0.0
    sq = 0.0
    for k in range(cnt):
        t = s_f[k, r, 8]
        e = math.exp(-s_f[k, r, 4] * step)
        w = T * (1.0 - e)
        T = T * e
        pairs += 2.0 * w * (t * w_sum - wt_sum)
        w_sum += w
        wt_sum += w * t
        sq += w * w
    if math.isfinite(te):
        pairs += 2.0 * T * (te * w_sum - wt_sum)
        w_sum += T
        wt_sum += T * te
    return w_sum, wt_sum, pairs, sq


@njit(parallel=True, cache=True, fastmath=False)
def distortion_forward(s_f, counts, step, t_end, out):
    """The distortion loss of each ray (see :func:`nerfkit.render.volrend.distortion`)
    from the stored samples of :func:`render_forward`: ``out (n,)`` float32."""
    for r in prange(counts.shape[0]):
        _, _, pairs, sq = _distortion_sums(s_f, r, counts[r], step, t_end[r])
        out[r] = pairs + step * sq / 3.0


@njit(cache=True, fastmath=False, inline="always")
def _trilinear_grad(v000, v001, v010, v011, v100, v101, v110, v111, fx, fy, fz):
    """Trilinear interpolation of 8 corner values ``v{z}{y}{x}`` at fractions ``fx, fy, fz``
    and its derivatives: ``(value, d/dfx, d/dfy, d/dfz)``."""
    e00 = v000 + fx * (v001 - v000)
    e01 = v010 + fx * (v011 - v010)
    e10 = v100 + fx * (v101 - v100)
    e11 = v110 + fx * (v111 - v110)
    b0 = e00 + fy * (e01 - e00)
    b1 = e10 + fy * (e11 - e10)
    d0 = (v001 - v000) + fy * ((v011 - v010) - (v001 - v000))
    d1 = (v101 - v100) + fy * ((v111 - v110) - (v101 - v100))
    return (b0 + fz * (b1 - b0), d0 + fz * (d1 - d0), (e01 - e00) + fz * ((e11 - e10) - (e01 - e00)), b1 - b0)


@njit(cache=True, fastmath=False, inline="always")
def _colour_dot(grid, row, j, K, dzr, dzg, dzb):
    """``sum_c dL/dz_c * coefficient j of colour c`` at one vertex row."""
    return dzr * grid[row, 1 + j] + dzg * grid[row, 1 + K + j] + dzb * grid[row, 1 + 2 * K + j]


@njit(cache=True, fastmath=False, inline="always")
def _sample_point_grad(grid, vidx, voff, base, sxy, rx, fx, fy, fz, graw, dzr, dzg, dzb, sh, g_sh, r):
    """Gradient of the loss w.r.t. one sample's (clamped) grid coordinates, and its
    share of ``dL/dsh`` added into ``g_sh[r]``; the caller applies the clamp's slope.

    The loss sees the sample through ``raw`` and ``z_c = sum_j Z_cj sh_j`` (``Z_cj`` the
    interpolated coefficients), so ``dL/dg = graw draw/dg + sum_j sh_j dA_j/dg`` and
    ``dL/dsh_j = A_j`` with ``A_j = sum_c dz_c Z_cj``, interpolated like any feature.

    Returns:
        ``(dL/dgx, dL/dgy, dL/dgz)`` in grid units.
    """
    K = sh.shape[1]
    r000, r001 = _row(vidx, base, voff), _row(vidx, base + 1, voff)
    r010, r011 = _row(vidx, base + rx, voff), _row(vidx, base + rx + 1, voff)
    r100, r101 = _row(vidx, base + sxy, voff), _row(vidx, base + sxy + 1, voff)
    r110, r111 = _row(vidx, base + sxy + rx, voff), _row(vidx, base + sxy + rx + 1, voff)
    _, ax, ay, az = _trilinear_grad(
        grid[r000, 0],
        grid[r001, 0],
        grid[r010, 0],
        grid[r011, 0],
        grid[r100, 0],
        grid[r101, 0],
        grid[r110, 0],
        grid[r111, 0],
        fx,
        fy,
        fz,
    )
    ax *= graw
    ay *= graw
    az *= graw
    for j in range(K):
        A, bx, by, bz = _trilinear_grad(
            _colour_dot(grid, r000, j, K, dzr, dzg, dzb),
            _colour_dot(grid, r001, j, K, dzr, dzg, dzb),
            _colour_dot(grid, r010, j, K, dzr, dzg, dzb),
            _colour_dot(grid, r011, j, K, dzr, dzg, dzb),
            _colour_dot(grid, r100, j, K, dzr, dzg, dzb),
            _colour_dot(grid, r101, j, K, dzr, dzg, dzb),
            _colour_dot(grid, r110, j, K, dzr, dzg, dzb),
            _colour_dot(grid, r111, j, K, dzr, dzg, dzb),
            fx,
            fy,
            fz,
        )
        g_sh[r, j] += A
        shj = sh[r, j]
        ax += shj * bx
        ay += shj * by
        az += shj * bz
    return ax, ay, az


@njit(cache=True, parallel=True, fastmath=False)
def render_backward(
    s_idx,
    s_f,
    counts,
    sh,
    grid,
    vidx,
    voff,
    rx,
    ry,
    inv_voxel,
    step,
    dscale,
    rgb,
    depth,
    acc,
    g_rgb,
    g_depth,
    g_acc,
    g_dist,
    t_end,
    grad_near,
    grads,
    touched,
    ray_grads,
    g_o,
    g_d,
    g_sh,
):
    """Gradients of the loss w.r.t. the grid (added into per-lane buffers) and, with
    ``ray_grads``, w.r.t. the rays.

    With ``tau_k = sigma_k step``, ``T_{k+1} = T_k exp(-tau_k)`` and suffix sums over the
    later samples: ``dC/dtau_k = T_{k+1} c_k - sum_{i>k} w_i c_i``,
    ``dD/dtau_k = T_{k+1} t_k - sum_{i>k} w_i t_i``, ``dA/dtau_k = T_{k+1} - sum_{i>k} w_i``
    and ``dC/dc_k = w_k``; the suffix sums are the totals minus running prefix sums.
    The distortion loss ``L`` (:func:`distortion_forward`) enters the same way:
    ``dL/dtau_k = T_{k+1} g_k - sum_{i>k} w_i g_i`` with ``g_i = dL/dw_i``, whose total
    ``sum_i w_i g_i = 2 L_pairs + (2/3) step sum_i w_i^2`` a first pass over the ray gives.

    Lane ``l`` of ``L = grads.shape[0]`` handles a contiguous range of rays and adds only
    into ``grads[l]`` (M, C), so lanes never race and the result does not depend on
    thread scheduling; the optimizer sums the lanes. ``touched`` (M,) uint8 marks the row
    of every vertex of every sample (concurrent writes of the same value 1 are benign). ``grads``
    of shape (L, 0, C) asks for no grid gradient.

    Ray gradients hold each sample's ``t`` fixed: the sample at ``x = o + t d`` gives
    ``dL/do += dL/dx`` and ``dL/dd += t dL/dx`` (:func:`_sample_point_grad`, times
    ``inv_voxel`` and the clamp's slope); the colour's dependence on the direction is
    returned as ``dL/dsh``, for torch to chain through the SH basis.

    Args:
        s_idx (cap, n), s_f (cap, n, 9), counts (n,): records from :func:`render_forward`.
        sh (n, K) float32; grid (M, C) float32, vidx (N,) int32, voff: the forward's inputs (grid
            read only with ``ray_grads``); inv_voxel: 1 / voxel.
        rgb, depth, acc: the forward outputs (foreground colour, no background).
        g_rgb (n, 3), g_depth (n,), g_acc (n,), g_dist (n,): upstream gradients (of the
            distortion loss for ``g_dist``; rays with 0 skip its passes).
        t_end (n,) float64: where the distortion loss puts the leftover weight (inf: nowhere).
        grad_near: distance below which sample gradients are damped (0: none).
        g_o (n, 3), g_d (n, 3), g_sh (n, K) float64, zero on entry: the ray gradients
            (left untouched without ``ray_grads``).
    """
    n = counts.shape[0]
    K = sh.shape[1]
    L = grads.shape[0]
    grid_grad = grads.shape[1] != 0
    sxy = rx * ry
    C = grads.shape[2]
    scratch = np.zeros((L, C), np.float32)
    for lane in prange(L):
        grad = grads[lane]
        gf = scratch[lane]
        for r in range(lane * n // L, (lane + 1) * n // L):
            gr = g_rgb[r, 0]
            gg = g_rgb[r, 1]
            gb = g_rgb[r, 2]
            gd = g_depth[r]
            ga = g_acc[r]
            T = 1.0
            pr = 0.0
            pg = 0.0
            pb = 0.0
            pd = 0.0
            pa = 0.0
            cnt = counts[r]
            gl = g_dist[r]
            w_tot = 0.0
            wt_tot = 0.0
            g_tot = 0.0
            if gl != 0.0:
                w_tot, wt_tot, pairs, sq = _distortion_sums(s_f, r, cnt, step, t_end[r])
                g_tot = 2.0 * pairs + (2.0 / 3.0) * step * sq
            w_pre = 0.0
            wt_pre = 0.0
            wg_pre = 0.0
            for k in range(cnt):
                kv = k + 2 + VERTEX_ROWS_AHEAD
                if voff < 0 and kv < cnt:
                    vb = s_idx[kv, r] & ROW_MASK
                    for q in range(4):
                        prefetch1(vidx, vb + (q >> 1) * sxy + (q & 1) * rx)
                if k + 2 < cnt:
                    qb = s_idx[k + 2, r] & ROW_MASK
                    for q in range(4):
                        qrow = qb + (q >> 1) * sxy + (q & 1) * rx
                        qa, qc = _row(vidx, qrow, voff), _row(vidx, qrow + 1, voff)
                        if grid_grad:
                            prefetch(grad, qa, 0)
                            prefetch(grad, qc, C - 1)
                        if ray_grads:
                            prefetch(grid, qa, 0)
                            prefetch(grid, qc, C - 1)
                raw = s_f[k, r, 3]
                sigma = s_f[k, r, 4]
                colr = s_f[k, r, 5]
                colg = s_f[k, r, 6]
                colb = s_f[k, r, 7]
                t = s_f[k, r, 8]
                tau = sigma * step
                e = math.exp(-tau)
                w = T * (1.0 - e)
                Tn = T * e
                pr += w * colr
                pg += w * colg
                pb += w * colb
                pd += w * t
                pa += w
                dtau = (
                    gr * (Tn * colr - (rgb[r, 0] - pr))
                    + gg * (Tn * colg - (rgb[r, 1] - pg))
                    + gb * (Tn * colb - (rgb[r, 2] - pb))
                    + gd * (Tn * t - (depth[r] - pd))
                    + ga * (Tn - (acc[r] - pa))
                )
                if gl != 0.0:
                    # dL/dw_k: |t_k - t_j| summed over earlier (w_pre) and later samples
                    g_k = (
                        2.0 * ((t * w_pre - wt_pre) + (wt_tot - wt_pre - w * t) - t * (w_tot - w_pre - w))
                        + (2.0 / 3.0) * step * w
                    )
                    wg_pre += w * g_k
                    dtau += gl * (Tn * g_k - (g_tot - wg_pre))
                    w_pre += w
                    wt_pre += w * t
                near = 1.0
                if t < grad_near:
                    near = (t / grad_near) * (t / grad_near)
                graw = dtau * step * dscale * _softplus_grad(raw) * near
                dzr = w * gr * colr * (1.0 - colr) * near
                dzg = w * gg * colg * (1.0 - colg) * near
                dzb = w * gb * colb * (1.0 - colb) * near
                T = Tn
                bits = s_idx[k, r]
                base = bits & ROW_MASK
                fx = s_f[k, r, 0]
                fy = s_f[k, r, 1]
                fz = s_f[k, r, 2]
                if ray_grads:
                    ax, ay, az = _sample_point_grad(
                        grid, vidx, voff, base, sxy, rx, fx, fy, fz, graw, dzr, dzg, dzb, sh, g_sh, r
                    )
                    ax *= inv_voxel * _edge_slope(bits, 0)
                    ay *= inv_voxel * _edge_slope(bits, 1)
                    az *= inv_voxel * _edge_slope(bits, 2)
                    g_o[r, 0] += ax
                    g_o[r, 1] += ay
                    g_o[r, 2] += az
                    g_d[r, 0] += t * ax
                    g_d[r, 1] += t * ay
                    g_d[r, 2] += t * az
                if not grid_grad:
                    continue
                gf[0] = graw
                for j in range(K):
                    shj = sh[r, j]
                    gf[1 + j] = dzr * shj
                    gf[1 + K + j] = dzg * shj
                    gf[1 + 2 * K + j] = dzb * shj
                for cz in range(2):
                    wz = fz if cz else 1.0 - fz
                    for cy in range(2):
                        wzy = wz * (fy if cy else 1.0 - fy)
                        row0 = base + cz * sxy + cy * rx
                        for cx in range(2):
                            wc = np.float32(wzy * (fx if cx else 1.0 - fx))
                            row = _row(vidx, row0 + cx, voff)
                            for c in range(1 + 3 * K):
                                grad[row, c] += wc * gf[c]
                            touched[row] = 1


@njit(cache=True, fastmath=False, inline="always")
def _nonzero_bytes(w):
    """How many of the 8 bytes of the uint64 ``w`` are not zero."""
    x = w | (w >> np.uint64(4))
    x |= x >> np.uint64(2)
    x |= x >> np.uint64(1)
    x &= np.uint64(0x0101010101010101)
    return int((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True)
def touched_rows(touched):
    """The rows (m,) int64 whose ``touched`` flag is set (not 0), in increasing order.

    Reads the flags eight at a time and skips words of eight clear flags: a step touches
    a few percent of a grid's rows, so most words are clear (``np.flatnonzero`` is the
    reference)."""
    n = touched.shape[0]
    n8 = n // 8
    words = touched[: n8 * 8].view(np.uint64)
    m = 0
    for k in range(n8):
        if words[k] != 0:
            m += _nonzero_bytes(words[k])
    for i in range(n8 * 8, n):
        if touched[i]:
            m += 1
    rows = np.empty(m + 8, np.int64)  # slack for the branch-free writes
    j = 0
    for k in range(n8):
        if words[k] != 0:
            for i in range(8 * k, 8 * k + 8):
                rows[j] = i
                j += touched[i] != 0
    for i in range(n8 * 8, n):
        if touched[i]:
            rows[j] = i
            j += 1
    return rows[:m]


@njit(cache=True, parallel=True, fastmath=False)
def adam_rows(param, grads, rows, touched, exp_avg, exp_avg_sq, lr, beta1, beta2, eps, bc1, bc2):
    """Adam on the given rows, with the gradient summed over lanes; then zero those
    gradient rows and clear their ``touched`` flags. float32 arithmetic, in torch.optim.Adam's
    order: ``param -= (lr / bc1) * m / (sqrt(v) / sqrt(bc2) + eps)``.

    Args:
        param, exp_avg, exp_avg_sq: (N, C) float32; grads: (L, N, C); rows: (m,) int64
            distinct rows; touched: (N,) uint8.
        lr: (C,) per-channel learning rate; bc1, bc2: bias corrections ``1 - beta^step``.

    Returns:
        how many rows had a non-finite gradient; those rows (parameter and moments) are
        left as they were.
    """
    C = param.shape[1]
    L = grads.shape[0]
    m_rows = rows.shape[0]
    step = np.empty(C, np.float32)
    for c in range(C):
        step[c] = np.float32(lr[c] / bc1)
    b1 = np.float32(beta1)
    b2 = np.float32(beta2)
    ob1 = np.float32(1.0 - beta1)
    ob2 = np.float32(1.0 - beta2)
    inv_sqrt_bc2 = np.float32(1.0 / math.sqrt(bc2))
    eps32 = np.float32(eps)
    skipped = 0
    for j in prange(m_rows):
        if j + 8 < m_rows:  # the rows are scattered: start fetching a later one (both its ends) now
            q = rows[j + 8]
            for col in (0, C - 1):
                prefetch(param, q, col)
                prefetch(exp_avg, q, col)
                prefetch(exp_avg_sq, q, col)
                for lane in range(L):
                    prefetch(grads[lane], q, col)
        i = rows[j]
        probe = np.float32(0.0)  # NaN if any gradient of the row is not finite
        for lane in range(L):
            for c in range(C):
                probe += grads[lane, i, c] * np.float32(0.0)
        if np.isfinite(probe):  # a row with a non-finite gradient is skipped whole (and counted)
            for c in range(C):
                g = grads[0, i, c]
                for lane in range(1, L):
                    g += grads[lane, i, c]
                m = b1 * exp_avg[i, c] + ob1 * g
                v = b2 * exp_avg_sq[i, c] + ob2 * (g * g)
                exp_avg[i, c] = m
                exp_avg_sq[i, c] = v
                param[i, c] -= step[c] * m / (np.sqrt(v) * inv_sqrt_bc2 + eps32)
        else:
            skipped += 1
        for lane in range(L):
            for c in range(C):
                grads[lane, i, c] = 0.0
        touched[i] = 0
    return skipped


@njit(cache=True, parallel=True, fastmath=False)
def clear_rows(grads, rows, touched):
    """Zero the given gradient rows (of every lane) and clear their ``touched`` flags."""
    L = grads.shape[0]
    for j in prange(rows.shape[0]):
        i = rows[j]
        for lane in range(L):
            grads[lane, i, :] = 0.0
        touched[i] = 0


@njit(cache=True, parallel=True, fastmath=False)
def tv_rows(grid, vidx, voff, row_vertex, rx, ry, rz, rows, weight, grad):
    """Total variation on the given rows, added to their gradient: at row ``r`` (vertex
    ``v``), ``sum_n weight[c] * (grid[r, c] - grid[n, c])`` over the stored vertices ``n``
    next to ``v`` along x, y and z; that is, the gradient at ``r`` of
    ``0.5 * sum over neighbour pairs of weight[c] * (difference)^2``. Vertices that are not
    stored (row 0) are not neighbours.

    Args:
        grid: (M, C) float32; vidx, voff: as in :func:`render_forward`; row_vertex: (M,)
            int64 vertex of each row of a sparse grid (unused when ``voff >= 0``); rx, ry,
            rz: vertex counts; rows: (m,) int64 distinct rows; weight: (C,) float32;
            grad: (M, C) float32, one lane of the gradient (each row is written once).
    """
    C = grid.shape[1]
    sxy = rx * ry
    for j in prange(rows.shape[0]):
        r = rows[j]
        v = r - voff if voff >= 0 else row_vertex[r]
        x = v % rx
        y = (v // rx) % ry
        z = v // sxy
        for k in range(6):
            axis = k >> 1
            sign = 1 if k & 1 else -1
            coord = x if axis == 0 else (y if axis == 1 else z)
            size = rx if axis == 0 else (ry if axis == 1 else rz)
            if coord + sign < 0 or coord + sign >= size:
                continue
            stride = 1 if axis == 0 else (rx if axis == 1 else sxy)
            n = _row(vidx, v + sign * stride, voff)
            if n == 0:
                continue
            for c in range(C):
                if weight[c] != 0.0:
                    grad[r, c] += weight[c] * (grid[r, c] - grid[n, c])


@njit(cache=True, parallel=True, fastmath=False)
def grid_interp_points(grid, vidx, voff, rx, ry, rz, lo, inv_voxel, points, out):
    """Trilinear interpolation of a vertex grid at world points (``reference.grid_interp``;
    coordinates outside the box are clamped to it).

    Args:
        grid: (M, C) float32; vidx, voff: as in :func:`render_forward`; rx, ry, rz: vertex
            counts; lo: (3,) float64 box corner; inv_voxel: 1 / voxel.
        points: (m, 3) float64 world points; out: (m, C) float32 output.
    """
    C = grid.shape[1]
    sxy = rx * ry
    for i in prange(points.shape[0]):
        ix, fx = _cell((points[i, 0] - lo[0]) * inv_voxel, rx)
        iy, fy = _cell((points[i, 1] - lo[1]) * inv_voxel, ry)
        iz, fz = _cell((points[i, 2] - lo[2]) * inv_voxel, rz)
        base = (iz * ry + iy) * rx + ix
        for c in range(C):
            out[i, c] = 0.0
        for dz in range(2):
            wz = fz if dz else 1.0 - fz
            for dy in range(2):
                wy = fy if dy else 1.0 - fy
                for dx in range(2):
                    w = np.float32(wz * wy * (fx if dx else 1.0 - fx))
                    r = _row(vidx, base + dz * sxy + dy * rx + dx, voff)
                    for c in range(C):
                        out[i, c] += w * grid[r, c]


@njit(cache=True, parallel=True, fastmath=False)
def occupancy_from_grid(grid, vidx, voff, rx, ry, rz, raw_thr, occ, coarse, cf):
    """Mark the cells whose largest corner raw density exceeds ``raw_thr``.

    Trilinear interpolation never exceeds a cell's largest corner and the density
    activation is increasing, so this bounds every sample in the cell.

    Args:
        grid: (M, C) float32 (channel 0: raw density); vidx: (rx * ry * rz,) int32 row of
            each vertex, voff: as in :func:`render_forward`; rx, ry, rz: vertex counts.
        occ: (rz-1, ry-1, rx-1) uint8 output.
        coarse: (ceil((rz-1)/cf), ...) uint8 output, zero on entry: 1 where any cell of the
            block is occupied.
    """
    sxy = rx * ry
    for z in prange(rz - 1):
        for y in range(ry - 1):
            b0 = (z * ry + y) * rx
            # largest of the four x-edges' left ends, carried along x
            prev = max(
                max(grid[_row(vidx, b0, voff), 0], grid[_row(vidx, b0 + rx, voff), 0]),
                max(grid[_row(vidx, b0 + sxy, voff), 0], grid[_row(vidx, b0 + sxy + rx, voff), 0]),
            )
            for x in range(rx - 1):
                b = b0 + x + 1
                cur = max(
                    max(grid[_row(vidx, b, voff), 0], grid[_row(vidx, b + rx, voff), 0]),
                    max(grid[_row(vidx, b + sxy, voff), 0], grid[_row(vidx, b + sxy + rx, voff), 0]),
                )
                o = 1 if max(prev, cur) > raw_thr else 0
                occ[z, y, x] = o
                if o:
                    coarse[z // cf, y // cf, x // cf] = 1
                prev = cur


@njit(cache=True, fastmath=False, inline="always")
def _texel_axis(u, n):
    """One axis of ``grid_sample``'s bilinear taps (``align_corners=False``, border
    padding): (first texel, second texel, fraction, 1 if not clamped) of coordinate ``u``
    in [-1, 1] over ``n`` texels, in float32 as :func:`nerfkit.fields.background.bilinear_taps`."""
    nf = np.float32(n)
    g = ((u + np.float32(1.0)) * nf - np.float32(1.0)) / np.float32(2.0)
    inside = np.float32(1.0) if (g >= np.float32(0.0) and g <= nf - np.float32(1.0)) else np.float32(0.0)
    g = min(max(g, np.float32(0.0)), nf - np.float32(1.0))
    i = min(np.floor(g), np.float32(max(n - 2, 0)))
    i0 = int(i)
    return i0, min(i0 + 1, n - 1), g - i, inside


@njit(cache=True, parallel=True, fastmath=False)
def texture_forward(tex, uv, w, h, rows, frac, inside, out):
    """Bilinear lookup of a row-major (h * w, C) texture at (n, 2) coordinates ``uv`` in
    [-1, 1] (x: column, y: row) into ``out`` (n, C), as ``F.grid_sample(align_corners=False,
    padding_mode="border")``; records the taps for :func:`texture_backward`: ``rows`` (n, 4)
    int64 (corners 00, 01, 10, 11), ``frac`` (n, 2) and ``inside`` (n, 2) float32."""
    C = tex.shape[1]
    for i in prange(uv.shape[0]):
        x0, x1, fx, inx = _texel_axis(uv[i, 0], w)
        y0, y1, fy, iny = _texel_axis(uv[i, 1], h)
        r0, r1, r2, r3 = y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1
        rows[i, 0], rows[i, 1], rows[i, 2], rows[i, 3] = r0, r1, r2, r3
        frac[i, 0], frac[i, 1], inside[i, 0], inside[i, 1] = fx, fy, inx, iny
        w0 = (np.float32(1.0) - fx) * (np.float32(1.0) - fy)
        w1 = fx * (np.float32(1.0) - fy)
        w2 = (np.float32(1.0) - fx) * fy
        w3 = fx * fy
        for c in range(C):
            out[i, c] = w0 * tex[r0, c] + w1 * tex[r1, c] + w2 * tex[r2, c] + w3 * tex[r3, c]


@njit(cache=True, parallel=True, fastmath=False)
def texture_backward(g, tex, rows, frac, inside, w, h, grads, touched, g_uv, want_uv):
    """Gradients of :func:`texture_forward`: the texture's added into ``grads`` (L, M, C)
    (lane ``l`` takes a contiguous share of the lookups, as :func:`render_backward`; one
    lane scatters serially), its rows marked in ``touched``; with ``want_uv``, the
    coordinates' into ``g_uv`` (n, 2) (0 where a coordinate was clamped to the border),
    in parallel over the lookups."""
    L = grads.shape[0]
    n = g.shape[0]
    C = g.shape[1]
    for lane in prange(L):
        for i in range(lane * n // L, (lane + 1) * n // L):
            fx, fy = frac[i, 0], frac[i, 1]
            gx, gy = np.float32(1.0) - fx, np.float32(1.0) - fy
            r0, r1, r2, r3 = rows[i, 0], rows[i, 1], rows[i, 2], rows[i, 3]
            for c in range(C):
                gc = g[i, c]
                grads[lane, r0, c] += gx * gy * gc
                grads[lane, r1, c] += fx * gy * gc
                grads[lane, r2, c] += gx * fy * gc
                grads[lane, r3, c] += fx * fy * gc
            touched[r0] = 1
            touched[r1] = 1
            touched[r2] = 1
            touched[r3] = 1
    if not want_uv:
        return
    hw = np.float32(w) / np.float32(2.0)
    hh = np.float32(h) / np.float32(2.0)
    for i in prange(n):
        fx, fy = frac[i, 0], frac[i, 1]
        gx, gy = np.float32(1.0) - fx, np.float32(1.0) - fy
        r0, r1, r2, r3 = rows[i, 0], rows[i, 1], rows[i, 2], rows[i, 3]
        dx = np.float32(0.0)
        dy = np.float32(0.0)
        for c in range(C):
            gc = g[i, c]
            t0, t1, t2, t3 = tex[r0, c], tex[r1, c], tex[r2, c], tex[r3, c]
            dx += gc * (gy * (t1 - t0) + fy * (t3 - t2))
            dy += gc * (gx * (t2 - t0) + fx * (t3 - t1))
        g_uv[i, 0] = dx * inside[i, 0] * hw
        g_uv[i, 1] = dy * inside[i, 1] * hh


def warm_up() -> None:
    """Compile (or load from the on-disk cache) every kernel on tiny inputs."""
    C, K = 13, 4
    rx = ry = rz = 3
    grid = np.zeros((rx * ry * rz, C), np.float32)
    vidx = np.arange(rx * ry * rz, dtype=np.int32)
    voff = -1  # (one compiled version serves both: voff is an int64 either way)
    occ = np.ones((2, 2, 2), np.uint8)
    o = np.zeros((1, 3))
    d = np.array([[1.0, 0.0, 0.0]])
    sh = np.ones((1, K), np.float32)
    t0, t1, u = np.zeros(1), np.ones(1), np.full(1, 0.5)
    rgb, dep, acc, cnt = (
        np.zeros((1, 3), np.float32),
        np.zeros(1, np.float32),
        np.zeros(1, np.float32),
        np.zeros(1, np.int32),
    )
    s_idx, s_f = np.zeros((4, 1), np.int64), np.zeros((4, 1, N_FIELDS), np.float32)
    render_forward(
        grid,
        vidx,
        voff,
        rx,
        ry,
        rz,
        np.zeros(3),
        1.0,
        occ,
        occ,
        1,
        o,
        d,
        sh,
        t0,
        t1,
        u,
        0.5,
        1.0,
        1e-4,
        rgb,
        dep,
        acc,
        cnt,
        True,
        s_idx,
        s_f,
    )
    grads = np.zeros((2,) + grid.shape, np.float32)
    touched = np.zeros(rx * ry * rz, np.uint8)
    g_o, g_sh = np.zeros((1, 3)), np.zeros((1, K))
    g_dist, t_end = np.zeros(1, np.float32), np.full(1, np.inf)
    distortion_forward(s_f, cnt, 0.5, t_end, g_dist)
    render_backward(
        s_idx,
        s_f,
        cnt,
        sh,
        grid,
        vidx,
        voff,
        rx,
        ry,
        1.0,
        0.5,
        1.0,
        rgb,
        dep,
        acc,
        rgb,
        dep,
        acc,
        g_dist,
        t_end,
        0.0,
        grads,
        touched,
        True,
        g_o,
        g_o.copy(),
        g_sh,
    )
    m = np.zeros_like(grid)
    rows = touched_rows(touched)
    adam_rows(grid, grads, rows, touched, m, m.copy(), np.ones(C, np.float32), 0.9, 0.99, 1e-15, 0.1, 0.01)
    clear_rows(grads, touched_rows(touched), touched)
    occupancy_from_grid(grid, vidx, voff, rx, ry, rz, 0.0, occ, occ.copy(), 1)
    grid_interp_points(grid, vidx, voff, rx, ry, rz, np.zeros(3), 1.0, np.zeros((2, 3)), np.zeros((2, C), np.float32))
    tv_rows(
        grid,
        vidx,
        voff,
        np.arange(rx * ry * rz, dtype=np.int64),
        rx,
        ry,
        rz,
        np.arange(1, 3, dtype=np.int64),
        np.ones(C, np.float32),
        grads[0],
    )
    uv = np.zeros((2, 2), np.float32)
    taps, frac, inside, out = (
        np.zeros((2, 4), np.int64),
        np.zeros((2, 2), np.float32),
        np.zeros((2, 2), np.float32),
        np.zeros((2, C), np.float32),
    )
    texture_forward(grid, uv, 3, 9, taps, frac, inside, out)
    texture_backward(out, grid, taps, frac, inside, 3, 9, grads, touched, uv, True)
