"""Dataset viewer geometry, the static PNG, the viser server and `nerfkit view` routing."""

from __future__ import annotations

import re
import socket
import sys
import types

import numpy as np
import pytest

from nerfkit.cameras import look_at
from nerfkit.cli import main
from nerfkit.data.npz import save_npz
from nerfkit.data.scene import Scene, Views
from nerfkit.errors import NerfkitError
from nerfkit.viz.scene_plot import frustum_points, plot_scene, printed_tags, sample_rays


def small_scene(n=6, w=40, h=30):
    c2w, imgs = [], []
    for k in range(n):
        a = 2 * np.pi * k / n
        eye = np.array([0.4 * np.cos(a), 0.4 * np.sin(a), 0.25])
        c2w.append(look_at(eye, np.zeros(3), np.array([0, 0, 1.0])))
        imgs.append(np.full((h, w, 3), (40 * k) % 255, np.uint8))
    K = np.array([[35.0, 0, 20.0], [0, 35.0, 15.0], [0, 0, 1]], np.float32)
    views = Views(
        np.array(c2w, np.float32), np.repeat(K[None], n, 0), w, h, np.array(imgs), [f"IMG_{k}.JPG" for k in range(n)]
    )
    return Scene(
        views.subset(np.arange(n - 2)),
        views.subset([n - 2]),
        views.subset([n - 1]),
        0.2,
        0.7,
        np.zeros(3, np.float32),
        np.array([0, 0, 1], np.float32),
        source="test",
    )


def test_frustum_corners_project_back_to_the_image_corners():
    s = small_scene()
    v = s.train
    f = frustum_points(v.K[0].astype(float), v.c2w[0].astype(float), v.width, v.height, 0.3)
    np.testing.assert_allclose(f[0], v.c2w[0, :3, 3], atol=1e-6)
    w2c = np.linalg.inv(v.c2w[0].astype(float))
    x = f[1:] @ w2c[:3, :3].T + w2c[:3, 3]
    np.testing.assert_allclose(x[:, 2], 0.3, atol=1e-9)
    uv = x @ v.K[0].astype(float).T
    np.testing.assert_allclose(uv[:, :2] / uv[:, 2:], [[0, 0], [40, 0], [40, 30], [0, 30]], atol=1e-6)


def test_sampled_points_lie_on_their_rays_between_near_and_far():
    s = small_scene()
    rs = sample_rays(s.train, s.near, s.far, 25, 16, seed=3)
    t = np.einsum("nsk,nk->ns", rs.points - rs.origins[:, None], rs.directions)
    off = rs.points - (rs.origins[:, None] + t[..., None] * rs.directions[:, None])
    assert np.abs(off).max() < 1e-5
    assert t.min() >= s.near - 1e-5 and t.max() <= s.far + 1e-5
    assert np.all(np.diff(t, axis=1) > 0)
    # Rays start at training cameras.
    cams = s.train.c2w[:, :3, 3]
    assert np.min(np.linalg.norm(rs.origins[:, None] - cams[None], axis=2), axis=1).max() < 1e-6


def test_rays_of_one_view_start_at_its_camera_and_fill_its_image():
    """The course's check that u and v are not swapped: every ray of view 2 projects back
    into view 2's image, and they reach its four quarters."""
    s = small_scene()
    rs = sample_rays(s.train, s.near, s.far, 200, 8, seed=1, view=2)
    np.testing.assert_allclose(rs.origins, np.broadcast_to(s.train.c2w[2, :3, 3], rs.origins.shape), atol=1e-6)
    w2c = np.linalg.inv(s.train.c2w[2].astype(np.float64))
    x = rs.points[:, 0] @ w2c[:3, :3].T + w2c[:3, 3]
    uv = (x @ s.train.K[2].astype(np.float64).T)[:, :2] / x[:, 2:]
    assert (uv >= 0).all() and (uv[:, 0] <= 40).all() and (uv[:, 1] <= 30).all()
    quarters = {(u > 20, v > 15) for u, v in uv}
    assert len(quarters) == 4


def test_png_shows_cameras_in_split_colours(tmp_path):
    from PIL import Image

    out = tmp_path / "scene.png"
    plot_scene(small_scene(), out, n_rays=10, n_samples=8, tag_size=0.06)
    img = np.asarray(Image.open(out).convert("RGB")).astype(int)
    assert img.shape[0] > 500 and img.shape[1] > 500
    # Train frustums are drawn in matplotlib blue (31, 119, 180), val in orange (255, 127, 14).
    blue = (np.abs(img - [31, 119, 180]).sum(-1) < 40).sum()
    orange = (np.abs(img - [255, 127, 14]).sum(-1) < 40).sum()
    assert blue > 50 and orange > 10


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_viser_server_shows_every_camera_and_the_rays():
    from nerfkit.viz.viewer import serve_dataset, set_rays

    scene = small_scene()
    server, handles = serve_dataset(
        scene, host="127.0.0.1", port=free_port(), n_rays=12, n_samples=8, tag_size=0.06, block=False
    )
    try:
        assert server.get_host() == "127.0.0.1"
        assert len(handles["frustums"]) == len(scene.train) + len(scene.val) + len(scene.test)
        assert handles["samples"].points.shape == (12 * 8, 3)
        pos = np.array([h.position for h in handles["frustums"][: len(scene.train)]])
        np.testing.assert_allclose(pos, scene.train.c2w[:, :3, 3], atol=1e-5)
        set_rays(server, scene, handles, 0, 8)
        assert handles["rays"] is None and handles["samples"] is None
        assert handles["points"] is None  # this dataset has no sparse points
    finally:
        server.stop()


