"""The fast grid field's operations: compiled kernels against their pure-torch references
(values and gradients), and the references against analytic facts."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from conftest import fibonacci_sphere
from nerfkit.estimators.occupancy import OccupancyEstimator, coarse_cells
from nerfkit.kernels import numba_kernels
from nerfkit.kernels import reference as ref
from nerfkit.kernels.ops import GradSink, GridGeom, MarchSpec, cell_density_max, render_grid
from nerfkit.kernels.optim import GridAdam
from nerfkit.render.box import ray_aabb

needs_numba = pytest.mark.skipif(numba_kernels() is None, reason="numba not available")


@pytest.mark.parametrize("degree", [0, 1, 2])
def test_sh_basis_is_orthonormal_on_the_sphere(degree):
    d = fibonacci_sphere(20000)
    Y = ref.sh_basis(d, degree)
    gram = 4 * math.pi * (Y.T @ Y) / len(d)  # integral of Y_i Y_j over the sphere
    torch.testing.assert_close(gram, torch.eye(ref.sh_dim(degree), dtype=torch.float64), atol=2e-3, rtol=0)


def test_sh_basis_rejects_unsupported_degree():
    with pytest.raises(ValueError):
        ref.sh_basis(torch.zeros(1, 3), 3)


def test_trilinear_reproduces_vertices_and_linear_functions():
    torch.manual_seed(0)
    res = (5, 4, 6)
    geom = GridGeom(torch.tensor([-1.0, 0.5, 2.0], dtype=torch.float64), 0.3, res)
    pos = geom.vertex_positions()
    # a linear function of position, stored at the vertices, is reproduced exactly anywhere inside
    A = torch.randn(3, 2, dtype=torch.float64)
    grid = pos @ A + 0.7
    pts = geom.lo + torch.rand(500, 3, dtype=torch.float64) * (geom.hi - geom.lo)
    got = ref.grid_interp(grid, ref.grid_coords(pts, geom.lo, geom.voxel), res)
    torch.testing.assert_close(got, pts @ A + 0.7)
    # at vertices it returns the vertex rows themselves
    rows = torch.randint(0, geom.n_vertices, (50,))
    got = ref.grid_interp(grid, ref.grid_coords(geom.vertex_positions(rows), geom.lo, geom.voxel), res)
    torch.testing.assert_close(got, grid[rows])
    _, w = ref.trilinear_corners(ref.grid_coords(pts, geom.lo, geom.voxel), res)
    torch.testing.assert_close(w.sum(1), torch.ones(500, dtype=torch.float64))


def random_field(seed: int, res=(9, 7, 8), sh_degree: int = 1):
    """A random grid (and its geometry) whose density is random inside two balls and
    zero-ish (raw -30) outside them, so that an occupancy grid skips part of the box."""
    g = torch.Generator().manual_seed(seed)
    geom = GridGeom(torch.tensor([-1.0, -0.8, -0.9]), 0.25, res)
    C = 1 + 3 * ref.sh_dim(sh_degree)
    grid = torch.randn(geom.n_vertices, C, generator=g) * 1.5
    raw = torch.randn(geom.n_vertices, generator=g) * 2 + 1
    pos = geom.vertex_positions()
    span = geom.hi - geom.lo
    c1, c2 = (geom.lo + torch.rand(3, generator=g) * span for _ in range(2))
    inside = ((pos - c1).norm(dim=1) < 0.5) | ((pos - c2).norm(dim=1) < 0.4)
    grid[:, 0] = torch.where(inside, raw, torch.full_like(raw, -30.0))
    return grid, geom


def sparse_version(grid, geom, seed: int):
    """The same field stored sparsely: vertices outside the balls share row 0 (raw -30,
    no colour), the others have rows in a shuffled order. Returns ``(rows, geom with index,
    the dense grid it stands for)``."""
    stored = grid[:, 0] > -30.0
    m = int(stored.sum())
    order = torch.randperm(m, generator=torch.Generator().manual_seed(seed))
    index = torch.zeros(geom.n_vertices, dtype=torch.int32)
    index[stored] = (order + 1).int()
    rows = torch.zeros(m + 1, grid.shape[1])
    rows[0, 0] = -30.0
    rows[order + 1] = grid[stored]
    return rows, GridGeom(geom.lo, geom.voxel, geom.res, index), rows[index.long()]


def stored_as(grid, geom, layout: str, seed: int):
    """The field in one of the kernels' storage layouts: "dense" (row = vertex, no index),
    "after_sentinel" (a dense grid behind an empty row 0, index = vertex + 1, as the fast
    model's dense stages: the kernels compute rows instead of reading the index) or
    "sparse" (:func:`sparse_version`, rows read through the index)."""
    if layout == "dense":
        return grid, geom
    if layout == "after_sentinel":
        rows = torch.cat([torch.full((1, grid.shape[1]), 0.0), grid])
        rows[0, 0] = -30.0
        index = torch.arange(1, geom.n_vertices + 1, dtype=torch.int32)
        return rows, GridGeom(geom.lo, geom.voxel, geom.res, index)
    rows, sparse, _ = sparse_version(grid, geom, seed)
    return rows, sparse


LAYOUTS = ["dense", "after_sentinel", "sparse"]


def test_row_offset_is_found_for_dense_indices_and_follows_changes_to_the_index():
    grid, geom = random_field(seed=3)
    assert stored_as(grid, geom, "dense", 0)[1].row_offset() == 0
    after = stored_as(grid, geom, "after_sentinel", 0)[1]
    assert after.row_offset() == 1
    after.index[5] = 0  # (in place: a cached answer must not survive it)
    assert after.row_offset() == -1
    assert stored_as(grid, geom, "sparse", 0)[1].row_offset() == -1


def test_sparse_interpolation_equals_the_dense_grid_it_stands_for():
    grid, geom = random_field(seed=3)
    rows, sparse, dense = sparse_version(grid, geom, seed=0)
    assert 0 < int((sparse.index == 0).sum()) < geom.n_vertices  # some vertices without storage
    pts = geom.lo + torch.rand(500, 3, generator=torch.Generator().manual_seed(1)) * (geom.hi - geom.lo)
    g = ref.grid_coords(pts, geom.lo, geom.voxel)
    torch.testing.assert_close(ref.grid_interp(rows, g, geom.res, sparse.index), ref.grid_interp(dense, g, geom.res))


def spec_for(grid, geom, step=0.1, coarse_factor=1, alpha_thre=1e-6, eps=1e-4, density_scale=1.0):
    occ = OccupancyEstimator(geom.box)
    occ.set_from_cell_sigma(cell_density_max(grid, geom, density_scale), step, alpha_thre)
    coarse = coarse_cells(occ.occ, coarse_factor).to(torch.uint8).contiguous()
    return MarchSpec(occ.occ.to(torch.uint8), coarse, coarse_factor, step, eps, density_scale), occ


def random_rays(n: int, geom: GridGeom, seed: int):
    g = torch.Generator().manual_seed(seed)
    center = 0.5 * (geom.lo + geom.hi)
    dirs = torch.randn(n, 3, generator=g)
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    o = center - 4 * dirs + 0.4 * torch.randn(n, 3, generator=g)
    t0, t1 = ray_aabb(o, dirs, geom.lo, geom.hi, 0.5, 10.0)
    u = torch.rand(n, generator=g)
    return o, dirs, t0, t1, u


def as64(geom):
    return GridGeom(geom.lo.double(), geom.voxel, geom.res, geom.index)


@needs_numba
@pytest.mark.parametrize("coarse_factor", [1, 2, 3, 4])  # (the kernel finds blocks by a shift for 2 and 4)
@pytest.mark.parametrize("sh_degree", [0, 1, 2])
@pytest.mark.parametrize("layout", LAYOUTS)
def test_compiled_render_matches_reference_values_and_gradients(coarse_factor, sh_degree, layout):
    grid, geom = random_field(seed=coarse_factor * 10 + sh_degree, sh_degree=sh_degree)
    spec, occ = spec_for(grid, geom, coarse_factor=coarse_factor)
    # the same field through a row index (the reference gathers the same way)
    grid, geom = stored_as(grid, geom, layout, seed=sh_degree)
    assert 0.05 < occ.occupied_fraction < 0.8  # the test really skips cells
    o, d, t0, t1, u = random_rays(400, geom, seed=1)

    g_fast = grid.clone().requires_grad_()
    sink = GradSink(grid.shape[0], grid.shape[1])
    fast = render_grid(g_fast, geom, spec, o, d, t0, t1, u, sh_degree, sink, "numba")
    g_ref = grid.double().requires_grad_()
    slow = render_grid(
        g_ref, as64(geom), spec, o.double(), d.double(), t0.double(), t1.double(), u.double(), sh_degree, None, "torch"
    )

    assert torch.equal(fast.counts.long(), slow.counts.long())  # the very same samples
    assert fast.n_samples > 300
    torch.testing.assert_close(fast.rgb.double(), slow.rgb, atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(fast.depth.double(), slow.depth, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(fast.acc.double(), slow.acc, atol=1e-6, rtol=1e-5)

    gen = torch.Generator().manual_seed(2)
    w_rgb, w_d, w_a = (
        torch.randn(400, 3, generator=gen),
        torch.randn(400, generator=gen),
        torch.randn(400, generator=gen),
    )
    ((fast.rgb * w_rgb).sum() + (fast.depth * w_d).sum() + (fast.acc * w_a).sum()).backward()
    ((slow.rgb * w_rgb.double()).sum() + (slow.depth * w_d.double()).sum() + (slow.acc * w_a.double()).sum()).backward()
    assert g_fast.grad is None  # the compiled path routes the gradient into the sink
    torch.testing.assert_close(sink.grad.sum(0).double(), g_ref.grad, atol=2e-5, rtol=1e-4)
    # every vertex that got a gradient is marked touched (and only corners of samples are)
    nonzero = (g_ref.grad != 0).any(1)
    assert torch.equal(sink.touched.bool() | nonzero, sink.touched.bool())


def test_near_damping_keeps_values_and_scales_gradients_by_distance_squared():
    x = torch.tensor([2.0, -1.0, 3.0, 0.5], requires_grad=True)
    t = torch.tensor([0.5, 1.0, 2.0, 4.0])
    y = ref.near_damping(x, t, 2.0)
    assert torch.equal(y, x)
    y.sum().backward()
    torch.testing.assert_close(x.grad, torch.tensor([0.0625, 0.25, 1.0, 1.0]))
    assert ref.near_damping(x, t, 0.0) is x


@needs_numba
def test_compiled_near_damping_matches_reference_and_changes_only_gradients():
    grid, geom = random_field(seed=7, sh_degree=1)
    spec, _ = spec_for(grid, geom, coarse_factor=2)
    o, d, t0, t1, u = random_rays(400, geom, seed=3)  # samples at t ~ 3 to 5
    damped = MarchSpec(
        spec.occ, spec.coarse, spec.coarse_factor, spec.step, spec.eps, spec.density_scale, grad_near=4.5
    )
    w_rgb, w_d, w_a = loss_weights(400)
    grads, outs = [], []
    for sp in (spec, damped):
        g = grid.clone().requires_grad_()
        sink = GradSink(geom.n_vertices, grid.shape[1])
        out = render_grid(g, geom, sp, o, d, t0, t1, u, 1, sink, "numba")
        ((out.rgb * w_rgb).sum() + (out.depth * w_d).sum() + (out.acc * w_a).sum()).backward()
        grads.append(sink.grad.sum(0).double())
        outs.append(out)
    g_ref = grid.double().requires_grad_()
    slow = render_grid(
        g_ref, as64(geom), damped, o.double(), d.double(), t0.double(), t1.double(), u.double(), 1, None, "torch"
    )
    ((slow.rgb * w_rgb.double()).sum() + (slow.depth * w_d.double()).sum() + (slow.acc * w_a.double()).sum()).backward()
    assert torch.equal(outs[0].rgb, outs[1].rgb) and torch.equal(outs[0].depth, outs[1].depth)
    torch.testing.assert_close(grads[1], g_ref.grad, atol=2e-5, rtol=1e-4)
    # damped where samples were near the ray origins: smaller, never larger
    assert grads[1].norm() < 0.9 * grads[0].norm()


def loss_weights(n: int, seed: int = 2):
    """Random upstream gradients for (rgb (n, 3), depth (n,), acc (n,))."""
    gen = torch.Generator().manual_seed(seed)
    return torch.randn(n, 3, generator=gen), torch.randn(n, generator=gen), torch.randn(n, generator=gen)


def render_with_ray_grads(backend, grid, geom, spec, rays, sh_degree, train_grid=False, dtype=torch.float32):
    """Render with ``rays_o``, ``rays_d`` requiring grad, backpropagate a random linear loss
    and return ``(rays_o.grad, rays_d.grad, grid gradient or None, output)``."""
    o, d, t0, t1, u = (x.to(dtype) for x in rays)
    o, d = o.clone().requires_grad_(), d.clone().requires_grad_()
    g = grid.to(dtype).clone().requires_grad_(train_grid)
    sink = GradSink(geom.n_vertices, grid.shape[1]) if train_grid and backend == "numba" else None
    geom = GridGeom(geom.lo.to(dtype), geom.voxel, geom.res)
    out = render_grid(g, geom, spec, o, d, t0, t1, u, sh_degree, sink, backend)
    w_rgb, w_d, w_a = (w.to(dtype) for w in loss_weights(o.shape[0]))
    ((out.rgb * w_rgb).sum() + (out.depth * w_d).sum() + (out.acc * w_a).sum()).backward()
    g_grid = sink.grad.sum(0) if sink is not None else g.grad
    return o.grad, d.grad, g_grid, out


@needs_numba
@pytest.mark.parametrize("coarse_factor", [1, 3])
@pytest.mark.parametrize("sh_degree", [0, 1, 2])
def test_compiled_ray_gradients_match_reference_autograd(coarse_factor, sh_degree):
    grid, geom = random_field(seed=20 + coarse_factor * 10 + sh_degree, sh_degree=sh_degree)
    spec, occ = spec_for(grid, geom, coarse_factor=coarse_factor)
    assert 0.05 < occ.occupied_fraction < 0.8
    rays = random_rays(400, geom, seed=4)
    go, gd, _, fast = render_with_ray_grads("numba", grid, geom, spec, rays, sh_degree, train_grid=True)
    ro, rd, _, slow = render_with_ray_grads("torch", grid, geom, spec, rays, sh_degree, dtype=torch.float64)
    assert torch.equal(fast.counts.long(), slow.counts.long()) and fast.n_samples > 300
    assert go.dtype == torch.float32 and gd.dtype == torch.float32  # the rays' own dtype
    # the largest entries are ~100 (o) and ~500 (d, which also carries t up to ~5)
    torch.testing.assert_close(go.double(), ro, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(gd.double(), rd, atol=5e-4, rtol=1e-4)


@needs_numba
def test_ray_gradients_leave_the_grid_gradient_bitwise_unchanged():
    grid, geom = random_field(seed=31)
    spec, _ = spec_for(grid, geom, coarse_factor=2)
    o, d, t0, t1, u = random_rays(300, geom, seed=5)
    _, _, with_rays, _ = render_with_ray_grads("numba", grid, geom, spec, (o, d, t0, t1, u), 1, train_grid=True)
    g = grid.clone().requires_grad_()
    sink = GradSink(geom.n_vertices, grid.shape[1])
    out = render_grid(g, geom, spec, o, d, t0, t1, u, 1, sink, "numba")
    w_rgb, w_d, w_a = loss_weights(300)
    ((out.rgb * w_rgb).sum() + (out.depth * w_d).sum() + (out.acc * w_a).sum()).backward()
    assert torch.equal(sink.grad.sum(0), with_rays)


@needs_numba
def test_frozen_grid_gives_ray_gradients_without_a_sink():
    grid, geom = random_field(seed=32, sh_degree=2)
    spec, _ = spec_for(grid, geom, coarse_factor=2)
    rays = random_rays(300, geom, seed=6)
    go, gd, g_grid, _ = render_with_ray_grads("numba", grid, geom, spec, rays, 2, train_grid=False)
    assert g_grid is None
    to, td, _, _ = render_with_ray_grads("numba", grid, geom, spec, rays, 2, train_grid=True)
    assert torch.equal(go, to) and torch.equal(gd, td)
    ro, rd, _, _ = render_with_ray_grads("torch", grid, geom, spec, rays, 2, dtype=torch.float64)
    torch.testing.assert_close(go.double(), ro, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(gd.double(), rd, atol=5e-4, rtol=1e-4)
    # training the grid still needs its sink
    g = grid.clone().requires_grad_()
    with pytest.raises(ValueError, match="a GradSink is needed to train the grid on the compiled path"):
        render_grid(g, geom, spec, *rays, 2, None, "numba")


@needs_numba
def test_ray_gradients_on_the_box_faces_match_reference_clamping():
    """Samples outside the box (clamped: slope 0), on its lower face (slope 1) and on its
    upper face (torch's minimum splits the slope: 1/2)."""
    geom = GridGeom(torch.tensor([-1.0, -1.0, -1.0]), 0.25, (9, 7, 8))  # exact binary coordinates
    grid = torch.randn(geom.n_vertices, 13, generator=torch.Generator().manual_seed(3))
    spec, occ = spec_for(grid, geom)
    assert occ.occupied_fraction == 1.0
    hi = geom.hi
    # along x, on the faces y = lo, y = hi, z = hi, starting 0.3 before the box and ending 0.3 after it
    o = torch.tensor([[-1.3, -1.0, 0.1], [-1.3, hi[1], 0.2], [-1.3, 0.05, hi[2]], [-1.3, hi[1], hi[2]]])
    d = torch.tensor([[1.0, 0.0, 0.0]]).expand(4, 3).contiguous()
    t0, t1 = torch.zeros(4), torch.full((4,), 2.6)
    rays = (o, d, t0, t1, torch.full((4,), 0.3))
    go, gd, _, fast = render_with_ray_grads("numba", grid, geom, spec, rays, 1)
    ro, rd, _, _ = render_with_ray_grads("torch", grid, geom, spec, rays, 1, dtype=torch.float64)
    assert fast.counts.min() == 26
    torch.testing.assert_close(go.double(), ro, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(gd.double(), rd, atol=5e-4, rtol=1e-4)


def linear_field(geom: GridGeom, sh_degree: int) -> torch.Tensor:
    """Features linear in position: trilinear interpolation reproduces them exactly, so
    the rendered colour is a smooth function of the rays (no kinks at cell faces)."""
    g = torch.Generator().manual_seed(9)
    C = 1 + 3 * ref.sh_dim(sh_degree)
    A = torch.randn(3, C, generator=g)
    grid = geom.vertex_positions() @ A + 0.5 * torch.randn(C, generator=g)
    return grid.float()


@needs_numba
@pytest.mark.parametrize("sh_degree", [0, 2])
def test_ray_origin_gradient_predicts_the_change_of_colour(sh_degree):
    geom = GridGeom(torch.tensor([-1.0, -0.8, -0.9]), 0.25, (9, 7, 8))
    grid = linear_field(geom, sh_degree)
    spec, occ = spec_for(grid, geom, eps=0.0)  # no early stop: the samples cannot change
    assert occ.occupied_fraction == 1.0
    o, d, _, _, _ = random_rays(200, geom, seed=7)
    # samples only inside a box 0.05 smaller on every side: shifted by < 0.01 they stay in the grid's box
    t0, t1 = ray_aabb(o, d, geom.lo + 0.05, geom.hi - 0.05, 0.5, 10.0)
    u = torch.full((200,), 0.5)
    w = torch.randn(200, 3, generator=torch.Generator().manual_seed(8))

    def colour(origins):
        out = render_grid(grid, geom, spec, origins, d, t0, t1, u, sh_degree, None, "numba")
        return (out.rgb.double() * w).sum(1)  # per ray

    oo = o.clone().requires_grad_()
    out = render_grid(grid, geom, spec, oo, d, t0, t1, u, sh_degree, None, "numba")
    (out.rgb * w).sum().backward()
    v = torch.randn(200, 3, generator=torch.Generator().manual_seed(9))
    h = 2e-3
    with torch.no_grad():
        fd = (colour(o + h * v) - colour(o - h * v)) / (2 * h)
    predicted = (oo.grad.double() * v.double()).sum(1)
    assert predicted.abs().max() > 0.5
    torch.testing.assert_close(fd, predicted, atol=5e-4, rtol=1e-3)  # seen: 8e-5


@needs_numba
def test_compiled_render_without_grad_matches_training_pass():
    grid, geom = random_field(seed=5)
    spec, _ = spec_for(grid, geom, coarse_factor=2)
    o, d, t0, t1, u = random_rays(300, geom, seed=3)
    with torch.no_grad():
        a = render_grid(grid, geom, spec, o, d, t0, t1, u, 1, None, "numba")
    b = render_grid(
        grid.clone().requires_grad_(), geom, spec, o, d, t0, t1, u, 1, GradSink(geom.n_vertices, grid.shape[1]), "numba"
    )
    assert torch.equal(a.counts, b.counts) and torch.equal(a.acc, b.acc.detach())
    # rendering skips the colour of samples of weight < 1e-7 (each changes a channel by < 1e-7)
    torch.testing.assert_close(a.rgb, b.rgb.detach(), atol=1e-6, rtol=0)


@needs_numba
def test_opaque_spike_takes_all_weight_and_stops_the_ray():
    res = (6, 6, 6)
    geom = GridGeom(torch.zeros(3), 1.0, res)
    grid = torch.zeros(geom.n_vertices, 13)
    grid[:, 0] = -30.0
    grid[:, 1] = 10.0  # red coefficient of SH band 0: colour ~ (1, 0.5, 0.5)
    pos = geom.vertex_positions()
    grid[pos[:, 2] >= 3, 0] = 60.0  # a huge density behind z = 3
    spec, _ = spec_for(grid, geom, step=0.25)
    o = torch.tensor([[2.5, 2.5, -1.0]])
    d = torch.tensor([[0.0, 0.0, 1.0]])
    t0, t1 = ray_aabb(o, d, geom.lo, geom.hi, 0.0, 100.0)
    out = render_grid(grid, geom, spec, o, d, t0, t1, torch.full((1,), 0.5), 1, None, "numba")
    assert out.acc.item() == pytest.approx(1.0, abs=1e-6)
    # raw density crosses 0 at z = 2.33 (world), so the ray stops between z 2.2 and 2.7 (t = z + 1)
    assert 3.2 < out.depth.item() < 3.7
    assert out.counts.item() <= 4  # skipped empty cells, and nothing after the wall is evaluated
    assert out.rgb[0, 0].item() > 0.9


@needs_numba
@pytest.mark.parametrize("layout", LAYOUTS)
def test_occupancy_kernel_matches_reference(layout):
    grid, geom = stored_as(*random_field(seed=7, res=(21, 13, 17)), layout, seed=1)
    step, dscale = 0.1, 2.0
    for alpha in (1e-3, 0.1, 0.5):
        occ = OccupancyEstimator(geom.box)
        occ.set_from_cell_sigma(cell_density_max(grid, geom, dscale), step, alpha)
        x = -math.log1p(-alpha) / (step * dscale)
        raw_thr = math.log(math.expm1(x))
        rx, ry, rz = geom.res
        got = np.zeros((rz - 1, ry - 1, rx - 1), np.uint8)
        cf = 4
        coarse = np.zeros((-(-(rz - 1) // cf), -(-(ry - 1) // cf), -(-(rx - 1) // cf)), np.uint8)
        numba_kernels().occupancy_from_grid(
            grid.numpy(), geom.vertex_index().numpy(), geom.row_offset(), rx, ry, rz, raw_thr, got, coarse, cf
        )
        assert np.array_equal(got.astype(bool), occ.occ.numpy())
        assert np.array_equal(coarse.astype(bool), coarse_cells(occ.occ, cf).numpy())


@needs_numba
@pytest.mark.parametrize("layout", LAYOUTS)
def test_resample_kernel_matches_reference_inside_and_outside_the_box(layout):
    from nerfkit.models.fast import resample_grid

    grid, geom = stored_as(*random_field(seed=5, res=(9, 12, 7)), layout, seed=2)
    g = torch.Generator().manual_seed(3)
    span = geom.hi - geom.lo
    inside = geom.lo + torch.rand(400, 3, generator=g) * span
    outside = geom.lo - 0.5 * span + torch.rand(100, 3, generator=g) * 2 * span  # partly beyond every face
    on_vertices = geom.vertex_positions(torch.arange(0, geom.n_vertices, 7))
    pts = torch.cat([inside, outside, on_vertices])
    want = resample_grid(grid, geom, pts, backend="torch")
    got = resample_grid(grid, geom, pts, backend="numba")
    torch.testing.assert_close(got, want, atol=2e-5, rtol=1e-5)
    # at a vertex, the vertex's own row
    rows = geom.vertex_index()[torch.arange(0, geom.n_vertices, 7)].long()
    torch.testing.assert_close(got[500:], grid[rows], atol=2e-5, rtol=1e-5)


def test_cell_density_max_bounds_every_point_in_the_cell():
    grid, geom = random_field(seed=8)
    smax = cell_density_max(grid, geom, 3.0)
    pts = geom.lo + torch.rand(4000, 3) * (geom.hi - geom.lo)
    feat = ref.grid_interp(grid, ref.grid_coords(pts, geom.lo, geom.voxel), geom.res)
    sigma = 3.0 * torch.nn.functional.softplus(feat[:, 0])
    c = ref.cell_of(ref.grid_coords(pts, geom.lo, geom.voxel), geom.res)
    assert (sigma <= smax[c[:, 2], c[:, 1], c[:, 0]] * (1 + 1e-5)).all()


def adam_case(seed: int, n_rows=50, C=4):
    g = torch.Generator().manual_seed(seed)
    p = torch.randn(n_rows, C, generator=g)
    grads = [torch.randn(n_rows, C, generator=g) * (torch.rand(n_rows, 1, generator=g) < 0.5) for _ in range(4)]
    return p, grads


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_grid_adam_with_every_row_touched_equals_torch_adam(backend, monkeypatch):
    if backend == "numba" and numba_kernels() is None:
        pytest.skip("numba not available")
    if backend == "torch":
        monkeypatch.setattr("nerfkit.kernels.optim.numba_kernels", lambda: None)
        monkeypatch.setattr("nerfkit.kernels.ops.numba_kernels", lambda: None)
    p0, grads = adam_case(0)
    grads = [g + 0.1 for g in grads]  # every row has a gradient
    a = torch.nn.Parameter(p0.clone())
    sink = GradSink(*p0.shape, lanes=2)
    opt = GridAdam([{"params": [a], "lr": 0.05}], sinks={a: sink}, betas=(0.9, 0.99), eps=1e-8)
    b = torch.nn.Parameter(p0.clone())
    ref_opt = torch.optim.Adam([b], lr=0.05, betas=(0.9, 0.99), eps=1e-8)
    for g in grads:
        opt.zero_grad()
        sink.grad[0] += 0.25 * g  # split over two lanes, as the compiled backward does
        sink.grad[1] += 0.75 * g
        sink.touched[:] = 1
        sink.dirty = True
        opt.step()
        ref_opt.zero_grad()
        b.grad = g.clone()
        ref_opt.step()
        torch.testing.assert_close(a.data, b.data)
    assert not sink.touched.any() and not sink.grad.any()  # consumed


@needs_numba
def test_touched_rows_lists_the_set_flags_in_order_like_flatnonzero():
    """Eight flags at a time, any non-zero byte counting as set, and lengths that are not
    a multiple of eight (a tail read one by one)."""
    rng = np.random.default_rng(0)
    for n in (0, 1, 7, 8, 9, 63, 64, 1001):
        for p in (0.0, 0.02, 0.5, 1.0):
            flags = (rng.random(n) < p).astype(np.uint8) * rng.integers(1, 256, n).astype(np.uint8)
            got = numba_kernels().touched_rows(flags)
            assert got.dtype == np.int64
            np.testing.assert_array_equal(got, np.flatnonzero(flags))


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_grid_adam_updates_only_touched_rows_with_per_channel_lr(backend, monkeypatch):
    if backend == "numba" and numba_kernels() is None:
        pytest.skip("numba not available")
    if backend == "torch":
        monkeypatch.setattr("nerfkit.kernels.optim.numba_kernels", lambda: None)
        monkeypatch.setattr("nerfkit.kernels.ops.numba_kernels", lambda: None)
    p0, grads = adam_case(1)
    a = torch.nn.Parameter(p0.clone())
    sink = GradSink(*p0.shape, lanes=1)
    scale = [1.0, 0.5, 0.5, 0.25]
    opt = GridAdam([{"params": [a], "lr": 0.1, "channel_lr_scale": scale}], sinks={a: sink})
    # reference: lazy Adam by hand, only on rows with a gradient
    p = p0.clone()
    m = torch.zeros_like(p)
    v = torch.zeros_like(p)
    lr = 0.1 * torch.tensor(scale)
    for step, g in enumerate(grads, start=1):
        rows = torch.nonzero((g != 0).any(1)).squeeze(1)
        a.grad = g.clone()  # the torch path: a dense .grad, folded into the sink
        opt.step()
        ref.adam_rows(p, g[rows], rows, m, v, lr, 0.9, 0.99, 1e-15, step)
        torch.testing.assert_close(a.data, p)
        if step == 1:  # independent of the reference: Adam's first step is lr x scale x sign(g)
            torch.testing.assert_close((a.data - p0)[rows], -(lr * torch.sign(g))[rows])
    untouched = ~torch.stack([(g != 0).any(1) for g in grads]).any(0)
    assert untouched.any()
    torch.testing.assert_close(a.data[untouched], p0[untouched], rtol=0, atol=0)


def test_grid_adam_state_dict_round_trip_resumes_identically():
    p0, grads = adam_case(2)

    def make(p):
        prm = torch.nn.Parameter(p.clone())
        sink = GradSink(*p.shape, lanes=1)
        return prm, sink, GridAdam([{"params": [prm], "lr": 0.1, "channel_lr_scale": [1, 2, 3, 4]}], sinks={prm: sink})

    def step(prm, opt, g):
        prm.grad = g.clone()
        opt.step()

    a, _, opt_a = make(p0)
    for g in grads:
        step(a, opt_a, g)
    b, _, opt_b = make(p0)
    for g in grads[:2]:
        step(b, opt_b, g)
    saved = opt_b.state_dict()
    c, _, opt_c = make(b.data)
    opt_c.load_state_dict(saved)
    for g in grads[2:]:
        step(c, opt_c, g)
    torch.testing.assert_close(c.data, a.data)


def distortion_brute_force(w, t, interval, t_end=None):
    """mip-NeRF 360's distortion, summed over every pair (float64), with the leftover
    weight as one more sample at ``t_end`` where that is finite."""
    out = []
    for r in range(w.shape[0]):
        ws, ts = list(w[r].tolist()), list(t[r].tolist())
        own = sum(x * x * interval for x in ws) / 3.0
        if t_end is not None and math.isfinite(float(t_end[r])):
            ws.append(1.0 - sum(w[r].tolist()))
            ts.append(float(t_end[r]))
        out.append(sum(a * b * abs(ta - tb) for a, ta in zip(ws, ts) for b, tb in zip(ws, ts)) + own)
    return torch.tensor(out, dtype=torch.float64)


def test_distortion_matches_all_pairs_and_the_worked_examples():
    from nerfkit.render.volrend import distortion, regular_ray_indices, render_weights

    def dist(w, t, interval, ends=None):  # (n_rays, n_samples) in, as distortion_brute_force takes
        rays = regular_ray_indices(*w.shape)
        return distortion(w.reshape(-1), t.reshape(-1), interval, rays, w.shape[0], ends)

    gen = torch.Generator().manual_seed(5)
    sig = torch.rand(6, 9, generator=gen, dtype=torch.float64) * 3
    t = torch.cumsum(torch.full((6, 9), 0.2, dtype=torch.float64), 1) + torch.rand(6, 1, generator=gen)
    w = render_weights(sig.reshape(-1), torch.tensor(0.2, dtype=torch.float64), regular_ray_indices(6, 9))[0].view(6, 9)
    ends = torch.tensor([3.0, math.inf, 2.5, 4.0, math.inf, 3.3], dtype=torch.float64)
    torch.testing.assert_close(dist(w, t, 0.2), distortion_brute_force(w, t, 0.2))
    torch.testing.assert_close(dist(w, t, 0.2, ends), distortion_brute_force(w, t, 0.2, ends))
    # all weight in one sample: only its own interval term; half of it 2 further on a surface
    one = torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64)
    tt = torch.tensor([[0.5, 1.5, 2.5]], dtype=torch.float64)
    assert float(dist(one, tt, 1.0)) == pytest.approx(1 / 3)
    half = one * 0.5
    assert float(dist(half, tt, 1.0, torch.tensor([3.5], dtype=torch.float64))) == pytest.approx(
        2 * 0.5 * 0.5 * 2 + 0.25 / 3
    )
    # haze spread in front of a surface costs more than the same weight next to it
    near = torch.tensor([[0.0, 0.0, 0.3]], dtype=torch.float64)
    far = torch.tensor([[0.3, 0.0, 0.0]], dtype=torch.float64)
    end = torch.tensor([2.6], dtype=torch.float64)
    assert float(dist(far, tt, 1.0, end)) > 5 * float(dist(near, tt, 1.0, end))


@needs_numba
@pytest.mark.parametrize("sh_degree", [0, 2])
def test_compiled_distortion_matches_reference_values_and_gradients(sh_degree):
    """The distortion loss (with a surface behind some rays) through the compiled
    forward/backward against autograd on the torch reference, grid and ray gradients."""
    grid, geom = random_field(seed=70 + sh_degree, sh_degree=sh_degree)
    spec, _ = spec_for(grid, geom)
    o, d, t0, t1, u = random_rays(300, geom, seed=3)
    t_end = torch.where(torch.arange(300) % 3 == 0, torch.full_like(t1, math.inf), t1 + 0.3)
    outs, grads = [], []
    for backend, dt in (("numba", torch.float32), ("torch", torch.float64)):
        g = grid.to(dt).clone().requires_grad_()
        oo, dd = o.to(dt).clone().requires_grad_(), d.to(dt).clone().requires_grad_()
        sink = GradSink(geom.n_vertices, grid.shape[1]) if backend == "numba" else None
        gm = GridGeom(geom.lo.to(dt), geom.voxel, geom.res)
        out = render_grid(
            g,
            gm,
            spec,
            oo,
            dd,
            t0.to(dt),
            t1.to(dt),
            u.to(dt),
            sh_degree,
            sink,
            backend,
            t_end=t_end.to(dt),
            distortion=True,
        )
        w_rgb, _, w_a = (w.to(dt) for w in loss_weights(300))
        loss = 3.0 * out.distortion.sum()  # alone at degree 0, so that its gradient is checked by itself
        if sh_degree:
            loss = loss + (out.rgb * w_rgb).sum() + (out.acc * w_a).sum()
        loss.backward()
        outs.append(out)
        grads.append((sink.grad.sum(0) if sink is not None else g.grad, oo.grad, dd.grad))
    fast, slow = outs
    assert torch.equal(fast.counts.long(), slow.counts.long())
    assert float(slow.distortion.detach().abs().max()) > 1e-3  # the loss is not trivially zero
    torch.testing.assert_close(fast.distortion.double(), slow.distortion, atol=1e-6, rtol=1e-4)
    for got, want in zip(grads[0], grads[1]):
        torch.testing.assert_close(got.double(), want, atol=5e-5, rtol=2e-4)


def test_total_variation_gradient_of_a_row_of_three_vertices():
    """Values 0, 1, 3 along x: energy 0.5 * (1 + 4); gradient (0 - 1, (1 - 0) + (1 - 3), 3 - 1)."""
    grid = torch.tensor([[-30.0], [0.0], [1.0], [3.0]])  # row 0: the empty row
    index = torch.tensor([1, 2, 3], dtype=torch.int32)
    g = ref.tv_grad(grid, index, (3, 1, 1), torch.tensor([2.0]))
    torch.testing.assert_close(g, 2.0 * torch.tensor([[0.0], [-1.0], [-1.0], [2.0]]))


def test_total_variation_gradient_in_3d_matches_finite_differences_of_a_loop_energy():
    """On a 4x3x2 grid with two vertices not stored: the reference gradient equals central
    differences of the energy summed pair by pair in plain loops (x, y and z neighbours)."""
    rx, ry, rz = 4, 3, 2
    index = torch.arange(1, rx * ry * rz + 1, dtype=torch.int32)
    index[[5, 17]] = 0  # not stored: no pair with them counts
    g = torch.Generator().manual_seed(4)
    grid = torch.randn(rx * ry * rz + 1, 2, generator=g, dtype=torch.float64)
    weight = torch.tensor([2.0, 0.5], dtype=torch.float64)

    def energy(values: np.ndarray) -> float:
        e = 0.0
        for z in range(rz):
            for y in range(ry):
                for x in range(rx):
                    a = int(index[(z * ry + y) * rx + x])
                    for dx, dy, dz in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):
                        if x + dx < rx and y + dy < ry and z + dz < rz:
                            b = int(index[((z + dz) * ry + y + dy) * rx + x + dx])
                            if a and b:
                                e += 0.5 * float((weight.numpy() * (values[a] - values[b]) ** 2).sum())
        return e

    base, h = grid.numpy(), 1e-6
    numeric = np.zeros_like(base)
    for r in range(base.shape[0]):
        for c in range(base.shape[1]):
            up, down = base.copy(), base.copy()
            up[r, c] += h
            down[r, c] -= h
            numeric[r, c] = (energy(up) - energy(down)) / (2 * h)
    got = ref.tv_grad(grid, index, (rx, ry, rz), weight)
    assert np.abs(numeric).max() > 1.0  # a gradient worth checking
    np.testing.assert_allclose(got.numpy(), numeric, atol=1e-6)
    assert torch.all(got[[0, 6, 18]] == 0)  # the empty row and the vertices not stored


@pytest.mark.parametrize("backend", ["numba", "torch"])
@pytest.mark.parametrize("layout", ["after_sentinel", "sparse"])
def test_total_variation_goes_to_the_touched_rows_only_and_matches_the_reference(backend, layout):
    """The compiled pass and the torch path add the reference gradient (autograd of the
    energy) on the rows the rays touched, and nothing elsewhere."""
    if backend == "numba" and numba_kernels() is None:
        pytest.skip("numba not available")
    from nerfkit.kernels.ops import add_grid_tv

    grid, geom = stored_as(*random_field(seed=3, res=(9, 7, 8)), layout, seed=2)
    weight = torch.tensor([0.5] + [0.05] * (grid.shape[1] - 1))
    g = torch.Generator().manual_seed(0)
    touched = torch.rand(grid.shape[0], generator=g) < 0.3
    touched[0] = True  # the empty row is never regularised
    photo = torch.randn(grid.shape, generator=g) * touched.unsqueeze(1)
    expect = ref.tv_grad(grid, geom.vertex_index(), geom.res, weight)
    sink = GradSink(grid.shape[0], grid.shape[1], lanes=2)
    if backend == "numba":
        sink.grad[1] = photo
        sink.touched[:] = touched.to(torch.uint8)
        param = grid
    else:
        param = grid.clone().requires_grad_(True)
        param.grad = photo.clone()
    n = add_grid_tv(param, geom, weight, sink, backend)
    total = sink.grad.sum(0) if backend == "numba" else param.grad
    rows = touched.clone()
    rows[0] = False
    assert n == int(rows.sum())
    torch.testing.assert_close(total[rows], photo[rows] + expect[rows], rtol=1e-5, atol=1e-5)
    assert torch.equal(total[~rows], photo[~rows])
    assert torch.all(expect[0] == 0)  # the empty row is nobody's neighbour


def test_kernels_numba_refused_says_why(monkeypatch):
    from nerfkit import kernels

    monkeypatch.setitem(kernels._STATE, "error", "disabled by NERFKIT_NO_NUMBA")
    assert "disabled by NERFKIT_NO_NUMBA. Unset it" in str(kernels.numba_refused())
    monkeypatch.setitem(kernels._SPLAT, "error", "ImportError: No module named 'numba'")
    said = str(kernels.numba_refused(splat=True))
    assert "not available (ImportError: No module named 'numba')" in said and "pip install" in said
