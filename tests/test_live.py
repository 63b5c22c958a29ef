"""The live viewer: camera conversion, refinement schedule, checkpoint watching, rendering."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

pytest.importorskip("viser")

from nerfkit.cameras import look_at  # noqa: E402
from nerfkit.commands import live  # noqa: E402
from nerfkit.data.synthetic import sphere_color, sphere_scene  # noqa: E402
from nerfkit.errors import NerfkitError  # noqa: E402
from nerfkit.models.base import NerfModel, RenderOutput, SceneBounds  # noqa: E402


def _project(K, c2w, X):
    x = np.linalg.inv(c2w.astype(np.float64)) @ np.append(X, 1.0)
    return (K.astype(np.float64) @ x[:3])[:2] / x[2], x[2]


def test_viewer_camera_follows_viser_convention():
    """viser: P_world = R p_cam + t with OpenCV camera axes, vertical fov in radians."""
    c2w = look_at(np.array([1.0, -3.0, 2.0]), np.zeros(3), np.array([0, 0, 1.0]))
    fov, aspect = np.radians(50), 1.5
    K, c2w_out, w, h = live.viewer_camera(live.matrix_to_quat(c2w[:3, :3]), c2w[:3, 3], fov, aspect, 120)
    assert (w, h) == (120, 80)
    np.testing.assert_allclose(c2w_out, c2w, atol=1e-6)
    uv, z = _project(K, c2w_out, np.zeros(3))  # the look-at point: image centre, in front
    assert z > 0 and np.allclose(uv, [60, 40], atol=1e-4)
    # a point fov/2 above the axis (world up) lands on the top edge; one to the right, right of centre
    d = np.linalg.norm(c2w[:3, 3])
    up_cam = -c2w[:3, 1]
    top = c2w[:3, 3] + d * (np.cos(fov / 2) * c2w[:3, 2] + np.sin(fov / 2) * up_cam)
    np.testing.assert_allclose(_project(K, c2w_out, top)[0], [60, 0], atol=1e-3)
    assert _project(K, c2w_out, 0.3 * c2w[:3, 0])[0][0] > 60
    # portrait windows keep the long side
    assert live.viewer_camera([1, 0, 0, 0], np.zeros(3), fov, 0.5, 100)[2:] == (50, 100)


def test_quaternion_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        R = live.quat_to_matrix(q)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
        np.testing.assert_allclose(live.quat_to_matrix(live.matrix_to_quat(R)), R, atol=1e-9)


def test_a_boxs_depth_range_runs_from_its_nearest_point_to_its_farthest_corner():
    box = (np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 2.0]))
    c2w = np.eye(4)
    c2w[:3, 3] = [0.0, -5.0, 1.0]  # facing the box's y = -1 face, 4 away
    near, far = live.box_depth_range(box, c2w, 0.1, 100.0)
    assert near == pytest.approx(4.0) and far == pytest.approx(np.sqrt(1 + 36 + 1))
    assert live.box_depth_range(box, c2w, 4.5, 5.0) == (4.5, pytest.approx(np.sqrt(38)))  # no nearer than near
    c2w[:3, 3] = [0.0, -20.0, 1.0]  # beyond the scene's far: still the box's own range
    assert live.box_depth_range(box, c2w, 0.1, 6.0) == (pytest.approx(19.0), pytest.approx(np.sqrt(1 + 21**2 + 1)))
    assert live.box_depth_range(None, c2w, 0.1, 100.0) == (0.1, 100.0)


def test_refinement_sides():
    assert live.refinement_sides(64, 256) == [64, 128, 256]
    assert live.refinement_sides(64, 100) == [64, 100]
    assert live.refinement_sides(64, 32) == [32]


def test_watcher_reloads_new_checkpoints_only(tmp_path):
    calls = []

    def loader(run_dir):
        calls.append(run_dir)
        if (tmp_path / "broken").exists():
            raise NerfkitError("checkpoint is truncated")
        step = int(sorted((tmp_path / "checkpoints").glob("step_*.pt"))[-1].stem[5:])
        return "model", "info", step

    w = live.RunWatcher(tmp_path, loader)
    assert not w.poll() and w.current is None and "waiting" in w.status
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "step_00000010.pt").write_bytes(b"x")
    assert w.poll() and w.current.step == 10
    assert not w.poll() and len(calls) == 1  # unchanged: no reload
    (tmp_path / "broken").touch()
    (tmp_path / "checkpoints" / "step_00000020.pt").write_bytes(b"x")
    assert not w.poll() and w.current.step == 10 and "could not load" in w.status
    (tmp_path / "broken").unlink()
    assert w.poll() and w.current.step == 20


class SphereModel(NerfModel):
    """The textured unit sphere rendered exactly (a stand-in for a trained model)."""

    def render_rays(self, rays, background, perturb):
        o, d = rays.origins.double(), rays.directions.double()
        b = (o * d).sum(1)
        disc = b * b - ((o * o).sum(1) - 1.0)
        hit = disc > 0
        t = torch.where(hit, -b - torch.sqrt(torch.clamp(disc, min=0)), torch.zeros_like(b))
        rgb = torch.from_numpy(sphere_color((o + t[:, None] * d).numpy())).float()
        rgb = torch.where(hit[:, None], rgb, background.expand_as(rgb))
        return RenderOutput(rgb, (t * hit).float(), hit.float())


def sphere_viewer(model_cls=None, background="black", scene=None, **options) -> live.LiveViewer:
    """A live viewer (127.0.0.1, a free port, not watching) of a unit sphere model, 4 units from
    the cameras; ``options`` are the viewer's (max_side, preview)."""
    bounds = SceneBounds(2.0, 6.0, np.zeros(3, np.float32), 1.3, np.array([0, 0, 1.0], np.float32))
    info = SimpleNamespace(bounds=bounds, train=SimpleNamespace(background=background))
    watcher = live.RunWatcher(".", lambda d: None)
    watcher.current = live.LoadedRun((model_cls or SphereModel)(bounds), info, 5, None)
    return live.LiveViewer(watcher, scene, host="127.0.0.1", port=0, watch=False, **options)