def test_viser_server_shows_the_sparse_points_in_their_colours():
    from nerfkit.viz.viewer import serve_dataset

    scene = small_scene()
    rng = np.random.default_rng(0)
    scene.points = rng.normal(size=(40, 3)).astype(np.float32)
    scene.point_colors = rng.integers(0, 256, (40, 3)).astype(np.uint8)
    server, handles = serve_dataset(scene, host="127.0.0.1", port=free_port(), block=False)
    try:
        np.testing.assert_allclose(handles["points"].points, scene.points, rtol=2e-3)  # viser keeps float16
        np.testing.assert_array_equal(handles["points"].colors, scene.point_colors)
    finally:
        server.stop()


@pytest.mark.slow
def test_view_command_writes_png_for_a_dataset(tmp_path, capsys):
    save_npz(small_scene(), tmp_path / "d.npz")
    assert main(["view", str(tmp_path / "d.npz"), "--rays", "5", "--png", str(tmp_path / "v.png")]) == 0
    assert (tmp_path / "v.png").stat().st_size > 10_000
    assert main(["view", str(tmp_path / "d.npz"), "--rays-from", "3", "--png", str(tmp_path / "one.png")]) == 0
    assert main(["view", str(tmp_path / "d.npz"), "--rays-from", "4", "--png", str(tmp_path / "x.png")]) == 2
    assert (
        "has 4 training views (0 to 3), not a view 4" in capsys.readouterr().err and not (tmp_path / "x.png").exists()
    )


def run_folder(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "config.json").write_text("{}")
    return run


def test_view_of_a_run_folder_calls_the_live_viewer(tmp_path, monkeypatch):
    calls = []
    fake = types.ModuleType("nerfkit.commands.live")
    fake.serve_run = lambda run_dir, host, port, **kw: calls.append((str(run_dir), host, port, kw))
    monkeypatch.setitem(sys.modules, "nerfkit.commands.live", fake)
    run = run_folder(tmp_path)
    assert main(["view", str(run), "--port", "9123"]) == 0
    assert calls == [(str(run), "127.0.0.1", 9123, {"allow_outside_paths": False, "quiet": False})]


def test_view_of_a_run_folder_without_the_live_viewer_is_a_clear_error(tmp_path, monkeypatch):
    from nerfkit.cli import build_parser

    monkeypatch.setitem(sys.modules, "nerfkit.commands.live", None)  # import fails
    args = build_parser().parse_args(["view", str(run_folder(tmp_path))])
    with pytest.raises(NerfkitError, match="live viewer .* is not available"):
        args.func(args)


def test_the_viewer_draws_every_printed_tag_the_dataset_records():
    from nerfkit.viz.viewer import serve_dataset

    scene = small_scene()
    one = printed_tags(scene, 0.06)  # no tags recorded: one of the given size at the origin
    np.testing.assert_allclose(np.abs(one[0][:, :2]), 0.03)
    np.testing.assert_allclose(one[0][:, 2], 0.0)
    assert printed_tags(scene, None) is None
    square = np.array([[-0.03, -0.03, 0], [0.03, -0.03, 0], [0.03, 0.03, 0], [-0.03, 0.03, 0]], np.float32)
    scene.tags = np.stack([square, square + [0.1, 0, 0], square + [0, -0.1, 0]])
    np.testing.assert_array_equal(printed_tags(scene, 0.06), scene.tags)  # a sheet's tags, wherever they are
    server, handles = serve_dataset(scene, host="127.0.0.1", port=free_port(), tag_size=0.06, block=False)
    try:
        mesh = handles["tag"]
        assert mesh.vertices.shape == (12, 3) and mesh.faces.shape == (6, 3)
        np.testing.assert_allclose(mesh.vertices[4:8, :2], scene.tags[1][:, :2], atol=1e-6)
        assert mesh.faces.max() == 11
    finally:
        server.stop()


