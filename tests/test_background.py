"""The table plane and the room behind a real capture's object."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from conftest import fibonacci_sphere
from nerfkit.cameras import plane_hit
from nerfkit.fields.background import contract_disc, sh16, sphere_exit
from nerfkit.render.layers import composite_layers, layers_depth
from nerfkit.surroundings.room import RoomShells
from nerfkit.surroundings.table import TablePlane, table_doubt


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


def test_sh16_are_orthogonal_spherical_harmonics_with_their_hand_computed_norms():
    # the mean of f_i f_j over the sphere: zero off the diagonal (the real SH of degrees 0..3
    # are orthogonal, within and across degrees), and on it the mean of each f^2 from the
    # sphere's moments E[x^2a y^2b z^2c] = (2a-1)!! (2b-1)!! (2c-1)!! / (2(a+b+c)+1)!!,
    # e.g. E[(3z^2 - 1)^2] = 9/5 - 2 + 1 = 4/5, E[x^2 (x^2 - 3y^2)^2] = (15 - 18 + 27)/105
    d = fibonacci_sphere(20000)
    B = sh16(d)
    assert B.shape == (20000, 16)
    gram = B.T @ B / len(d)
    norms = [1, 1 / 3, 1 / 3, 1 / 3, 1 / 15, 1 / 15, 1 / 15, 4 / 15, 4 / 5]  # degrees 0, 1, 2
    norms += [8 / 35, 8 / 35, 4 / 105, 1 / 105, 8 / 21, 8 / 21, 4 / 7]  # degree 3
    torch.testing.assert_close(gram, torch.diag(torch.tensor(norms, dtype=torch.float64)), atol=1e-4, rtol=0)


@pytest.mark.parametrize("side", [9, (12, 5)])
@pytest.mark.parametrize("compiled", [False, True], ids=["torch", "numba"])
def test_sparse_texture_lookup_matches_grid_sample_in_values_and_gradients(side, compiled):
    """The sparse lookup (torch in float64; the compiled kernels in float32 with two
    gradient lanes) against ``F.grid_sample`` and its autograd."""
    from nerfkit.fields.background import _compiled, sample_texture
    from nerfkit.kernels.ops import GradSink

    dtype = torch.float32 if compiled else torch.float64
    g = torch.Generator().manual_seed(0)
    n_texels = side * side if isinstance(side, int) else side[0] * side[1]
    tex = torch.randn(n_texels, 3, generator=g, dtype=dtype, requires_grad=True)
    uv = (torch.rand(200, 2, generator=g, dtype=dtype) * 2.4 - 1.2).requires_grad_(True)  # some clamped
    w = torch.randn(200, 3, generator=g, dtype=dtype)
    ref = sample_texture(tex, side, uv)  # grid_sample
    (ref * w).sum().backward()
    ref_tex, ref_uv = tex.grad.clone(), uv.grad.clone()
    tex.grad, uv.grad = None, None
    sink = GradSink(n_texels, 3, lanes=2 if compiled else 1)
    if compiled:
        if _compiled(tex.detach(), sink) is None:
            pytest.skip("numba is not available")
    else:
        sink.grad = sink.grad.double()
    out = sample_texture(tex, side, uv, sink)
    (out * w).sum().backward()
    tol = {"atol": 1e-5, "rtol": 1e-5} if compiled else {}
    torch.testing.assert_close(out, ref, **tol)
    assert tex.grad is None  # the texture gradient went to the sink only
    torch.testing.assert_close(sink.grad.sum(0), ref_tex, **tol)
    if compiled:
        assert (sink.grad[0] != 0).any() and (sink.grad[1] != 0).any()  # both lanes took a share
    torch.testing.assert_close(uv.grad, ref_uv, **tol)
    assert torch.equal(sink.touched.bool(), (ref_tex != 0).any(1))


def test_a_torch_model_looks_up_its_textures_in_torch(monkeypatch):
    """``--kernels torch`` holds for the table and room textures too: with ``compiled``
    off the lookup never asks for the compiled kernels, and gives the same values."""
    import nerfkit.fields.background as background
    from nerfkit.kernels.ops import GradSink

    g = torch.Generator().manual_seed(1)
    tex = torch.randn(64, 3, generator=g, requires_grad=True)
    uv = torch.rand(50, 2, generator=g) * 2 - 1
    ref = background.sample_texture(tex, 8, uv)

    def refuse(*_):
        raise AssertionError("the compiled kernels were asked for")

    monkeypatch.setattr(background, "_compiled", refuse)
    sink = GradSink(64, 3, lanes=1)
    out = background.sample_texture(tex, 8, uv, sink, compiled=False)
    out.sum().backward()
    torch.testing.assert_close(out, ref)
    assert sink.dirty and sink.touched.any()


def behind(model, o, d, t_stop):
    """What the model's surroundings draw behind an empty volume along rays ``o``, ``d``."""
    s = model.surroundings
    return s.behind(o, d, t_stop, None, torch.ones(len(o)), model.field.backend() == "numba")