def test_viewer_renders_the_model_from_the_browser_camera():
    viewer = sphere_viewer(background="white", scene=sphere_scene(n_train=3, n_val=1, size=16), max_side=64)
    try:
        assert viewer.server.get_host() == "127.0.0.1"
        assert len(viewer._frustum_handles) == 3
        c2w = look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3), np.array([0, 0, 1.0]))
        q = live.matrix_to_quat(c2w[:3, :3])
        img = viewer.render_for(q, c2w[:3, 3], np.radians(40), 1.0, 32, "RGB")
        assert img.shape == (32, 32, 3)
        hit = np.array([0.0, -1.0, 0.0])  # the centre ray hits the sphere here
        np.testing.assert_allclose(
            img[15:17, 15:17].reshape(-1, 3).mean(0) / 255, sphere_color(hit[None])[0], atol=0.05
        )
        assert (img[0, 0] == 255).all()  # the white background in a corner
        depth = viewer.render_for(q, c2w[:3, 3], np.radians(40), 1.0, 32, "Depth")
        assert (depth[0, 0] == 0).all() and depth[16, 16].any()
        assert viewer.render_for(q, c2w[:3, 3], np.radians(40), 1.0, 32, "RGB", abort=lambda: True) is None
        viewer.step()  # no browser connected: nothing to do, no error
    finally:
        viewer.server.stop()


class SphereInRoom(SphereModel):
    """The sphere in front of a grey room (its surroundings: a learned background) that
    :func:`~nerfkit.surroundings.isolate_object` takes away."""

    def __init__(self, bounds):
        from nerfkit.surroundings import Surroundings

        super().__init__(bounds)
        room = SimpleNamespace(learn_background=True, room_shells=0, table=False, floor=False)
        self.surroundings = Surroundings(room, bounds)

    def render_rays(self, rays, background, perturb):
        grey = torch.tensor([0.5, 0.5, 0.5])
        return super().render_rays(rays, grey if self.surroundings is not None else background, perturb)


