"""The table plane and the room behind a real capture's object."""

import math

import numpy as np
import torch

from nerfkit.fields.background import TablePlane, contract_disc, plane_hit, sh16


def test_plane_hit_distances_front_side_only():
    plane = torch.tensor([0.0, 0.0, 1.0, 0.0])
    o = torch.tensor([[0.0, 0.0, 2.0], [1.0, 1.0, 3.0], [0.0, 0.0, 2.0], [0.0, 0.0, -1.0]])
    d = torch.tensor([[0.0, 0.0, -1.0], [0.6, 0.0, -0.8], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
    t = plane_hit(o, d, plane)
    assert torch.allclose(t[:2], torch.tensor([2.0, 3.75]))
    assert math.isinf(t[2]) and math.isinf(t[3])  # parallel; below the table
    p = o[1] + t[1] * d[1]
    assert abs(float(p[2])) < 1e-6


def test_contraction_keeps_the_unit_disc_and_squeezes_the_rest_below_radius_two():
    q = torch.tensor([[0.3, -0.4], [3.0, 4.0], [1e6, 0.0]])
    c = contract_disc(q)
    assert torch.allclose(c[0], q[0])
    assert torch.allclose(c[1], torch.tensor([0.6, 0.8]) * (2 - 1 / 5.0))
    assert float(c.norm(dim=1).max()) < 2.0
    r = torch.linspace(0.1, 50, 200)
    cr = contract_disc(torch.stack([r, torch.zeros_like(r)], 1))[:, 0]
    assert bool((cr[1:] > cr[:-1]).all())  # monotonic: near texels never overlap far ones


def test_table_texture_is_sampled_where_rays_hit_and_frames_are_orthonormal():
    table = TablePlane(torch.tensor([0.0, 0.0, 2.0, 0.0]), torch.tensor([0.5, 0.0, 1.0]), radius=1.0, resolution=64)
    axes = torch.cat([table.axes, table.plane[:3, None]], 1)
    assert torch.allclose(axes.t() @ axes, torch.eye(3), atol=1e-6)
    assert torch.allclose(table.origin, torch.tensor([0.5, 0.0, 0.0]))
    with torch.no_grad():  # left half of the texture red, right half blue
        tex = table.fine.view(64, 64, 3)
        tex.zero_()
        tex[:, :32, 0] = 4.0
        tex[:, 32:, 2] = 4.0
    e1 = table.axes[:, 0]
    x = torch.stack([table.origin - 0.5 * e1, table.origin + 0.5 * e1])  # texel columns grow along e1
    col = table.colour(x)
    assert col[0, 0] > 0.95 and col[0, 2] < 0.55
    assert col[1, 2] > 0.95 and col[1, 0] < 0.55


def test_sh16_is_a_basis_of_sixteen_independent_functions():
    g = torch.Generator().manual_seed(0)
    d = torch.randn(500, 3, generator=g)
    d = d / d.norm(dim=1, keepdim=True)
    B = sh16(d)
    assert B.shape == (500, 16)
    assert int(torch.linalg.matrix_rank(B.double())) == 16
    assert np.isclose(float(B[:, 0].min()), 1.0)


def test_sparse_texture_lookup_matches_grid_sample_in_values_and_gradients():
    from nerfkit.fields.background import sample_texture
    from nerfkit.kernels.ops import GradSink

    g = torch.Generator().manual_seed(0)
    side = 9
    tex = torch.randn(side * side, 3, generator=g, dtype=torch.float64, requires_grad=True)
    uv = (torch.rand(200, 2, generator=g, dtype=torch.float64) * 2.4 - 1.2).requires_grad_(True)  # some clamped
    w = torch.randn(200, 3, generator=g, dtype=torch.float64)
    ref = sample_texture(tex, side, uv)  # grid_sample
    (ref * w).sum().backward()
    ref_tex, ref_uv = tex.grad.clone(), uv.grad.clone()
    tex.grad, uv.grad = None, None
    sink = GradSink(side * side, 3, lanes=1)
    sink.grad = sink.grad.double()
    out = sample_texture(tex, side, uv, sink)
    (out * w).sum().backward()
    torch.testing.assert_close(out, ref)
    assert tex.grad is None  # the texture gradient went to the sink only
    torch.testing.assert_close(sink.grad[0], ref_tex)
    torch.testing.assert_close(uv.grad, ref_uv)
    assert torch.equal(sink.touched.bool(), (ref_tex != 0).any(1))


def test_table_coverage_shows_the_room_where_the_table_ends():
    """Rays that hit the plane see ``cover * table + (1 - cover) * room``: opaque at
    first, the room where the coverage texture has learned the table is not there."""
    from nerfkit.data.synthetic import tabletop_scene
    from nerfkit.models import SceneBounds
    from nerfkit.models.fast import FastConfig, FastNeRF

    scene = tabletop_scene(n_train=2, n_val=0, size=16)
    model = FastNeRF(FastConfig(resolutions="8", upsample_steps="", table=True, table_resolution=32,
                                learn_background=True), SceneBounds.from_scene(scene))
    with torch.no_grad():
        model.table.fine.fill_(2.0)  # table colour sigmoid(2)
        model.bg_coef.zero_()
        model.bg_coef[:, 0] = -1.0  # room colour sigmoid(-1)
    o = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    d = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])  # down onto the table; up, into the room
    t = model.table.hit(o, d)
    table, room = torch.sigmoid(torch.tensor(2.0)), torch.sigmoid(torch.tensor(-1.0))
    cover0 = torch.sigmoid(torch.tensor(4.0))
    out = model._background(o, d, t, None)
    torch.testing.assert_close(out[0], (cover0 * table + (1 - cover0) * room).expand(3))
    torch.testing.assert_close(out[1], room.expand(3))
    with torch.no_grad():
        model.table.cover.fill_(-30.0)  # no table anywhere
    torch.testing.assert_close(model._background(o, d, t, None)[0], room.expand(3), atol=1e-6, rtol=0)