def test_table_coverage_shows_the_room_where_the_table_ends():
    """Rays that hit the plane see ``cover * table + (1 - cover) * room``: opaque at
    first, the room where the coverage texture has learned the table is not there."""
    from nerfkit.data.synthetic import tabletop_scene
    from nerfkit.models import SceneBounds
    from nerfkit.models.fast import FastConfig, FastNeRF

    scene = tabletop_scene(n_train=2, n_val=0, size=16)
    model = FastNeRF(
        FastConfig(
            resolutions="8",
            upsample_steps="",
            table=True,
            table_resolution=32,
            learn_background=True,
            room_shells=2,
            room_resolution=16,
            table_cover_weight=0.05,
        ),
        SceneBounds.from_scene(scene),
    )
    with torch.no_grad():
        model.surroundings.table.fine.fill_(2.0)  # table colour sigmoid(2)
        model.surroundings.room.fine[:, 3] = -30.0  # room shells transparent
        model.surroundings.bg_coef.zero_()
        model.surroundings.bg_coef[:, 0] = -1.0  # room colour sigmoid(-1)
    o = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    d = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])  # down onto the table; up, into the room
    t = model.surroundings.table.hit(o, d)
    table, room = torch.sigmoid(torch.tensor(2.0)), torch.sigmoid(torch.tensor(-1.0))
    cover0 = torch.sigmoid(torch.tensor(4.0))
    out, _, extras = behind(model, o, d, t)
    torch.testing.assert_close(out[0], (cover0 * table + (1 - cover0) * room).expand(3))
    torch.testing.assert_close(out[1], room.expand(3))
    clear = torch.stack([1 - cover0, torch.tensor(0.0)])  # the up ray meets no table
    torch.testing.assert_close(extras["table_doubt"], table_doubt(clear))
    model.config.table_cover_weight = 0.0
    assert behind(model, o, d, t)[2] == {}  # not asked for: the cover prior is off
    model.config.table_cover_weight = 0.05
    with torch.no_grad():
        model.surroundings.table.cover.fill_(-30.0)  # no table anywhere
    torch.testing.assert_close(behind(model, o, d, t)[0][0], room.expand(3), atol=1e-6, rtol=0)
    with torch.no_grad():  # an opaque first room shell hides the colour per direction, not the table
        model.surroundings.table.cover.fill_(30.0)
        model.surroundings.room.fine[:, :3] = 1.0
        model.surroundings.room.fine[:, 3] = 30.0
    out, depth, _ = behind(model, o, d, t)
    torch.testing.assert_close(out[0], table.expand(3))
    torch.testing.assert_close(out[1], torch.sigmoid(torch.tensor(1.0)).expand(3))
    assert depth is None  # only rendering out of training asks for the layers' depth
    model.eval()
    depth, met = behind(model, o, d, t)[1]
    first_shell = sphere_exit(o[1:], d[1:], model.surroundings.room.center, model.surroundings.room.radii[:1])[0, 0]
    torch.testing.assert_close(depth, torch.stack([t[0], first_shell]))  # the table, then the room
    torch.testing.assert_close(met, torch.ones(2))
    with torch.no_grad():  # a see-through table is still where the ray meets a surface
        model.surroundings.table.cover.fill_(1.0)  # coverage 0.73
    torch.testing.assert_close(behind(model, o, d, t)[1][0], torch.stack([t[0], first_shell]))


def test_the_room_behind_the_volume_is_composited_in_float32_under_bf16_autocast():
    """Training and rendering run under autocast; the learned colour per direction and the
    layers in front of it (table, floor, room shells) must not be rounded to bf16."""
    from nerfkit.data.synthetic import tabletop_scene
    from nerfkit.models import SceneBounds
    from nerfkit.models.fast import FastConfig, FastNeRF

    scene = tabletop_scene(n_train=2, n_val=0, size=16)
    config = FastConfig(
        resolutions="8", upsample_steps="", table=True, table_resolution=32, learn_background=True, room_shells=2
    )
    model = FastNeRF(config, SceneBounds.from_scene(scene))
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        model.surroundings.bg_coef.copy_(torch.randn(model.surroundings.bg_coef.shape, generator=g))
    o = torch.zeros(32, 3) + torch.tensor([0.0, 0.0, 1.0])
    d = torch.nn.functional.normalize(torch.randn(32, 3, generator=g), dim=-1)
    t = model.surroundings.table.hit(o, d)
    plain = behind(model, o, d, t)[0].detach()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        far = model.surroundings.far(d, None)
        under = behind(model, o, d, t)[0].detach()
    assert far.dtype == torch.float32 and under.dtype == torch.float32
    torch.testing.assert_close(under, plain, atol=1e-6, rtol=0)


def test_table_doubt_is_zero_where_the_table_is_there_or_not_and_one_at_half():
    c = torch.tensor([0.0, 0.25, 0.5, 0.75, 1.0])
    torch.testing.assert_close(table_doubt(c), torch.tensor([0.0, 0.75, 1.0, 0.75, 0.0]))


