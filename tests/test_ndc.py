"""Forward-facing scenes: NDC rays, the automatic choice of NDC, the spiral path, training."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from nerfkit.cameras import forward_facing, intrinsics_matrix, look_at, mean_camera
from nerfkit.data.scene import Views
from nerfkit.data.synthetic import forward_facing_scene, sphere_scene
from nerfkit.models.base import SceneBounds
from nerfkit.render.ndc import NdcSpace


@pytest.fixture(scope="module")
def space():
    c2w = look_at(np.array([0.2, -0.1, 0.3]), np.array([0.5, 0.3, 5.0]), np.array([0.0, -1.0, 0.0]))
    return NdcSpace.from_camera(c2w, intrinsics_matrix(50.0, 55.0, 33.0, 30.0), 64, 56, near=0.7)


def random_rays(space, n=200, seed=0):
    g = torch.Generator().manual_seed(seed)
    c2w = torch.tensor(space.c2w, dtype=torch.float64)
    o = c2w[:3, 3] + 0.1 * torch.randn(n, 3, generator=g, dtype=torch.float64)
    d = c2w[:3, 2] + 0.15 * torch.randn(n, 3, generator=g, dtype=torch.float64)
    return o, d / d.norm(dim=1, keepdim=True)


def test_ndc_maps_rays_to_straight_rays_from_the_near_plane_to_infinity(space):
    o, d = random_rays(space)
    on, dn, forward = space.rays(o, d)
    assert forward.all()
    torch.testing.assert_close(on[:, 2], torch.full_like(on[:, 2], -1.0))  # every ray starts on the near plane
    for t in (2.0, 5.0, 40.0, 1e4):  # (all beyond the near plane)
        p = space.points(o + t * d)
        s = (p[:, 2] - on[:, 2]) / dn[:, 2]
        torch.testing.assert_close(on + s.unsqueeze(-1) * dn, p)  # the world point lies on the NDC ray
        assert bool(((s > 0) & (s < 1)).all())
        torch.testing.assert_close(space.distance(o, d, s), torch.full_like(s, t), rtol=1e-6, atol=1e-6 * t)


def test_ndc_x_and_y_are_the_reference_pixel_coordinates_scaled_to_one(space):
    p_world = torch.tensor([[0.4, -0.2, 3.0], [-1.0, 0.5, 9.0]], dtype=torch.float64)
    p = space.to_camera(p_world)
    u = space.fx * p[:, 0] / p[:, 2] + space.cx
    v = space.fy * p[:, 1] / p[:, 2] + space.cy
    ndc = space.points(p_world)
    torch.testing.assert_close(ndc[:, 0], 2 * u / space.width - 1)
    torch.testing.assert_close(ndc[:, 1], 2 * v / space.height - 1)
    torch.testing.assert_close(ndc[:, 2], 1 - 2 * space.near / p[:, 2])


def test_backward_rays_are_flagged_and_the_space_round_trips(space):
    o, d = random_rays(space, n=4)
    _, _, forward = space.rays(o, -d)
    assert not forward.any()
    assert NdcSpace.from_dict(space.to_dict()) == space


def test_the_ndc_box_holds_every_pixel_of_cameras_turned_about_their_axis(space):
    """Photos taken with the phone turned about its axis (a top-down sweep) see beyond the
    reference frustum's corners: the fitted box holds every ray of every camera from the
    near plane to infinity; cameras like the reference one keep the smallest box."""
    from nerfkit.cameras import image_rays

    ref = np.array(space.c2w)
    K = np.array([[space.fx, 0, space.cx], [0, space.fy, space.cy], [0, 0, 1.0]])
    assert space.fit_extent(ref[None], K[None], space.width, space.height).extent == pytest.approx(1.25)
    turned = []
    for deg in (0, 40, 90, 135):
        a = np.radians(deg)
        roll = np.eye(4)
        roll[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        turned.append(ref @ roll)
    turned = np.stack(turned)
    fitted = space.fit_extent(turned, np.repeat(K[None], 4, 0), space.width, space.height)
    assert fitted.extent > 1.3 and NdcSpace.from_dict(fitted.to_dict()) == fitted
    for c2w in turned:
        rays = image_rays(
            torch.tensor(K, dtype=torch.float32), torch.tensor(c2w, dtype=torch.float32), space.width, space.height
        )
        o, d, forward = fitted.rays(rays.origins.double(), rays.directions.double())
        assert forward.all()
        for s in (0.0, 0.5, 0.999):
            assert float((o + s * d)[:, :2].abs().max()) <= fitted.extent
    assert max(float((o + s * d)[:, :2].abs().max()) for s in (0.0, 0.999)) > 1.25  # the old box missed some


def test_forward_facing_scenes_get_ndc_and_a_spiral_others_do_not():
    ff, sphere = forward_facing_scene(n_train=8, n_val=1, size=16), sphere_scene(n_train=20, size=16)
    assert forward_facing(ff.train.c2w, ff.center) and not forward_facing(sphere.train.c2w, sphere.center)
    assert SceneBounds.from_scene(ff).ndc is not None and SceneBounds.from_scene(sphere).ndc is None
    path = ff.render_path(12)
    eyes = path.c2w[:, :3, 3]
    ref = mean_camera(ff.train.c2w)
    assert np.abs((eyes - ref[:3, 3]) @ ref[:3, 2]).max() < 1e-5  # circles across the view, not around the scene
    assert (
        np.linalg.norm(eyes - ref[:3, 3], axis=1).max()
        <= np.linalg.norm(ff.train.c2w[:, :3, 3] - ref[:3, 3], axis=1).max() + 1e-6
    )  # within the cameras' spread
    assert (path.c2w[:, :3, 2] @ ref[:3, 2]).min() > 0.9  # looking the way the photos did
    no_path = replace(sphere, test=Views.empty(16, 16))  # (its test split is a pose-only path)
    np.testing.assert_allclose(no_path.render_path(12).c2w, sphere.orbit(12).c2w)
    assert (ff.video_kind(), no_path.video_kind(), sphere.video_kind()) == ("spiral", "orbit", "test")


def test_a_video_path_can_be_chosen_over_the_automatic_one():
    ff = forward_facing_scene(n_train=8, n_val=1, size=16)
    orbit = ff.render_path(12, kind="orbit").c2w
    offsets = orbit[:, :3, 3] - ff.center
    azimuths = np.unwrap(np.arctan2(offsets[:, 1], offsets[:, 0]))
    np.testing.assert_allclose(np.abs(np.diff(azimuths)), 2 * np.pi / 12, rtol=1e-4)  # all the way round
    np.testing.assert_allclose(ff.render_path(12, kind="spiral").c2w, ff.render_path(12).c2w)
    with pytest.raises(ValueError, match="unknown camera path 'helix'"):
        ff.render_path(12, kind="helix")


@pytest.mark.slow
def test_fast_model_in_ndc_beats_the_box_on_a_forward_facing_scene(tmp_path, capsys):
    """Content from 3 units to a backdrop 15 units away: a box around the scene's middle
    cannot hold the backdrop; the NDC grid holds everything out to infinity."""
    from nerfkit.cli import main
    from nerfkit.data.npz import save_npz
    from nerfkit.models.fast import FastConfig
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import train

    scene = forward_facing_scene(n_train=24, n_val=3, size=40)
    save_npz(scene, tmp_path / "forward.npz")
    scores = {}
    for space in ("auto", "box"):
        cfg = TrainConfig(
            data=str(tmp_path / "forward.npz"),
            out=str(tmp_path / space),
            steps=240,
            batch_rays=1024,
            seed=0,
            eval_views=3,
            checkpoint_seconds=1e9,
        )
        result = train(scene, cfg, FastConfig(resolutions="32,64", upsample_steps="80", space=space), quiet=True)
        scores[space] = [r["psnr"] for r in result.rows if r["split"] == "val"][-1]
    assert scores["auto"] > 23.0
    assert scores["auto"] > scores["box"] + 2.0, scores
    # a forward-facing scene has no object standing apart for `render --object` to frame
    assert main(["render", str(tmp_path / "auto"), "--object", "--frames", "2"]) == 2
    assert "has no object standing apart to frame" in capsys.readouterr().err
    assert not (tmp_path / "auto" / "videos" / "object.mp4").exists()


def test_ndc_is_refused_for_a_scene_that_is_not_forward_facing():
    from nerfkit.errors import NerfkitError
    from nerfkit.models.fast import FastConfig, FastNeRF

    with pytest.raises(NerfkitError, match="not forward-facing"):
        FastNeRF(FastConfig(space="ndc"), SceneBounds.from_scene(sphere_scene(n_train=20, size=16)))


def test_a_scaled_disparity_axis_keeps_world_points_on_their_rays(space):
    """The grid's space (Z times ndc_depth_scale) is linear: each world point lies on its
    scaled NDC ray at the same fraction s as on the unscaled one."""
    from nerfkit.render.ndc import to_grid

    o, d = random_rays(space, n=50, seed=3)
    on, dn, _ = space.rays(o, d)
    for t in (2.0, 30.0):
        p = space.points(o + t * d)
        s = (p[:, 2] - on[:, 2]) / dn[:, 2]
        for scale in (0.25, 1.0, 2.0):
            g = to_grid(p, scale)
            torch.testing.assert_close(to_grid(on, scale) + s.unsqueeze(-1) * to_grid(dn, scale), g)
            torch.testing.assert_close(g[:, 2], scale * p[:, 2])
            torch.testing.assert_close(g[:, :2], p[:, :2])


@pytest.mark.parametrize("scale", [1.0, 0.4])
def test_the_fast_grid_in_ndc_puts_a_wall_at_its_depth_whatever_the_disparity_scale(scale):
    """A wall (the reference camera's plane z = 3) painted into the grid where it is in the
    grid's space renders at its world distance; a disparity scale of 0.4 lays about 0.4 times
    as many vertices along Z for each across X as cubes in NDC do."""
    from nerfkit.fields.grid import EMPTY_RAW
    from nerfkit.models.fast import FastConfig, FastNeRF

    bounds = SceneBounds.from_scene(forward_facing_scene(n_train=6, n_val=0, size=16))
    model = FastNeRF(FastConfig(resolutions="64", upsample_steps="", ndc_depth_scale=scale, kernels="torch"), bounds)
    rx, _, rz = model.field.res
    e = bounds.ndc.extent
    assert (rz - 1) / (rx - 1) == pytest.approx(scale / e, rel=0.05)
    ndc, z0 = bounds.ndc, 3.0
    geom = model.field.geom
    behind = geom.vertex_positions()[:, 2] >= scale * (1.0 - 2.0 * ndc.near / z0)
    with torch.no_grad():
        model.field.grid[1:, 0] = torch.where(behind, 20.0, EMPTY_RAW)
    model.refresh_occupancy()
    model.estimator.active = True
    c2w = torch.tensor(ndc.c2w, dtype=torch.float32)
    cam = torch.tensor([[0.0, 0.0, 1.0], [0.2, -0.1, 1.0], [-0.15, 0.2, 1.0]])  # reference camera's frame
    d = cam @ c2w[:3, :3].T
    o = c2w[:3, 3].expand(3, 3)
    out = model._render_ndc(o, d, torch.full((3,), 0.5), torch.zeros(3))
    assert bool((out.acc > 0.99).all())
    # each ray (o + t d, d's z 1 in the camera's frame) meets the wall at t = 3, within a
    # voxel of the grid's Z (in depth: dz = dZ z^2 / (2 near))
    voxel_depth = model.field.voxel / scale * z0**2 / (2.0 * ndc.near)
    assert voxel_depth < 0.3
    torch.testing.assert_close(out.depth, torch.full((3,), z0), atol=voxel_depth, rtol=0)


@pytest.mark.parametrize("square", [False, True])
def test_square_pixels_make_a_pixel_across_as_long_as_a_pixel_down_in_the_grid(space, square):
    """One pixel across and one pixel down (same depth, the reference camera's own intrinsics)
    move a point equally far in the grid's space with ``square_pixels``; without, NDC's X
    and Y both span the photo, so a pixel across is height / width of a pixel down."""
    from nerfkit.render.ndc import grid_scale, to_grid

    c2w = torch.tensor(space.c2w, dtype=torch.float64)
    R, c = c2w[:3, :3], c2w[:3, 3]
    cam = torch.tensor([[0.3, -0.2, 2.0], [-0.5, 0.4, 7.0]], dtype=torch.float64)  # reference camera's frame
    z = cam[:, 2:]
    across = cam + torch.cat([z / space.fx, 0 * z, 0 * z], 1)
    down = cam + torch.cat([0 * z, z / space.fy, 0 * z], 1)
    scale = grid_scale(space.width, space.height, 0.3, square)
    assert scale == ((space.width / space.height if square else 1.0), 1.0, 0.3)

    def grid(p):
        return to_grid(space.points(p @ R.T + c), scale)

    step_x, step_y = (grid(across) - grid(cam)).norm(dim=1), (grid(down) - grid(cam)).norm(dim=1)
    want = 1.0 if square else space.height / space.width
    torch.testing.assert_close(step_x / step_y, torch.full_like(step_x, want))


def test_the_fast_grid_with_square_pixels_lays_more_vertices_across_a_landscape_photo():
    """A forward-facing scene of 4:3 photos: the first grid has about 4/3 as many vertices
    across as down with ``ndc_square_pixels``, as many without (NDC's box is square)."""
    from nerfkit.models.fast import FastConfig, FastNeRF

    scene = forward_facing_scene(n_train=6, n_val=0, size=16)
    K = scene.train.K.copy()
    K[:, 0, 2], K[:, 1, 2] = 32 / 2, 24 / 2
    wide = replace(scene, train=replace(scene.train, width=32, height=24, K=K, images=None))
    bounds = SceneBounds.from_scene(wide)
    for square, ratio in ((False, 1.0), (True, 32 / 24)):
        model = FastNeRF(FastConfig(resolutions="48", upsample_steps="", ndc_square_pixels=square), bounds)
        rx, ry, _ = model.field.res
        assert (rx - 1) / (ry - 1) == pytest.approx(ratio, rel=0.05)


def test_the_distortion_loss_in_ndc_measures_the_fraction_of_the_way_to_infinity():
    """In NDC the distortion loss's distances are the NDC rays' fraction ``s`` (spanning
    [0, 1) whatever the scene's size): its term is the weight times the mean per-ray
    distortion, not divided by the scene radius as in a box."""
    from nerfkit.models.base import RenderOutput
    from nerfkit.models.fast import FastConfig, FastNeRF

    fwd = SceneBounds.from_scene(forward_facing_scene(n_train=6, n_val=0, size=8))
    obj = SceneBounds.from_scene(sphere_scene(n_train=6, size=8))
    dist = torch.tensor([0.2, 0.4])
    out = RenderOutput(torch.zeros(2, 3), torch.zeros(2), torch.zeros(2), 0, {"distortion": dist})
    for bounds, unit in ((fwd, 1.0), (obj, obj.radius)):
        model = FastNeRF(FastConfig(resolutions="8", upsample_steps="", distortion_weight=0.5), bounds)
        assert model.distortion_unit == unit
        torch.testing.assert_close(model.loss(out, torch.zeros(2, 3)), torch.tensor(0.5 * 0.3 / unit))
    assert fwd.radius > 2.0  # (the two units differ)


@pytest.mark.parametrize("capture, ndc", [("auto", True), ("on", False)])
def test_the_scene_kind_a_run_resolves_decides_whether_it_trains_in_ndc(tmp_path, capture, ndc):
    """NDC follows the kind the run takes its settings from: a forward-facing scene trained
    with --capture on is a capture (no NDC), as presets.scene_kind says."""
    import json

    from nerfkit import api
    from nerfkit.data.npz import save_npz

    ff = forward_facing_scene(n_train=8, n_val=1, size=16)
    assert SceneBounds.from_scene(ff, ndc=False).ndc is None and SceneBounds.from_scene(ff).ndc is not None
    save_npz(ff, tmp_path / "ff.npz")
    api.train(tmp_path / "ff.npz", tmp_path / "run", model="fast", steps=1, capture=capture, quiet=True)
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["train"]["preset"] == ("forward-facing" if ndc else "capture")
    assert (config["bounds"]["ndc"] is not None) == ndc