def test_the_frustums_look_along_each_cameras_z_with_its_field_of_view_and_aspect():
    """OpenCV axes: each frustum's rotation is its camera's (+z forward, toward the scene),
    its vertical field of view 2 atan(h / 2 fy), its aspect w / h; views named alike in two
    folders are two cameras."""
    import viser.transforms as vtf

    from nerfkit.viz.viewer import serve_dataset

    scene = small_scene(w=40, h=20)
    scene.train.K[:, 1, 1] = 10.0  # fy: a vertical field of view of 90 degrees
    scene.train.names = [f"{d}/frame.jpg" for d in "abcd"]
    server, handles = serve_dataset(scene, host="127.0.0.1", port=free_port(), block=False)
    try:
        train = handles["frustums"][: len(scene.train)]
        assert len({h.name for h in train}) == len(scene.train)
        for h, c2w in zip(train, scene.train.c2w.astype(np.float64)):
            R = vtf.SO3(np.asarray(h.wxyz)).as_matrix()
            np.testing.assert_allclose(R, c2w[:3, :3], atol=1e-5)
            assert (scene.center - c2w[:3, 3]) @ R[:, 2] > 0  # +z looks at the scene
            assert h.fov == pytest.approx(np.pi / 2) and h.aspect == pytest.approx(2.0)
    finally:
        server.stop()


def test_the_sliders_reach_the_rays_and_samples_asked_for():
    from nerfkit.viz.viewer import serve_dataset

    server, handles = serve_dataset(
        small_scene(), host="127.0.0.1", port=free_port(), n_rays=5000, n_samples=1, block=False
    )
    try:
        assert handles["gui"]["rays"].value == 5000 and handles["gui"]["samples"].value == 1
        assert handles["samples"].points.shape == (5000, 3)
    finally:
        server.stop()


def test_a_host_the_machine_cannot_listen_on_is_refused_before_serving():
    from nerfkit.viz.viewer import listening_port

    with pytest.raises(NerfkitError, match="--host: is empty"):
        listening_port(" ", 8080)
    with pytest.raises(NerfkitError, match="--host: 'no.such.host.invalid' does not resolve"):
        listening_port("no.such.host.invalid", 8080)
    with pytest.raises(NerfkitError, match="--host: cannot listen on 192.0.2.1"):  # TEST-NET-1: not ours
        listening_port("192.0.2.1", 8080)
    with socket.socket() as taken:  # a port in use: the next one
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        got = listening_port("127.0.0.1", port)
        assert got != port and port < got <= min(port + 100, 65535)
        if port == 65535:
            pytest.skip("no port after 65535")


def test_a_thumbnail_keeps_its_aspect_without_opencv(monkeypatch):
    from nerfkit.viz.viewer import _thumbnail

    monkeypatch.setitem(sys.modules, "cv2", None)
    image = np.zeros((300, 600, 3), np.uint8)
    image[:, 300:] = 200
    small = _thumbnail(image, 256)
    assert small.shape == (128, 256, 3) and small[:, :127].max() == 0 and small[:, 129:].min() == 200
    assert _thumbnail(image, 1000) is image


def test_the_pictures_axes_are_the_worlds_where_up_is_z():
    from nerfkit.viz.scene_plot import _axis_label, _to_plot

    R = _to_plot(np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(R, np.eye(3), atol=1e-12)
    assert [_axis_label(r) for r in R[:2]] == ["x", "y"]
    R = _to_plot(np.array([0.0, -1.0, 0.0]))  # y down is up (OpenCV-style worlds)
    assert np.linalg.det(R) == pytest.approx(1.0) and [_axis_label(r) for r in R] == ["x", "z", "-y"]
    R = _to_plot(np.array([0.3, 0.2, 0.9]))
    assert _axis_label(R[1]) == "across up" and np.allclose(R @ R.T, np.eye(3))


def test_a_run_in_training_before_its_first_checkpoint_opens_the_live_viewer(tmp_path, monkeypatch):
    from nerfkit import api
    from nerfkit.io.lock import folder_lock

    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text('{"train": {"data": "d.npz"}}')
    with pytest.raises(NerfkitError, match="folder holds no dataset"):  # stopped: nothing to show
        api.view(run)
    training = pytest.raises(NerfkitError, match="is a trained run: its live viewer renders on the calling thread")
    with folder_lock(run), training:  # training: the live viewer waits for its first checkpoint
        api.view(run)
    with pytest.raises(NerfkitError, match="config.json: is a file of a trained run. Pass the run's folder"):
        (run / "model.pt").write_bytes(b"")
        api.view(run / "config.json")
    for options, flag in (({"samples": 8}, "--samples"), ({"force": True}, "--force")):
        with pytest.raises(NerfkitError, match=flag):
            api.view(run, **options)


def test_a_picture_asked_of_a_run_names_the_dataset_to_draw_instead(tmp_path):
    from nerfkit import api
    from nerfkit.data.npz import save_npz
    from nerfkit.data.synthetic import sphere_scene

    save_npz(sphere_scene(n_train=4, n_val=1, size=16), tmp_path / "s.npz")
    api.train(tmp_path / "s.npz", tmp_path / "run", model="fast", steps=1, quiet=True)
    want = f"nerfkit view {(tmp_path / 's.npz').resolve()} --png {tmp_path / 'v.png'}"
    with pytest.raises(NerfkitError, match=re.escape(want)):
        api.view(tmp_path / "run", png=tmp_path / "v.png")
