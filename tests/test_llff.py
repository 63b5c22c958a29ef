"""LLFF forward-facing layout: poses_bounds.npy + images/ (round trips, hold-out, errors)."""

from __future__ import annotations

import os

import imageio.v3 as iio
import numpy as np
import pytest

from conftest import tiny_vanilla
from nerfkit.cameras import look_at, opengl_to_opencv
from nerfkit.data.llff import holdout_indices, llff_to_opencv, load_llff, opencv_to_llff
from nerfkit.data.load import detect_format, load_scene
from nerfkit.errors import NerfkitError

W, H, FOCAL = 32, 24, 30.0


def forward_facing_cameras(n: int, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) OpenCV cameras on a small grid in the z = 0 plane, all looking at a point
    near (0, 0, 4) (z up is irrelevant here: world up is -y)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        eye = np.array([0.3 * (i % 4) - 0.45, 0.2 * (i // 4) - 0.2, 0.0]) + rng.normal(0, 0.01, 3)
        out.append(look_at(eye, np.array([0.0, 0.0, 4.0]) + rng.normal(0, 0.05, 3), np.array([0.0, -1.0, 0.0])))
    return np.stack(out)


def write_llff(folder, c2w, bounds, sizes=((1, W, H),), n_images=None):
    """A scene folder: poses_bounds.npy and, per (factor, w, h), images[_factor]/ with one
    flat-coloured PNG per view (colour encodes the view index)."""
    folder.mkdir(parents=True, exist_ok=True)
    rows = np.concatenate([opencv_to_llff(c2w, [H, W, FOCAL]).reshape(len(c2w), 15), bounds], axis=1)
    np.save(folder / "poses_bounds.npy", rows)
    for factor, w, h in sizes:
        d = folder / ("images" if factor == 1 else f"images_{factor}")
        d.mkdir(exist_ok=True)
        for i in range(len(c2w) if n_images is None else n_images):
            iio.imwrite(d / f"IMG_{i:04d}.png", np.full((h, w, 3), (10 * i, 255 - 10 * i, 7), np.uint8))
    return folder


@pytest.fixture
def scene_dir(tmp_path):
    c2w = forward_facing_cameras(17)
    bounds = np.stack([np.linspace(2.0, 2.5, 17), np.linspace(6.0, 7.0, 17)], axis=1)
    return write_llff(tmp_path / "fern", c2w, bounds, sizes=((1, W, H), (4, W // 4, H // 4))), c2w, bounds


def test_llff_axes_match_the_nerf_papers_conversion():
    # NeRF's load_llff turns [down, right, back] into OpenGL [right, up, back]; nerfkit goes on to OpenCV
    rng = np.random.default_rng(1)
    q, _ = np.linalg.qr(rng.normal(size=(5, 3, 3)))
    poses = np.concatenate(
        [
            q * np.sign(np.linalg.det(q))[:, None, None],
            rng.normal(size=(5, 3, 1)),
            np.tile([[H], [W], [FOCAL]], (5, 1, 1)),
        ],
        axis=2,
    )
    gl = np.concatenate([poses[:, :, 1:2], -poses[:, :, 0:1], poses[:, :, 2:4]], axis=2)
    gl44 = np.concatenate([gl, np.tile([[[0, 0, 0, 1.0]]], (5, 1, 1))], axis=1)
    assert np.allclose(llff_to_opencv(poses), opengl_to_opencv(gl44))
    assert np.allclose(opencv_to_llff(llff_to_opencv(poses), [H, W, FOCAL]), poses)


def test_holdout_is_every_eighth_image():
    train, held = holdout_indices(17)
    assert held.tolist() == [0, 8, 16]
    assert sorted(train.tolist() + held.tolist()) == list(range(17))
    assert holdout_indices(1)[1].size == 0  # a single photo is trained on


def test_round_trip_cameras_holdout_and_bounds(scene_dir):
    folder, c2w, bounds = scene_dir
    assert detect_format(folder) == "llff" and detect_format(folder / "poses_bounds.npy") == "llff"
    scene = load_scene(folder)
    train, held = holdout_indices(17)
    assert np.allclose(scene.train.c2w, c2w[train], atol=1e-6)
    assert np.allclose(scene.val.c2w, c2w[held], atol=1e-6) and np.allclose(scene.test.c2w, c2w[held], atol=1e-6)
    assert scene.val.names == ["IMG_0000", "IMG_0008", "IMG_0016"]
    assert [int(im[0, 0, 0]) // 10 for im in scene.val.images] == [0, 8, 16]  # the photos follow their poses
    assert [int(im[0, 0, 0]) // 10 for im in scene.train.images] == train.tolist()
    K = scene.train.K[0]
    assert (scene.train.width, scene.train.height) == (W, H)
    assert np.allclose(K, [[FOCAL, 0, W / 2], [0, FOCAL, H / 2], [0, 0, 1]])
    assert scene.near == pytest.approx(0.9 * 2.0) and scene.far == pytest.approx(7.0)
    # the scene's centre lies in front of the cameras, mid-way through the depth range
    assert np.allclose(scene.center[:2], 0, atol=0.3) and scene.center[2] == pytest.approx(0.5 * (1.8 + 7.0), abs=0.1)


def test_downscaled_folder_and_focal(scene_dir):
    folder, c2w, _ = scene_dir
    scene = load_llff(folder, downscale=4)  # reads images_4: the files, not a resample
    assert (scene.train.width, scene.train.height) == (W // 4, H // 4)
    assert np.allclose(scene.train.K[0], [[FOCAL / 4, 0, W / 8], [0, FOCAL / 4, H / 8], [0, 0, 1]])
    assert np.allclose(scene.train.c2w, c2w[holdout_indices(17)[0]], atol=1e-6)
    half = load_llff(folder, downscale=2)  # no images_2: resampled from images/
    assert (half.train.width, half.train.height) == (W // 2, H // 2)
    assert half.train.K[0, 0, 0] == pytest.approx(FOCAL / 2)


def _error(folder) -> str:
    with pytest.raises(NerfkitError) as e:
        load_scene(folder)
    msg = str(e.value)
    assert "\n" not in msg  # one line
    return msg


def test_malformed_poses_bounds_are_clear_errors(tmp_path):
    c2w = forward_facing_cameras(9)
    bounds = np.tile([2.0, 6.0], (9, 1))
    folder = write_llff(tmp_path / "s", c2w, bounds)
    rows = np.load(folder / "poses_bounds.npy")
    np.save(folder / "poses_bounds.npy", rows[:, :15])
    assert "shape (9, 15), expected (N, 17)" in _error(folder)
    bad = rows.copy()
    bad[3, 4] = np.nan
    np.save(folder / "poses_bounds.npy", bad)
    assert "row 3 has NaN or inf" in _error(folder)
    bad = rows.copy()
    bad[2, 15:] = [5.0, 1.0]
    np.save(folder / "poses_bounds.npy", bad)
    assert "row 2: bounds" in _error(folder)
    bad = rows.copy().reshape(9, 17)
    bad[1, :15] = (opencv_to_llff(c2w[1:2] * np.array([2.0, 1, 1, 1])[None, :, None], [H, W, FOCAL])).reshape(15)
    np.save(folder / "poses_bounds.npy", bad)
    assert "not rigid" in _error(folder)
    np.save(folder / "poses_bounds.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    assert "cannot read it as a .npy array" in _error(folder)  # pickles are never loaded
    (folder / "poses_bounds.npy").write_bytes(b"not numpy")
    assert "poses_bounds.npy: is not a .npy file" in _error(folder)  # (not "pickled data")


def test_image_problems_are_clear_errors(tmp_path):
    c2w = forward_facing_cameras(9)
    bounds = np.tile([2.0, 6.0], (9, 1))
    folder = write_llff(tmp_path / "s", c2w, bounds, n_images=8)
    assert "holds 8 images but poses_bounds.npy has 9 poses" in _error(folder)
    iio.imwrite(folder / "images" / "IMG_0008.png", np.zeros((H, 2 * W, 3), np.uint8))
    assert "IMG_0008.png" in _error(folder) and "one size" in _error(folder)
    for p in (folder / "images").iterdir():
        iio.imwrite(p, np.zeros((H, 2 * W, 3), np.uint8))
    assert "another aspect ratio" in _error(folder)
    for p in (folder / "images").iterdir():
        p.unlink()
    (folder / "images").rmdir()
    assert "images" in _error(folder) and "missing" in _error(folder)


def test_an_image_linking_outside_the_folder_is_refused(tmp_path):
    c2w = forward_facing_cameras(9)
    folder = write_llff(tmp_path / "s", c2w, np.tile([2.0, 6.0], (9, 1)))
    outside = tmp_path / "elsewhere.png"
    iio.imwrite(outside, np.zeros((H, W, 3), np.uint8))
    (folder / "images" / "IMG_0003.png").unlink()
    os.symlink(outside, folder / "images" / "IMG_0003.png")
    assert "outside the dataset folder" in _error(folder)
    scene = load_scene(folder, allow_outside=True)  # the user trusts it
    assert len(scene.train) == 7


def test_an_llff_scene_trains_in_ndc_and_renders_a_spiral(scene_dir):
    from nerfkit.cameras import mean_camera
    from nerfkit.models.base import SceneBounds

    folder, c2w, bounds = scene_dir
    scene = load_llff(folder)
    b = SceneBounds.from_scene(scene)
    assert b.ndc is not None and np.isclose(b.ndc.near, scene.near)
    ref = mean_camera(scene.train.c2w)
    np.testing.assert_allclose(np.asarray(b.ndc.c2w), ref, atol=1e-6)
    path = scene.render_path(8)
    assert np.abs((path.c2w[:, :3, 3] - ref[:3, 3]) @ ref[:3, 2]).max() < 1e-5  # a spiral by the cameras


def test_a_run_trains_on_the_downscaled_folder_and_keeps_reading_it(scene_dir, tmp_path, capsys):
    from nerfkit.cli import main
    from nerfkit.commands._common import scene_for_run
    from nerfkit.train.checkpoint import read_run

    folder, _, _ = scene_dir
    run = tmp_path / "run"
    assert (
        main(
            [
                "train",
                "--data",
                str(folder),
                "--downscale",
                "4",
                "--out",
                str(run),
                "--steps",
                "2",
                *tiny_vanilla(samples=4, width=8, batch_rays=16),
            ]
        )
        == 0
    )
    scene = scene_for_run(read_run(run), None)  # raises if these are not the images the run trained on
    assert (scene.train.width, scene.train.height) == (W // 4, H // 4)
    assert main(["eval", str(run), "--split", "val"]) == 0
    assert main(["view", str(run), "--downscale", "4"]) == 2
    assert "--downscale: a trained run loads its dataset as it was trained" in capsys.readouterr().err
    assert main(["view", str(run), "--rays", "10"]) == 2  # the live viewer draws no rays
    assert "--rays: the live viewer of a trained run draws its cameras" in capsys.readouterr().err
