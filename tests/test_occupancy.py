"""Empty-space skipping: the occupancy grid never drops samples that matter."""

from __future__ import annotations

import pytest
import torch

from nerfkit.estimators.occupancy import OccupancyEstimator, coarse_cells
from nerfkit.kernels import numba_kernels
from nerfkit.kernels import reference as ref
from nerfkit.kernels.ops import GridGeom, MarchSpec, cell_density_max, render_grid
from nerfkit.render.box import GridBox, ray_aabb
from nerfkit.render.occupancy import RaySamples, lattice
from nerfkit.render.volrend import composite, render_weights


def test_ray_aabb_docstring_example_and_misses():
    o = torch.tensor([[0.0, 0.0, -5.0], [0.0, 3.0, -5.0], [0.0, 0.0, 0.0]])
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    t0, t1 = ray_aabb(o, d, -torch.ones(3), torch.ones(3), 0.0, 10.0)
    assert (t0[0].item(), t1[0].item()) == pytest.approx((4.0, 6.0))
    assert t1[1] <= t0[1]  # passes beside the box
    assert (t0[2].item(), t1[2].item()) == pytest.approx((0.0, 1.0))  # starts inside: clipped at near


def test_packed_samples_select_counts_and_points():
    samples = RaySamples(torch.tensor([1.0, 2.0, 3.0, 0.5, 1.5]), torch.tensor([0, 0, 0, 2, 2]), 3, 0.25)
    assert samples.counts().tolist() == [3, 0, 2]
    kept = samples.select(torch.tensor([False, True, True, True, False]))
    assert kept.t.tolist() == [2.0, 3.0, 0.5] and kept.ray_indices.tolist() == [0, 0, 2]
    assert kept.counts().tolist() == [2, 0, 1] and kept.n_rays == 3
    o = torch.tensor([[0.0, 0.0, 0.0], [9.0, 9.0, 9.0], [1.0, 0.0, 0.0]])
    d = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    assert kept.points(o, d).tolist() == [[0.0, 0.0, 2.0], [0.0, 0.0, 3.0], [1.0, 0.5, 0.0]]


def test_lattice_is_regular_inside_the_segment():
    s = lattice(
        torch.tensor([1.0, 2.0, 3.0, 0.0]), torch.tensor([2.0, 2.1, 2.0, 0.2]), torch.tensor([0.5, 0.0, 0.5, 0.9]), 0.25
    )
    assert s.t.tolist() == pytest.approx([1.125, 1.375, 1.625, 1.875, 2.0])
    assert s.ray_indices.tolist() == [0, 0, 0, 0, 1]  # ray 2 misses (t1 < t0); ray 3's only candidate is past t1
    assert s.counts().tolist() == [4, 1, 0, 0] and s.step == 0.25


def ball_field(res=(33, 33, 33), radius=0.6):
    """Raw density of a soft ball (high inside, -40 outside) on a vertex grid over [-1, 1]^3,
    and a colour varying with position; SH degree 0."""
    geom = GridGeom(-torch.ones(3, dtype=torch.float64), 2.0 / (res[0] - 1), res)
    pos = geom.vertex_positions()
    r = pos.norm(dim=1)
    grid = torch.zeros(geom.n_vertices, 4, dtype=torch.float64)
    grid[:, 0] = torch.where(r < radius, 8.0 * (radius - r) / radius + 1.0, torch.full_like(r, -40.0))
    grid[:, 1:] = torch.stack([pos[:, 0], pos[:, 1] * 2, -pos[:, 2]], 1)
    return grid, geom


def render_reference(grid, geom, occ: OccupancyEstimator, rays_o, rays_d, step, use_occupancy, eps=0.0):
    """Render through OccupancyEstimator.sampling + the reference field with render_weights/composite."""
    lo = geom.lo

    def sigma_fn(p, _ri):
        return 5.0 * torch.nn.functional.softplus(
            ref.grid_interp(grid[:, :1], ref.grid_coords(p, lo, geom.voxel), geom.res)[:, 0]
        )

    samples = occ.sampling(
        rays_o,
        rays_d,
        0.5,
        10.0,
        step,
        sigma_fn=sigma_fn if eps > 0 else None,
        early_stop_eps=eps,
        use_occupancy=use_occupancy,
    )
    pts = samples.points(rays_o, rays_d)
    feat = ref.grid_interp(grid, ref.grid_coords(pts, lo, geom.voxel), geom.res)
    sh = ref.sh_basis(rays_d[samples.ray_indices], 0)
    sig, rgb = ref.decode(feat, sh, 5.0)
    w, _, _ = render_weights(sig, step, samples.ray_indices)
    colour, depth, acc = composite(
        w, rgb, samples.ray_indices, len(rays_o), samples.t, background=torch.tensor([0.2, 0.3, 0.4], dtype=sig.dtype)
    )
    return colour, depth, acc, samples


