"""nerfstudio-style transforms.json: round trips, axes, intrinsics, splits, distortion, errors."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from nerfkit.cameras import look_at
from nerfkit.data.nerfstudio import image_file_name, load_transforms_json, write_transforms_json
from nerfkit.data.scene import Scene, Views
from nerfkit.errors import NerfkitError


def random_views(n, w=32, h=24, seed=0, names=None, K=None):
    rng = np.random.default_rng(seed)
    c2w = np.stack(
        [look_at(rng.normal(0, 1, 3) * 2 + np.array([0, 0, 3.0]), np.zeros(3), np.array([0, 0, 1.0])) for _ in range(n)]
    ).astype(np.float32)
    K = np.array([[30.0, 0, 16.5], [0, 31.0, 11.25], [0, 0, 1]], np.float32) if K is None else K
    images = rng.integers(0, 256, (n, h, w, 3), dtype=np.uint8)
    return Views(c2w, np.repeat(K[None], n, 0), w, h, images, names)


def make_scene(**kw):
    train = random_views(5, names=[f"IMG_{i}.png" for i in range(5)], seed=1)
    val = random_views(2, names=["v0.png", "v1.HEIC"], seed=2)
    test = Views.empty(32, 24)
    return Scene(
        train, val, test, 0.5, 4.5, np.array([0.1, 0.2, 0.3], np.float32), np.array([0, 0, 1], np.float32), **kw
    )


def test_round_trip_keeps_cameras_images_names_and_bounds(tmp_path):
    scene = make_scene()
    path = write_transforms_json(scene, tmp_path)
    back = load_transforms_json(path)
    for split in ("train", "val"):
        a, b = scene.splits[split], back.splits[split]
        np.testing.assert_allclose(b.c2w, a.c2w, atol=1e-6)
        np.testing.assert_allclose(b.K, a.K, rtol=1e-6)
        assert np.array_equal(b.images, a.images)  # PNG: lossless
        assert b.names == a.names
    assert len(back.test) == 0
    assert (back.near, back.far) == (0.5, 4.5)
    np.testing.assert_allclose(back.center, [0.1, 0.2, 0.3], atol=1e-7)
    assert (tmp_path / "images" / "v1.HEIC.png").exists()
    data = json.loads(path.read_text())
    assert data["val_filenames"] == ["images/v0.png", "images/v1.HEIC.png"]
    assert {"fl_x", "fl_y", "cx", "cy", "w", "h"} <= set(data)


def test_transform_matrix_uses_opengl_axes(tmp_path):
    # An OpenGL camera with identity pose looks along world -z with +y up.
    img = np.zeros((8, 10, 3), np.uint8)
    from PIL import Image

    Image.fromarray(img).save(tmp_path / "a.png")
    (tmp_path / "transforms.json").write_text(
        json.dumps(
            {
                "fl_x": 10.0,
                "w": 10,
                "h": 8,
                "nerfkit": {"near": 0.5, "far": 3.0},  # one camera: no depth range to estimate
                "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}],
            }
        )
    )
    s = load_transforms_json(tmp_path)
    R = s.train.c2w[0, :3, :3]
    np.testing.assert_allclose(R[:, 2], [0, 0, -1])  # OpenCV forward = world -z
    np.testing.assert_allclose(R[:, 1], [0, -1, 0])  # OpenCV down = world -y
    np.testing.assert_allclose(s.train.K[0], [[10, 0, 5], [0, 10, 4], [0, 0, 1]])  # cx, cy default to the centre
    data = json.loads(write_transforms_json(s, tmp_path / "out").read_text())
    np.testing.assert_allclose(data["frames"][0]["transform_matrix"], np.eye(4), atol=1e-7)


def test_per_frame_intrinsics_when_views_differ(tmp_path):
    train = random_views(3, seed=3)
    train.K[1, 0, 0] = 40.0
    scene = Scene(train, Views.empty(32, 24), Views.empty(32, 24), 1.0, 6.0)
    data = json.loads(write_transforms_json(scene, tmp_path).read_text())
    assert "fl_x" not in data and data["frames"][1]["fl_x"] == 40.0
    back = load_transforms_json(tmp_path)
    np.testing.assert_allclose(back.train.K, train.K, rtol=1e-6)


def test_nerfstudio_filename_lists_and_camera_angle(tmp_path):
    from PIL import Image

    frames = []
    for i in range(4):
        Image.fromarray(np.full((6, 8, 3), i * 40, np.uint8)).save(tmp_path / f"f{i}.png")
        frames.append({"file_path": f"f{i}", "transform_matrix": np.eye(4).tolist()})  # no extension
    (tmp_path / "transforms.json").write_text(
        json.dumps(
            {
                "camera_angle_x": 2 * np.arctan(4 / 10.0),
                "frames": frames,
                "nerfkit": {"near": 0.5, "far": 3.0},
                "train_filenames": ["f0", "f1"],
                "val_filenames": ["f2"],
                "test_filenames": ["f3"],
            }
        )
    )
    s = load_transforms_json(tmp_path / "transforms.json")
    assert (len(s.train), len(s.val), len(s.test)) == (2, 1, 1)
    assert s.train.K[0, 0, 0] == pytest.approx(10.0)
    assert s.test.images[0, 0, 0, 0] == 120


def test_distortion_is_removed_on_load_with_a_warning(tmp_path):
    """Dots drawn where a k1 = -0.2 lens puts known points land, after loading, where the
    loaded pinhole K puts them (centroids within 0.15 px); the lens had moved them > 3 px."""
    import cv2

    from conftest import dot_centroid_errors, draw_dots
    from nerfkit.images import write_image

    W, H, f = 160, 120, 120.0
    gx, gy = np.meshgrid(np.linspace(-0.55, 0.55, 6), np.linspace(-0.4, 0.4, 5))  # dots >= 20 px apart
    pts = np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)], 1)
    K_cv = np.array([[f, 0, W / 2 - 0.5], [0, f, H / 2 - 0.5], [0, 0, 1]])  # OpenCV: pixel centres at 0
    dist = np.array([-0.2, 0.0, 0.0, 0.0, 0.0])
    uv = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K_cv, dist)[0].reshape(-1, 2) + 0.5
    write_image(tmp_path / "a.png", draw_dots(W, H, uv))
    (tmp_path / "transforms.json").write_text(
        json.dumps(
            {
                "fl_x": f,
                "fl_y": f,
                "cx": W / 2,
                "cy": H / 2,
                "w": W,
                "h": H,
                "k1": -0.2,
                "k2": 0.0,
                "p1": 0.0,
                "p2": 0.0,
                "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}],
                "nerfkit": {"near": 0.5, "far": 3.0},
            }
        )
    )
    with pytest.warns(UserWarning, match="undistorted them on load"):
        s = load_transforms_json(tmp_path)
    K = s.train.K[0].astype(np.float64)
    errs = dot_centroid_errors(s.train.images[0], (pts @ K.T)[:, :2])
    assert len(errs) >= 15 and max(errs) < 0.15, errs
    assert np.abs(uv - (pts @ np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]]).T)[:, :2]).max() > 3


@pytest.mark.parametrize(
    "content, message",
    [
        ("{not json", "not valid JSON"),
        (json.dumps({"frames": []}), 'non-empty "frames"'),
        (json.dumps({"camera_model": "OPENCV_FISHEYE", "frames": [{}]}), "OPENCV_FISHEYE is not supported"),
        (
            json.dumps({"fl_x": 5, "frames": [{"file_path": "missing.png", "transform_matrix": np.eye(4).tolist()}]}),
            "not found",
        ),
        (
            json.dumps({"fl_x": 5, "frames": [{"file_path": "a.png", "transform_matrix": (2 * np.eye(4)).tolist()}]}),
            "not rigid|last row",
        ),
        (
            json.dumps(
                {
                    "fl_x": 5,
                    "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist(), "split": "holdout"}],
                }
            ),
            "split 'holdout'",
        ),
    ],
)
def test_bad_transforms_are_one_line_errors(tmp_path, content, message):
    from PIL import Image

    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(tmp_path / "a.png")
    (tmp_path / "transforms.json").write_text(content)
    with pytest.raises(NerfkitError, match=message) as e:
        load_transforms_json(tmp_path)
    assert "\n" not in str(e.value) and "transforms.json" in str(e.value)


def test_pose_only_split_round_trips(tmp_path):
    scene = make_scene()
    scene.test = Views(scene.train.c2w[:3].copy(), scene.train.K[:3].copy(), 32, 24)
    write_transforms_json(scene, tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = load_transforms_json(tmp_path)
    assert back.test.images is None
    np.testing.assert_allclose(back.test.c2w, scene.test.c2w, atol=1e-6)


def test_image_file_names_keep_the_photo_name():
    assert image_file_name("IMG_0930.JPG") == "IMG_0930.JPG"
    assert image_file_name("IMG_1.heic") == "IMG_1.heic.png"
    assert image_file_name("dir/x.png") == "x.png"


def test_a_stated_centre_no_ray_reaches_is_refused(tmp_path):
    path = write_transforms_json(make_scene(), tmp_path)  # cameras about 3 from the centre, far 4.5
    data = json.loads(path.read_text())
    data["nerfkit"]["center"] = [100.0, 0.0, 0.0]
    path.write_text(json.dumps(data))
    with pytest.raises(NerfkitError, match=r"'nerfkit\.center' \[100\.0, 0\.0, 0\.0\] .* no ray reaches the object"):
        load_transforms_json(path)
    del data["nerfkit"]["center"]  # estimated from the cameras instead: it loads, at the origin
    path.write_text(json.dumps(data))  # (random_views' cameras all look at it)
    np.testing.assert_allclose(load_transforms_json(path).center, [0.0, 0.0, 0.0], atol=1e-5)