def tiny_table_model(**options):
    """(bounds, FastConfig) of a fast model of a tiny table-top scene: an 8^3 grid, a 32-texel
    table and a learned background, with ``options`` changed."""
    from nerfkit.data.synthetic import tabletop_scene
    from nerfkit.models import SceneBounds
    from nerfkit.models.fast import FastConfig

    bounds = SceneBounds.from_scene(tabletop_scene(n_train=2, n_val=0, size=16))
    config = FastConfig(resolutions="8", upsample_steps="", table=True, table_resolution=32, learn_background=True)
    return bounds, replace(config, **options)


def test_the_table_cover_prior_costs_in_the_loss_from_its_start():
    """``--table-cover-weight`` adds its weight times the mean, over the rays, of the doubt
    about the table (:func:`table_doubt` of the light it lets through) where the light
    reaches it, once the schedule has switched it on; its gradient pushes a mostly opaque
    spot toward opaque and a mostly clear one toward clear."""
    from dataclasses import replace

    from nerfkit.cameras import Rays
    from nerfkit.models.base import StepState
    from nerfkit.models.fast import EMPTY_RAW, FastNeRF

    bounds, config = tiny_table_model(room_shells=0, opacity_weight=0.0, distortion_weight=0.0, table_cover_start=0.5)
    weight = 0.5
    plain, model = (FastNeRF(replace(config, table_cover_weight=w), bounds) for w in (0.0, weight))
    off = plain.render_rays(Rays(torch.zeros(1, 3), torch.ones(1, 3)), torch.zeros(3), perturb=False)
    assert "table_doubt" not in off.extras  # weight 0: nothing is computed
    (switch,) = [s for s in model.schedules() if s.name == "table cover prior"]
    for m in (plain, model):
        with torch.no_grad():
            m.field.grid[:, 0] = EMPTY_RAW  # an empty box: all light reaches the table
        m.train()
    o = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    d = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])  # onto the table; away from it
    target = torch.full((2, 3), 0.5)
    for cover_logit, sign in ((1.0, -1), (-1.0, 1)):  # mostly opaque: pushed up; mostly clear: down
        for m in (plain, model):
            with torch.no_grad():
                m.surroundings.table.cover.fill_(cover_logit)
        outs = [m.render_rays(Rays(o, d), torch.zeros(3), perturb=False) for m in (plain, model)]
        doubt = outs[1].extras["table_doubt"]
        clear = 1 - torch.sigmoid(torch.tensor(cover_logit))
        through = 1 - outs[1].acc.detach()
        torch.testing.assert_close(doubt, torch.stack([through[0] * 4 * clear * (1 - clear), torch.tensor(0.0)]))
        for progress, on in ((0.4, False), (0.6, True)):
            switch.run(StepState(step=0, progress=progress, optimizer=None))
            assert model.surroundings.cover_prior_on is on
            gap = model.loss(outs[1], target) - plain.loss(outs[0], target)
            torch.testing.assert_close(gap, weight * doubt.mean() if on else torch.tensor(0.0))
        sink = model.surroundings.texture_sinks[model.surroundings.table.cover]
        sink.grad.zero_()
        (weight * doubt.mean()).backward()
        assert sink.dirty and sign * float(sink.grad.sum()) > 0  # descent moves the cover logit by -sign