def test_the_viewer_shows_the_object_alone_on_white_without_touching_the_run():
    viewer = sphere_viewer(SphereInRoom, max_side=32)
    watcher, bounds, info = viewer.watcher, viewer.watcher.current.info.bounds, viewer.watcher.current.info
    try:
        c2w = look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3), np.array([0, 0, 1.0]))
        q = live.matrix_to_quat(c2w[:3, :3])
        whole = viewer.render_for(q, c2w[:3, 3], np.radians(40), 1.0, 32, "RGB")
        alone = viewer.render_for(q, c2w[:3, 3], np.radians(40), 1.0, 32, "RGB", alone=True)
        assert (whole[0, 0] == 128).all() and (alone[0, 0] == 255).all()  # the room, then white
        np.testing.assert_array_equal(alone[12:20, 12:20], whole[12:20, 12:20])  # the same sphere
        assert watcher.current.model.surroundings is not None  # the run's own model still has its room
        copy = viewer._alone[1]
        viewer.render_for(q, c2w[:3, 3], np.radians(40), 1.0, 32, "RGB", alone=True)
        assert viewer._alone[1] is copy  # isolated once per checkpoint ...
        depth = viewer.render_for(q, c2w[:3, 3], np.radians(40), 1.0, 32, "Depth", alone=True)
        assert (depth[0, 0] == 0).all() and depth[16, 16].any()  # its depth: the sphere, nothing around it
        watcher.current = live.LoadedRun(SphereInRoom(bounds), info, 6, None)  # ... a new checkpoint
        viewer.render_for(q, c2w[:3, 3], np.radians(40), 1.0, 32, "RGB", alone=True)
        assert viewer._alone[1] is not copy and viewer._alone[0] is watcher.current
    finally:
        viewer.server.stop()


def test_progressive_refinement_for_a_resting_camera(monkeypatch):
    """Preview first; larger images only once the camera has rested; restart when it moves."""
    viewer = sphere_viewer(max_side=64, preview=16)
    try:
        c2w = look_at(np.array([0.0, -4.0, 1.0]), np.zeros(3), np.array([0, 0, 1.0]))
        sent = []
        camera = SimpleNamespace(wxyz=live.matrix_to_quat(c2w[:3, :3]), position=c2w[:3, 3], fov=0.7, aspect=2.0)
        client = SimpleNamespace(
            camera=camera, scene=SimpleNamespace(set_background_image=lambda img, **kw: sent.append(img.shape))
        )
        monkeypatch.setattr(viewer.server, "get_clients", lambda: {1: client})
        clock = [100.0]
        monkeypatch.setattr(live.time, "monotonic", lambda: clock[0])
        viewer.step()
        assert sent == [(8, 16, 3)]  # the preview, at once
        viewer.step()
        assert len(sent) == 1  # not settled yet
        clock[0] += 1.0
        viewer.step()
        viewer.step()
        viewer.step()
        assert sent[1:] == [(16, 32, 3), (32, 64, 3)]  # refined up to max_side, then idle
        camera.position = camera.position + 0.1  # the user moves: back to a preview
        viewer.step()
        assert sent[-1] == (8, 16, 3)
    finally:
        viewer.server.stop()


def test_a_splat_runs_gaussians_are_hidden_while_depth_or_the_object_alone_is_shown():
    """viser draws its Gaussians over the rendered background: shown over colour only."""
    viewer = sphere_viewer(max_side=32)
    try:
        viewer.splats = SimpleNamespace(visible=True)
        shown = []
        for mode, alone in (("Depth", False), ("RGB", True), ("RGB", False)):
            viewer.mode.value, viewer.alone.value = mode, alone
            viewer.step()
            shown.append(viewer.splats.visible)
        assert shown == [False, False, True]
    finally:
        viewer.server.stop()


def test_the_live_viewer_draws_in_the_precision_the_run_was_loaded_for(monkeypatch):
    """The viewer renders as `render` and `eval` do: in the model's resolved autocast dtype."""
    import nerfkit.output.images as images

    seen = {}
    monkeypatch.setattr(images, "render_image", lambda *a, **kw: seen.update(kw))
    model = SimpleNamespace(autocast_dtype=torch.bfloat16)
    live.render_camera(model, np.eye(3), np.eye(4), 4, 4, torch.zeros(3))
    assert seen["autocast_dtype"] is torch.bfloat16
    live.render_camera(SimpleNamespace(autocast_dtype=None), np.eye(3), np.eye(4), 4, 4, torch.zeros(3))
    assert seen["autocast_dtype"] is None