def camera_rays(n=24, seed=0):
    g = torch.Generator().manual_seed(seed)
    dirs = torch.randn(n * n, 3, generator=g, dtype=torch.float64)
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    o = -3.0 * dirs + 0.5 * torch.randn(n * n, 3, generator=g, dtype=torch.float64)
    return o, dirs


@pytest.mark.parametrize("alpha_thre", [1e-12, 1e-4])
def test_skipping_gives_the_same_image_and_never_drops_occupied_samples(alpha_thre):
    grid, geom = ball_field()
    step = 0.02
    occ = OccupancyEstimator(geom.box)
    occ.set_from_cell_sigma(cell_density_max(grid, geom, 5.0), step, alpha_thre)
    assert 0.05 < occ.occupied_fraction < 0.4  # most of the box is skipped
    o, d = camera_rays()
    full = render_reference(grid, geom, occ, o, d, step, use_occupancy=False)
    skip = render_reference(grid, geom, occ, o, d, step, use_occupancy=True)
    assert skip[3].n_samples < 0.5 * full[3].n_samples
    # the skipped samples are exactly the ones in unoccupied cells
    wanted = full[3].select(occ.is_occupied(full[3].points(o, d)))
    assert torch.equal(skip[3].ray_indices, wanted.ray_indices) and torch.equal(skip[3].t, wanted.t)
    # and they carried (almost) no opacity: the images agree
    torch.testing.assert_close(skip[0], full[0], atol=1e-6, rtol=0)
    torch.testing.assert_close(skip[2], full[2], atol=1e-6, rtol=0)


def test_early_termination_changes_the_image_by_less_than_eps():
    grid, geom = ball_field()
    step = 0.02
    occ = OccupancyEstimator(geom.box)
    occ.set_from_cell_sigma(cell_density_max(grid, geom, 5.0), step, 1e-12)
    o, d = camera_rays(seed=1)
    eps = 1e-3
    full = render_reference(grid, geom, occ, o, d, step, use_occupancy=True)
    early = render_reference(grid, geom, occ, o, d, step, use_occupancy=True, eps=eps)
    assert early[3].n_samples < 0.8 * full[3].n_samples
    # dropped samples sit behind transmittance < eps: colour and opacity change by less than eps
    assert (early[0] - full[0]).abs().max() < eps
    assert (early[2] - full[2]).abs().max() < eps


def test_coarse_occupancy_is_the_block_maximum():
    g = torch.Generator().manual_seed(0)
    cells = (torch.rand((5, 7, 9), generator=g) < 0.05).to(torch.uint8)  # (the kernels' uint8 cells)
    occ = OccupancyEstimator(GridBox((0, 0, 0), 1.0, (10, 8, 6)), coarse_factor=4)
    occ.set_cells(cells)
    assert occ.occ.dtype == torch.uint8 and torch.equal(occ.occ, cells)
    with pytest.raises(ValueError, match="expected"):
        OccupancyEstimator(GridBox((0, 0, 0), 1.0, (10, 8, 7))).set_cells(cells)
    c = coarse_cells(occ.occ, 4)
    assert torch.equal(occ.coarse, c.to(torch.uint8))
    assert c.shape == (2, 2, 3)
    for z in range(2):
        for y in range(2):
            for x in range(3):
                block = occ.occ[4 * z : 4 * z + 4, 4 * y : 4 * y + 4, 4 * x : 4 * x + 4]
                assert bool(c[z, y, x]) == bool(block.any())


@pytest.mark.skipif(numba_kernels() is None, reason="numba not available")
@pytest.mark.parametrize("coarse_factor", [1, 3, 8])
def test_compiled_marcher_visits_exactly_the_reference_samples(coarse_factor):
    """The fused kernel leaps over empty cells and blocks; it must keep the same samples
    as the plain lattice walk of OccupancyEstimator.sampling (no early stop: eps = 0)."""
    grid, geom = ball_field(res=(41, 29, 35), radius=0.5)
    grid = grid.float()
    step = 0.013
    occ = OccupancyEstimator(geom.box)
    occ.set_from_cell_sigma(cell_density_max(grid, geom, 5.0), step, 1e-6)
    spec = MarchSpec(
        occ.occ.to(torch.uint8),
        coarse_cells(occ.occ, coarse_factor).to(torch.uint8).contiguous(),
        coarse_factor,
        step,
        0.0,
        5.0,
    )
    o, d = camera_rays(n=30, seed=2)
    g32 = GridGeom(geom.lo.float(), geom.voxel, geom.res)
    t0, t1 = ray_aabb(o, d, geom.lo, geom.hi, 0.5, 10.0)
    u = torch.rand(len(o), generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    out = render_grid(grid, g32, spec, o.float(), d.float(), t0, t1, u, 0, None, "numba")
    samples = occ.sampling(o, d, 0.5, 10.0, step, u=u, t_bounds=(t0, t1))
    assert torch.equal(out.counts.long(), samples.counts())
    assert out.n_samples > 1000