def test_sphere_exit_is_the_far_root_and_misses_are_infinite():
    c = torch.tensor([1.0, 0.0, 0.0])
    radii = torch.tensor([1.0, 2.0])
    o = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.5, 0.0], [5.0, 0.0, 0.0], [5.0, 3.0, 0.0], [5.0, 0.0, 0.0]])
    d = torch.tensor([[0.0, 0.0, 2.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    t = sphere_exit(o, d, c, radii)
    torch.testing.assert_close(t[0], torch.tensor([0.5, 1.0]))  # from the centre, |d| = 2
    torch.testing.assert_close(t[1], torch.tensor([math.sqrt(0.75), math.sqrt(3.75)]))
    torch.testing.assert_close(t[2], torch.tensor([5.0, 6.0]))  # from outside: where it leaves
    assert math.isinf(t[3, 0]) and math.isinf(t[3, 1])  # passes beside both spheres
    assert bool(torch.isinf(t[4]).all())  # heading away: both spheres are behind it
    p = o[1] + t[1, 1] * d[1]
    assert abs(float((p - c).norm()) - 2.0) < 1e-6


def test_layers_are_composited_nearest_first_whatever_their_order():
    g = torch.Generator().manual_seed(1)
    t = torch.tensor([[3.0, 1.0, math.inf], [0.5, 2.0, 1.0]])
    rgb = torch.rand(2, 3, 3, generator=g)
    alpha = torch.tensor([[0.5, 0.25, 0.0], [0.2, 0.9, 0.4]])
    behind = torch.rand(2, 3, generator=g)
    out = composite_layers(t, rgb, alpha, behind)
    # ray 0: layer 1 (t=1) then layer 0 (t=3); the missing layer changes nothing
    want0 = 0.25 * rgb[0, 1] + 0.75 * 0.5 * rgb[0, 0] + 0.75 * 0.5 * behind[0]
    torch.testing.assert_close(out[0], want0)
    perm = torch.tensor([2, 0, 1])
    torch.testing.assert_close(composite_layers(t[:, perm], rgb[:, perm], alpha[:, perm], behind), out)
    opaque = composite_layers(t, rgb, torch.ones_like(alpha), behind)
    torch.testing.assert_close(opaque[1], rgb[1, 0])  # the nearest opaque layer hides the rest


def test_layers_depth_is_the_surface_after_which_less_than_half_the_light_is_left():
    inf = math.inf
    t = torch.tensor([[1.0, 5.0], [3.0, 1.0], [inf, 2.0], [4.0, inf], [1.0, 2.0], [inf, inf]])
    alpha = torch.tensor([[0.7, 0.3], [0.9, 0.25], [0.0, 0.6], [0.2, 0.0], [0.3, 0.3], [0.0, 0.0]])
    depth, met = layers_depth(t, alpha)
    # 0: a see-through table (0.7) is met at its distance, not mixed with the room's (5)
    # 1: unsorted layers: 0.75 of the light left after t=1, 0.075 after t=3
    # 2: the missing layer (inf) counts for nothing
    # 3: 0.8 left after every layer: nothing met
    # 4: 0.7 left after t=1, 0.49 after t=2
    # 5: a ray that meets no layer
    torch.testing.assert_close(met, torch.tensor([1.0, 1.0, 1.0, 0.0, 1.0, 0.0]))
    torch.testing.assert_close(depth, torch.tensor([1.0, 3.0, 2.0, 0.0, 2.0, 0.0]))


def test_room_shells_show_the_texel_a_ray_meets_with_parallax():
    """A mark painted on the second shell is seen along the ray through it: straight out
    from the centre, and from an off-centre camera along a different direction."""
    room = RoomShells(center=torch.zeros(3), up=torch.tensor([0.0, 0.0, 1.0]), r0=1.0, n_shells=2, ratio=2.0, width=64)
    w, h = room.sizes[0]
    e1 = room.frame[:, 0]
    with torch.no_grad():
        room.fine[:, 3] = -30.0  # every shell transparent ...
        fine = room.fine.view(2, h, w, 4)
        fine[1, h // 2 - 1 : h // 2 + 1, w // 2 - 1 : w // 2 + 1] = torch.tensor(
            [30.0, -30.0, -30.0, 30.0]
        )  # ... but a red
        # opaque mark on shell 1 at azimuth 0 (the e1 axis), elevation 0
    o = torch.stack([torch.zeros(3), 0.5 * room.frame[:, 1]])  # the centre; off it, across e1
    target = 2.0 * e1
    d = target - o
    t, rgb, alpha = room.layers(o, d)
    assert t.shape == (2, 2) and bool(torch.isfinite(t).all())
    torch.testing.assert_close(t[:, 1], torch.ones(2))  # both rays reach the mark at t = 1
    assert bool((alpha[:, 1] > 0.99).all()) and bool((alpha[:, 0] < 1e-6).all())
    assert bool((rgb[:, 1, 0] > 0.99).all()) and bool((rgb[:, 1, 1:] < 1e-6).all())
    # the off-centre camera looking along e1 (not at the mark) misses it
    with torch.no_grad():
        _, _, alpha_e1 = room.layers(o[1:], e1[None])
    assert float(alpha_e1[0, 1]) < 1e-6


def test_capture_orbit_looks_at_the_trained_object_from_the_cameras_height():
    """``render`` aims an orbit at the model's object (where its opaque rays stop; thin
    haze does not count), not at the cameras' meeting point, at the training cameras'
    distance and height."""
    from nerfkit.data.synthetic import tabletop_scene
    from nerfkit.models import SceneBounds
    from nerfkit.models.fast import FastConfig, FastNeRF
    from nerfkit.output.images import object_aim

    scene = tabletop_scene(n_train=6, n_val=0, size=16)
    model = FastNeRF(FastConfig(resolutions="24", upsample_steps="", table=True), SceneBounds.from_scene(scene))
    black = torch.zeros(3)
    assert object_aim(model, scene.train, scene.up, black) is None  # nothing opaque yet
    g = model.field.geom
    xyz = g.lo + g.voxel * torch.stack(
        torch.meshgrid(*[torch.arange(r, dtype=torch.float32) for r in g.res[::-1]], indexing="ij")[::-1], -1
    ).reshape(-1, 3)
    cube = torch.tensor([0.3, -0.2, 0.4])
    with torch.no_grad():
        model.field.grid[:, 0] = -30.0
        rows = model.field.vertex_rows.long()  # each vertex's feature row
        grid = model.field.grid
        grid[rows[((xyz - cube).abs() < 0.25).all(1)], 0] = 30.0  # an opaque cube of side 0.5 beside the centre
        grid[rows[((xyz - torch.tensor([-0.5, 0.5, 1.4])).abs() < 0.3).all(1)], 0] = -4.0  # a faint haze above
    model.refresh_occupancy()
    aim = object_aim(model, scene.train, scene.up, black)
    np.testing.assert_allclose(aim[:2], cube[:2].numpy(), atol=0.1)  # across: the cube's middle
    assert 0.1 < aim[2] < 0.65  # along up: inside the cube, below its top face (0.65)
    views = scene.orbit(8, aim)
    eyes = views.c2w[:, :3, 3]
    to_aim = aim - eyes
    cosines = np.einsum("ni,ni->n", views.c2w[:, :3, 2], to_aim / np.linalg.norm(to_aim, axis=1, keepdims=True))
    np.testing.assert_allclose(cosines, 1.0, atol=1e-5)
    heights = (scene.train.c2w[:, :3, 3] - aim) @ scene.up
    orbit_heights = (eyes - aim) @ scene.up
    assert heights.min() - 1e-5 <= orbit_heights.min() and orbit_heights.max() <= heights.max() + 1e-5


def test_the_orbit_follows_the_cameras_height_and_distance_around_the_object():
    """Photos taken from high up on one side and low down on the other: the orbit is high
    and near where they looked down, low and far where they looked across."""
    from nerfkit.cameras import axes_across, intrinsics_matrix, look_at
    from nerfkit.data.scene import Scene, Views

    up = np.array([0.0, 0.0, 1.0])
    a, b = axes_across(up)
    eyes = []
    for azimuth, elevation, distance in [
        (0, 70, 3.0),
        (15, 70, 3.0),
        (-15, 70, 3.0),
        (180, 20, 5.0),
        (165, 20, 5.0),
        (195, 20, 5.0),
    ]:
        az, el = np.deg2rad(azimuth), np.deg2rad(elevation)
        eyes.append(distance * (np.cos(el) * (np.cos(az) * a + np.sin(az) * b) + np.sin(el) * up))
    c2w = np.stack([look_at(e, np.zeros(3), up) for e in eyes]).astype(np.float32)
    K = np.repeat(intrinsics_matrix(10.0, 10.0, 8.0, 8.0)[None], 6, 0)
    scene = Scene(
        Views(c2w, K, 16, 16),
        Views.empty(16, 16),
        Views.empty(16, 16),
        near=1.0,
        far=8.0,
        center=np.zeros(3, np.float32),
        up=up.astype(np.float32),
    )
    path = scene.orbit(4).c2w[:, :3, 3]  # azimuths 0, 90, 180, 270
    np.testing.assert_allclose(path[0] @ up, 3.0 * np.sin(np.deg2rad(70)), rtol=0.02)
    np.testing.assert_allclose(path[2] @ up, 5.0 * np.sin(np.deg2rad(20)), rtol=0.02)
    np.testing.assert_allclose(np.linalg.norm(path[2] - (path[2] @ up) * up), 5.0 * np.cos(np.deg2rad(20)), rtol=0.02)
    assert path[2] @ up < path[1] @ up < path[0] @ up  # in between at 90 degrees


def test_a_glossy_table_mirrors_its_surroundings():
    """Where the table's glossiness is 1, a ray looking down at it sees its map of the
    surroundings along the mirrored (upward) direction; where it is 0, its own colour."""
    from nerfkit.data.synthetic import tabletop_scene
    from nerfkit.models import SceneBounds
    from nerfkit.models.fast import FastConfig, FastNeRF
    from nerfkit.surroundings.table import ENV_SIZE

    scene = tabletop_scene(n_train=2, n_val=0, size=16)
    model = FastNeRF(
        FastConfig(
            resolutions="8", upsample_steps="", table=True, table_resolution=32, learn_background=True, table_gloss=True
        ),
        SceneBounds.from_scene(scene),
    )
    w, h = ENV_SIZE
    rows = -1.0 + (2.0 * torch.arange(h) + 1.0) / h  # texel centres, zenith (top row) to horizon
    with torch.no_grad():
        model.surroundings.table.fine.fill_(-2.0)
        model.surroundings.table.cover.fill_(30.0)
        model.surroundings.table.env.view(h, w, 3)[:] = 3.0 * rows.view(h, 1, 1)  # logit 3 v: darker toward the zenith
        model.surroundings.table.shine.fill_(30.0)
    o = torch.tensor([[0.0, 0.0, 1.0], [0.3, 0.0, 1.0], [0.3, 0.0, 1.0]])
    d = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.6, -0.8], [-0.6, 0.0, -0.8]])
    t = model.surroundings.table.hit(o, d)
    out = behind(model, o, d, t)[0]
    torch.testing.assert_close(out[0], torch.sigmoid(3.0 * rows[0]).expand(3))  # the zenith: the top row
    v = 1.0 - 2.0 * math.asin(0.8) / (0.5 * math.pi)  # mirrored z = +0.8, whichever way around
    torch.testing.assert_close(out[1:], torch.sigmoid(torch.tensor(3.0 * v)).expand(2, 3))
    with torch.no_grad():
        model.surroundings.table.shine.fill_(-30.0)
    torch.testing.assert_close(behind(model, o, d, t)[0], torch.sigmoid(torch.tensor(-2.0)).expand(3, 3))


def test_the_floor_under_a_table_is_found_and_seen_beyond_the_table_edge():
    """A tabletop capture whose sparse points show a floor 2 under the table: the bounds
    record it, and a ray past the table's edge sees the floor's texture where it meets it."""
    from dataclasses import replace

    from nerfkit.data.synthetic import tabletop_scene
    from nerfkit.models import SceneBounds
    from nerfkit.models.fast import FastConfig, FastNeRF

    rng = np.random.default_rng(0)
    table = np.concatenate([rng.uniform(-1, 1, (300, 2)), np.zeros((300, 1))], 1)
    floor = np.concatenate([rng.uniform(-6, 6, (400, 2)), np.full((400, 1), -2.0)], 1)
    scene = replace(
        tabletop_scene(n_train=4, n_val=0, size=16), points=np.concatenate([table, floor]).astype(np.float32)
    )
    bounds = SceneBounds.from_scene(scene)
    np.testing.assert_allclose(bounds.floor, [0, 0, 1, 2.0], atol=1e-3)
    assert SceneBounds.from_dict(bounds.to_dict()).floor == pytest.approx(bounds.floor)
    config = FastConfig(
        resolutions="8", upsample_steps="", table=True, table_resolution=32, learn_background=True, room_shells=0
    )
    model = FastNeRF(config, bounds)
    assert FastNeRF(replace(config, floor=False), bounds).surroundings.floor is None
    with torch.no_grad():
        model.surroundings.table.cover.fill_(-30.0)  # the table ends: nothing of it here
        model.surroundings.floor.cover.fill_(30.0)
        model.surroundings.floor.fine.view(32, 32, 3)[:, :16] = 3.0  # the floor: bright on the side of -e1, dark beyond
        model.surroundings.floor.fine.view(32, 32, 3)[:, 16:] = -3.0
    e1 = model.surroundings.floor.axes[:, 0]
    o = torch.stack([torch.tensor([0.0, 0.0, 1.0]) - 2.0 * e1, torch.tensor([0.0, 0.0, 1.0]) + 2.0 * e1])
    d = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    out = behind(model, o, d, model.surroundings.table.hit(o, d))[0]
    assert bool((out[0] > 0.9).all()) and bool((out[1] < 0.1).all())
    torch.testing.assert_close(model.surroundings.floor.hit(o, d), torch.tensor([3.0, 3.0]))


def test_room_shell_gradients_stay_finite_for_missing_tangent_and_polar_rays():
    """Pose fitting differentiates the room through the rays: rays that miss a shell, graze
    it, or point straight up through its centre must not turn the gradient into NaN."""
    room = RoomShells(center=torch.zeros(3), up=torch.tensor([0.0, 0.0, 1.0]), r0=1.0, n_shells=2, ratio=2.0, width=16)
    o = torch.tensor([[0.0, 0.0, 0.0], [3.0, 1.0, 0.0], [5.0, 5.0, 0.0], [0.0, 0.0, -0.5]], requires_grad=True)
    d = torch.tensor([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], requires_grad=True)
    t, rgb, alpha = room.layers(o, d)
    assert bool(torch.isinf(t[2]).all())  # misses both
    torch.testing.assert_close(t[1, 0], torch.tensor(math.inf))  # grazes the inner shell: no hit
    loss = (rgb.sum(-1) * alpha).sum() + torch.where(torch.isfinite(t), t, 0.0).sum()
    g_o, g_d = torch.autograd.grad(loss, (o, d))
    assert bool(torch.isfinite(g_o).all()) and bool(torch.isfinite(g_d).all())


def test_videos_follow_a_pose_only_test_path_and_orbit_a_capture():
    from dataclasses import replace

    from nerfkit.data.scene import Views
    from nerfkit.data.synthetic import tabletop_scene

    capture = tabletop_scene(n_train=4, n_val=2, size=16)
    assert not capture.has_video_path  # no test poses: an orbit
    assert len(capture.render_path(5)) == 5
    path = Views(capture.val.c2w, capture.val.K, 16, 16)  # poses without photos
    course = replace(capture, test=path)
    assert course.has_video_path and course.render_path(5) is path
    with_photos = replace(capture, test=capture.val)  # held-out photos are not a video path
    assert not with_photos.has_video_path and len(with_photos.render_path(3)) == 3


def test_a_rendered_view_gives_the_depth_of_the_table_beyond_an_empty_volume():
    """``render_image``'s ``scene_depth`` covers what the volume's depth leaves out: with
    no density in the box, the volume meets nothing and the table is met at the plane."""
    from nerfkit.cameras import image_rays
    from nerfkit.data.synthetic import tabletop_scene
    from nerfkit.models import SceneBounds
    from nerfkit.models.fast import FastConfig, FastNeRF
    from nerfkit.output.images import render_image

    scene = tabletop_scene(n_train=2, n_val=0, size=16)
    model = FastNeRF(
        FastConfig(resolutions="8", upsample_steps="", table=True, table_resolution=32, room_shells=0),
        SceneBounds.from_scene(scene),
    )
    with torch.no_grad():
        model.field.grid[:, 0] = -30.0  # no density anywhere
        model.surroundings.table.cover.fill_(30.0)  # an opaque table everywhere
    views = scene.train
    view = render_image(model, views.K[0], views.c2w[0], 16, 16, torch.zeros(3))
    assert float(view.acc.max()) < 1e-3 and not view.depth.any()  # the volume: nothing
    rays = image_rays(torch.as_tensor(views.K[0]), torch.as_tensor(views.c2w[0]), 16, 16)
    t = model.surroundings.table.hit(rays.origins, rays.directions).reshape(16, 16).numpy()
    on_table = np.isfinite(t)
    assert on_table.sum() > 100  # the cameras look down at the table
    np.testing.assert_allclose(view.scene_depth[on_table], t[on_table], rtol=1e-4)
    np.testing.assert_allclose(view.scene_acc[on_table], 1.0, atol=1e-6)
    from nerfkit.viz.video import colorize_depth

    np.testing.assert_allclose(
        view.depth_colours(1.0, 8.0), colorize_depth(view.scene_depth, view.scene_acc, 1.0, 8.0, unmet_is_far=True)
    )
    # a half-seen volume in front: its depth, then the table's for the light that passes it
    with torch.no_grad():
        model.field.grid[:, 0] = -1.5
    model.eval()
    with torch.no_grad():
        out = model.render_rays(rays, torch.zeros(3), perturb=False)
    t = torch.from_numpy(t.reshape(-1))
    seen = torch.isfinite(t) & (out.acc > 0.05) & (out.acc < 0.95)
    assert int(seen.sum()) > 50
    torch.testing.assert_close(out.scene_depth[seen], (out.depth + (1 - out.acc) * t)[seen], rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(out.scene_acc[seen], torch.ones(int(seen.sum())), rtol=0, atol=1e-5)
    model.train()
    assert model.render_rays(rays, torch.zeros(3), perturb=False).scene_depth is None  # not while training


def test_rendering_a_view_stops_when_asked_and_leaves_the_model_as_it_was():
    from nerfkit.data.synthetic import tabletop_scene
    from nerfkit.models import SceneBounds
    from nerfkit.models.fast import FastConfig, FastNeRF
    from nerfkit.output.images import render_image

    scene = tabletop_scene(n_train=1, n_val=0, size=16)
    model = FastNeRF(FastConfig(resolutions="8", upsample_steps="", table=True), SceneBounds.from_scene(scene))
    calls = []
    view = render_image(
        model,
        scene.train.K[0],
        scene.train.c2w[0],
        16,
        16,
        torch.zeros(3),
        chunk=64,
        abort=lambda: calls.append(1) or len(calls) > 2,
    )
    assert view is None and len(calls) == 3 and model.training  # two chunks rendered, then stopped


def test_a_model_file_from_before_the_field_and_surroundings_modules_loads():
    """A fast model's state under the keys of files written when the grid, the surface memory
    and the surroundings (learned background, table, room) sat on the model itself loads
    under today's names, every tensor in its place."""
    from nerfkit.models.fast import FastNeRF

    bounds, config = tiny_table_model(room_shells=1, room_resolution=16)
    model = FastNeRF(config, bounds)
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for p in model.parameters():
            p.copy_(torch.rand(p.shape, generator=gen))
        model.surfaces.remember(torch.rand(5, 3, generator=gen))
    old_names = {
        "field.grid": "grid",
        "field.vertex_rows": "vertex_rows",
        "surfaces.pts": "surface_pts",
        "surfaces.count": "surface_count",
        "estimator.occ": "occ_cells",
    }
    old = {old_names.get(k, k.removeprefix("surroundings.")): v for k, v in model.state_dict().items()}
    assert {"grid", "vertex_rows", "occ_cells", "bg_coef", "table.fine", "room.fine", "surface_pts"} <= set(old)
    fresh = FastNeRF(config, bounds)
    fresh.load_state_dict(old)
    for k, v in model.state_dict().items():
        assert torch.equal(fresh.state_dict()[k], v), k


def test_a_raised_table_is_met_at_its_height_along_each_ray():
    """A relief of constant height h: each ray meets it exactly h above the plane, nearer
    than the plane by h / cos (the angle to the normal); a relief of 0 moves nothing, and
    the hit's distance along the ray changes by the same amount in the rendered layer."""
    from nerfkit.surroundings.table import RELIEF_UNIT

    table = TablePlane(torch.tensor([0.0, 0.0, 1.0, 0.0]), torch.zeros(3), radius=1.0, resolution=64, relief=True)
    o = torch.tensor([[0.0, 0.0, 1.0], [0.2, -0.1, 1.0], [0.4, 0.3, 2.0]])
    d = torch.nn.functional.normalize(torch.tensor([[0.0, 0.0, -1.0], [0.3, 0.2, -1.0], [-0.5, 0.1, -1.0]]), dim=-1)
    on_plane = o + d * table.hit(o, d).unsqueeze(-1)
    same, dt = table.raise_hits(on_plane, d, compiled=False)
    torch.testing.assert_close(same, on_plane)
    assert torch.all(dt == 0)
    with torch.no_grad():
        table.relief.fill_(2.0)  # 2 units: 0.02 of the radius
    raised, dt = table.raise_hits(on_plane, d, compiled=False)
    height = 2.0 * RELIEF_UNIT * 1.0
    torch.testing.assert_close(raised[:, 2], torch.full((3,), height))
    torch.testing.assert_close(dt, -height / -d[:, 2])
    torch.testing.assert_close(raised, on_plane + d * dt.unsqueeze(-1))


def test_the_relief_learns_from_where_the_texture_is_seen():
    """The colour seen through a relief depends on its height (the texture is looked up
    where the ray meets it), so the relief gets a gradient from the photometric error; a
    table without relief has no such parameter."""
    table = TablePlane(torch.tensor([0.0, 0.0, 1.0, 0.0]), torch.zeros(3), radius=1.0, resolution=32, relief=True)
    ramp = torch.linspace(-3.0, 3.0, 32)
    with torch.no_grad():  # a ramp along both texture axes
        table.fine.copy_((ramp.view(32, 1) + ramp.view(1, 32)).reshape(-1, 1).expand(-1, 3))
    o = torch.tensor([[0.1, 0.0, 1.0]])
    d = torch.nn.functional.normalize(torch.tensor([[0.5, 0.3, -1.0]]), dim=-1)
    p = o + d * table.hit(o, d).unsqueeze(-1)
    raised, _ = table.raise_hits(p, d, compiled=False)
    colour = table.look(raised, compiled=False)[0]
    colour.sum().backward()
    assert table.relief.grad is not None and table.relief.grad.abs().sum() > 0
    assert TablePlane(torch.tensor([0.0, 0.0, 1.0, 0.0]), torch.zeros(3), 1.0, 32).relief is None


def _tag(center, side):
    """A printed tag's corners (4, 3) on z = 0, counter-clockwise from (-x, -y)."""
    (x, y), h = center, side / 2
    return np.array([[x - h, y - h, 0], [x + h, y - h, 0], [x + h, y + h, 0], [x - h, y + h, 0]])


def test_a_tags_fine_texture_adds_colour_over_its_square_doubled_and_nowhere_else():
    from nerfkit.kernels.ops import GradSink

    plane, center = torch.tensor([0.0, 0.0, 1.0, 0.0]), torch.zeros(3)
    tags = np.stack([_tag((0.2, 0.1), 0.1), _tag((-0.3, -0.2), 0.1)])
    plain = TablePlane(plane, center, radius=1.0, resolution=32)
    table = TablePlane(plane, center, radius=1.0, resolution=32, tags=tags, tag_texels=16)
    assert [t.shape for t in table.tag_fine] == [(256, 3), (256, 3)]
    assert len(table.textures()) == len(plain.textures()) + 2
    # without tags the state holds nothing new: a model file from before the tags' texture loads
    assert not [k for k in plain.state_dict() if k.startswith("tag_")]
    assert sorted(table.state_dict()) == sorted([*plain.state_dict(), "tag_frames", "tag_fine.0", "tag_fine.1"])
    pts = torch.tensor([[0.2, 0.1, 0.0], [0.29, 0.19, 0.0], [0.31, 0.1, 0.0], [-0.3, -0.2, 0.0], [0.0, 0.0, 0.0]])
    # zero at first: the same colour as a table without tags
    torch.testing.assert_close(table.colour(pts), plain.colour(pts))
    with torch.no_grad():
        table.tag_fine[0].fill_(1.0)  # the first tag's texture: +1 logit everywhere on it
    logit = torch.logit(table.colour(pts)) - torch.logit(plain.colour(pts))
    # the first tag's square doubled spans 0.2 +- 0.1, 0.1 +- 0.1: in, in, out (x 0.31), the other tag, far
    torch.testing.assert_close(logit[:, 0], torch.tensor([1.0, 1.0, 0.0, 0.0, 0.0]), atol=1e-4, rtol=0)
    # a gradient reaches only the texels of the tag a point lies on
    sinks = {p: GradSink(p.shape[0], p.shape[1], torch.device("cpu"), lanes=1) for p, _ in table.textures()}
    table.look(pts[:1], sinks)[0].sum().backward()
    first, second = (sinks[t] for t in table.tag_fine)
    assert first.grad.abs().sum() > 0 and second.grad.abs().sum() == 0 and not second.dirty


def test_a_tags_texels_are_the_finest_power_of_two_no_smaller_than_a_pixels_footprint():
    from nerfkit.presets import TAG_MAX_TEXELS, tag_texels_for

    assert tag_texels_for(0.1, 0.68e-3) == 256  # 0.78 mm texels over the 0.2 m square
    assert tag_texels_for(0.055, 0.81e-3) == 128  # 0.86 mm (256 would be 0.43)
    assert tag_texels_for(0.06, 1.28e-3) == 64  # 1.9 mm
    assert tag_texels_for(0.5, 1e-5) == TAG_MAX_TEXELS  # capped
    assert tag_texels_for(0.01, 2e-3) == 0 and tag_texels_for(0.1, None) == 0  # not even 16, unknown
    for side, foot in ((0.1, 0.68e-3), (0.055, 0.81e-3), (0.06, 1.28e-3)):
        n = tag_texels_for(side, foot)
        assert 2 * side / n >= foot > 2 * side / (2 * n)  # the texel is the footprint's, within a factor of 2
