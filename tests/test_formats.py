"""Dataset formats: Blender loader, the load_scene dispatcher, resampling, conversions.

Every fixture is generated here (small RGBA PNGs and json files in tmp_path).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from conftest import tiny_vanilla
from nerfkit.cameras import intrinsics_matrix, look_at, opencv_to_opengl
from nerfkit.cli import main
from nerfkit.data.blender import focal_from_angle, load_blender
from nerfkit.data.load import detect_format, load_scene
from nerfkit.data.nerfstudio import write_transforms_json
from nerfkit.data.npz import load_npz, save_npz
from nerfkit.data.resample import output_size, resample_scene, scale_intrinsics
from nerfkit.data.synthetic import render_sphere, sphere_cameras, sphere_scene
from nerfkit.errors import NerfkitError
from nerfkit.images import write_image

ANGLE = 0.6911112070083618  # lego's camera_angle_x


def _rgba(rng, w, h):
    """A random RGBA image with fully transparent, opaque and half-transparent regions."""
    img = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
    img[..., 3] = 255
    img[: h // 4, :, 3] = 0  # top quarter transparent
    img[h // 4 : h // 2, :, 3] = 128  # half transparent band
    return img


def make_blender(folder, n=(3, 2, 2), size=(40, 30), seed=0):
    """Write a Blender-layout scene; return {split: (c2w_cv (N,4,4), rgba images)}."""
    rng = np.random.default_rng(seed)
    w, h = size
    truth = {}
    for split, count in zip(("train", "val", "test"), n):
        c2w_cv = sphere_cameras(count, seed=seed + len(split)).astype(np.float64)
        frames, images = [], []
        for i in range(count):
            img = _rgba(rng, w, h)
            write_image(folder / split / f"r_{i}.png", img)
            images.append(img)
            frames.append(
                {
                    "file_path": f"./{split}/r_{i}",
                    "rotation": 0.0,
                    "transform_matrix": opencv_to_opengl(c2w_cv[i]).tolist(),
                }
            )
        (folder / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": ANGLE, "frames": frames}))
        truth[split] = (c2w_cv, np.stack(images))
    return truth


def _composite(rgba, bg):
    a = rgba[..., 3:4].astype(np.float64) / 255
    return (rgba[..., :3] / 255 * a + np.asarray(bg) * (1 - a)) * 255


# ----------------------------------------------------------------------------- Blender


def test_blender_cameras_and_compositing(tmp_path):
    truth = make_blender(tmp_path)
    for bg in ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0)):
        scene = load_blender(tmp_path, background=bg)
        f = 0.5 * 40 / math.tan(0.5 * ANGLE)
        for split in ("train", "val", "test"):
            v = scene.splits[split]
            c2w, rgba = truth[split]
            np.testing.assert_allclose(v.c2w, c2w, atol=1e-6)  # OpenGL -> OpenCV undone exactly
            np.testing.assert_allclose(v.K, np.repeat(intrinsics_matrix(f, f, 20, 15)[None], len(v), 0), rtol=1e-6)
            np.testing.assert_allclose(v.images.astype(float), _composite(rgba, bg), atol=1.01)
            assert v.names == [f"{split}/r_{i}" for i in range(len(v))]
        assert (scene.train.width, scene.train.height) == (40, 30)
    # transparent top rows are exactly the background
    assert (load_blender(tmp_path, background=(1.0, 1.0, 1.0)).train.images[:, :7] == 255).all()


def test_blender_camera_axes_see_the_origin(tmp_path):
    """The cameras look at the origin: its projection lands at the image centre."""
    make_blender(tmp_path)
    scene = load_scene(tmp_path / "transforms_val.json")  # a json file selects its folder
    for c2w, K in zip(scene.train.c2w, scene.train.K):
        x = np.linalg.inv(c2w.astype(np.float64)) @ np.array([0, 0, 0, 1.0])
        assert x[2] > 0  # in front (+z forward)
        uv = (K @ x[:3])[:2] / x[2]
        np.testing.assert_allclose(uv, [20, 15], atol=1e-3)


def test_focal_from_angle_lego():
    # lego: 800 px wide, camera_angle_x 0.6911 -> 1111.11 px (the course's 277.78 at 200 px)
    assert focal_from_angle(ANGLE, 800) == pytest.approx(1111.1111, rel=1e-6)
    assert focal_from_angle(ANGLE, 200) == pytest.approx(277.77777, rel=1e-6)


def test_blender_resize_scales_K(tmp_path):
    make_blender(tmp_path, size=(40, 30))
    full = load_blender(tmp_path)
    half = load_blender(tmp_path, downscale=2)
    assert (half.train.width, half.train.height) == (20, 15)
    assert half.train.images.shape == (3, 15, 20, 3)
    np.testing.assert_allclose(half.train.K[:, :2], full.train.K[:, :2] / 2, rtol=1e-6)
    np.testing.assert_allclose(half.train.c2w, full.train.c2w)
    # BOX resampling by 2 = mean of 2x2 blocks
    blocks = full.train.images.astype(float).reshape(3, 15, 2, 20, 2, 3).mean((2, 4))
    assert np.abs(half.train.images - blocks).max() <= 1.0


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda d: d.pop("camera_angle_x"), "camera_angle_x"),
        (lambda d: d["frames"][1].pop("transform_matrix"), "frames[1]"),
        (lambda d: d["frames"][0].update(transform_matrix=[[1, 0], [0, 1]]), "shape"),
        (lambda d: d["frames"][0].update(transform_matrix=np.diag([2.0, 2, 2, 1]).tolist()), "not rigid"),
        (
            lambda d: d["frames"][0].update(file_path="./train/missing"),
            "frame image not found: looked for 'train/missing' and it with an image suffix",
        ),
        (
            lambda d: d["frames"][0].update(file_path="train/gone.png"),
            "frame image not found: looked for 'train/gone.png' in",
        ),
        (lambda d: d.update(frames=[]), "empty"),
    ],
)
def test_blender_bad_input_is_one_line(tmp_path, edit, message):
    make_blender(tmp_path)
    p = tmp_path / "transforms_train.json"
    d = json.loads(p.read_text())
    edit(d)
    p.write_text(json.dumps(d))
    with pytest.raises(NerfkitError) as e:
        load_blender(tmp_path)
    assert message in str(e.value) and "\n" not in str(e.value)
    assert "transforms_train.json" in str(e.value) or "missing" in str(e.value) or "gone" in str(e.value)


def test_blender_truncated_json(tmp_path):
    make_blender(tmp_path)
    p = tmp_path / "transforms_train.json"
    p.write_text(p.read_text()[:50])
    with pytest.raises(NerfkitError, match="not valid JSON"):
        load_scene(tmp_path)


# ----------------------------------------------------------------------------- dispatcher


def test_detect_format(tmp_path):
    make_blender(tmp_path / "b")
    assert detect_format(tmp_path / "b") == "blender"
    assert detect_format(tmp_path / "b" / "transforms_train.json") == "blender"
    save_npz(sphere_scene(n_train=3, n_val=1, size=8), tmp_path / "n" / "scene.npz")
    assert detect_format(tmp_path / "n" / "scene.npz") == "npz"
    assert detect_format(tmp_path / "n") == "npz"  # a folder holding one npz
    (tmp_path / "t").mkdir()
    (tmp_path / "t" / "transforms.json").write_text("{}")
    assert detect_format(tmp_path / "t") == "transforms"
    for bad in (tmp_path / "nothing", tmp_path / "b" / "train"):
        with pytest.raises(NerfkitError):
            detect_format(bad)
    (tmp_path / "n" / "other.npz").write_bytes(b"")
    with pytest.raises(NerfkitError, match="2 .npz files"):
        load_scene(tmp_path / "n")


def test_blender_to_npz_round_trip(tmp_path):
    make_blender(tmp_path / "b")
    scene = load_scene(tmp_path / "b")
    assert main(["convert", str(tmp_path / "b"), "--to", str(tmp_path / "out.npz")]) == 0
    back = load_scene(tmp_path / "out.npz")
    for split in ("train", "val", "test"):
        a, b = scene.splits[split], back.splits[split]
        np.testing.assert_allclose(b.c2w, a.c2w, atol=1e-6)
        np.testing.assert_allclose(b.K, a.K, rtol=1e-6)
        np.testing.assert_array_equal(b.images, a.images)
        assert b.names == a.names
    assert (back.near, back.far) == pytest.approx((scene.near, scene.far))


def test_blender_views_of_one_name_in_each_split_convert_to_transforms_and_colmap(tmp_path):
    # train/r_0, val/r_0 and test/r_0 share their last component: each gets its own file
    from nerfkit.io.paths import distinct_names

    assert distinct_names([("train", "train/r_0"), ("val", "val/r_0"), ("val", "val/r_1")]) == [
        "train_r_0",
        "val_r_0",
        "r_1",
    ]
    assert distinct_names([("val", "IMG_0.png"), ("test", "IMG_0.png")]) == ["val_IMG_0.png", "test_IMG_0.png"]
    make_blender(tmp_path / "b")
    scene = load_scene(tmp_path / "b")
    for fmt in ("transforms", "colmap"):
        assert main(["convert", str(tmp_path / "b"), "--to", str(tmp_path / fmt), "--format", fmt]) == 0
        back = load_scene(tmp_path / fmt)
        views = {n: img for v in back.splits.values() if len(v) for n, img in zip(v.names, v.images)}
        for v in scene.splits.values():
            for name, image in zip(v.names, v.images):
                flat = name.replace("/", "_") + ("" if name.endswith(".png") else ".png")
                plain = name.rsplit("/", 1)[-1] + ("" if name.endswith(".png") else ".png")
                for key in (name, flat, plain):  # (transforms.json keeps the name; COLMAP names the file)
                    if key in views:
                        np.testing.assert_array_equal(views.pop(key), image)
        assert not views  # every view read back is one written


def test_convert_resize_and_refuses_overwrite(tmp_path, capsys):
    make_blender(tmp_path / "b", size=(40, 30))
    out = tmp_path / "small.npz"
    assert main(["convert", str(tmp_path / "b"), "--to", str(out), "--size", "20", "--background", "white"]) == 0
    s = load_npz(out)
    assert (s.train.width, s.train.height) == (20, 15)
    assert s.train.images[:, :3].min() == 255  # transparent rows on white
    assert main(["convert", str(tmp_path / "b"), "--to", str(out)]) == 2  # exists, no --force
    assert "already exists" in capsys.readouterr().err
    assert main(["convert", str(tmp_path / "b"), "--to", str(out), "--background", "pink", "--force"]) == 2
    assert main(["convert", str(tmp_path / "b"), "--to", str(tmp_path / "x.npz"), "--format", "colmap"]) == 2
    capsys.readouterr()
    assert main(["convert", str(tmp_path / "b"), "--to", str(tmp_path / "x.ply")]) == 2  # a file name, not a folder
    assert "looks like a .ply file, but convert writes a .npz file or a folder" in capsys.readouterr().err
    assert not (tmp_path / "x.ply").exists()


def test_npz_to_transforms_round_trip(tmp_path):
    pytest.importorskip("nerfkit.data.nerfstudio")
    scene = sphere_scene(n_train=4, n_val=2, size=16, n_test=3)
    save_npz(scene, tmp_path / "s.npz")
    assert main(["convert", str(tmp_path / "s.npz"), "--to", str(tmp_path / "ns")]) == 0
    back = load_scene(tmp_path / "ns")
    for split in ("train", "val"):
        a, b = scene.splits[split], back.splits[split]
        np.testing.assert_allclose(b.c2w, a.c2w, atol=1e-5)
        np.testing.assert_allclose(b.K, a.K, rtol=1e-5)
        np.testing.assert_array_equal(b.images, a.images)


@pytest.mark.parametrize("fmt", ["transforms", "colmap"])
def test_force_replaces_an_earlier_conversion_but_never_the_users_files(tmp_path, capsys, fmt):
    pytest.importorskip("nerfkit.data.nerfstudio" if fmt == "transforms" else "pycolmap")
    save_npz(sphere_scene(n_train=3, n_val=1, size=16), tmp_path / "s.npz")
    out = tmp_path / "out"
    convert = ["convert", str(tmp_path / "s.npz"), "--to", str(out), "--format", fmt]
    assert main(convert) == 0
    assert main([*convert, "--force"]) == 0  # its own earlier output: replaced
    (out / "images" / "holiday.jpg").write_bytes(b"the user's photo")
    assert main([*convert, "--force"]) == 2
    err = capsys.readouterr().err
    assert "holds files that no earlier output of nerfkit's wrote there (holiday.jpg)" in err
    assert "--force replaces only what nerfkit wrote" in err
    assert (out / "images" / "holiday.jpg").read_bytes() == b"the user's photo"
    fresh = tmp_path / "Documents"  # a folder of the user's, named as the output
    (fresh / "images").mkdir(parents=True)
    (fresh / "images" / "IMG_1.jpg").write_bytes(b"another photo")
    assert main(["convert", str(tmp_path / "s.npz"), "--to", str(fresh), "--format", fmt, "--force"]) == 2
    assert (fresh / "images" / "IMG_1.jpg").exists()


def test_convert_sets_the_depth_range(tmp_path, capsys):
    """A depth range given on the command line replaces the dataset's, in both formats."""
    scene = sphere_scene(n_train=4, n_val=2, size=16)
    save_npz(scene, tmp_path / "s.npz")
    assert (scene.near, scene.far) != (1.5, 7.0)
    for out in ("c.npz", "c_ns"):
        assert (
            main(["convert", str(tmp_path / "s.npz"), "--to", str(tmp_path / out), "--near", "1.5", "--far", "7"]) == 0
        )
        back = load_scene(tmp_path / out)
        assert (back.near, back.far) == (1.5, 7.0)
        np.testing.assert_array_equal(back.train.images, scene.train.images)
    assert main(["convert", str(tmp_path / "s.npz"), "--to", str(tmp_path / "n.npz"), "--near", "1"]) == 0
    assert (load_scene(tmp_path / "n.npz").near, load_scene(tmp_path / "n.npz").far) == (1.0, scene.far)  # one end
    capsys.readouterr()
    assert (
        main(["convert", str(tmp_path / "s.npz"), "--to", str(tmp_path / "bad.npz"), "--near", "7", "--far", "6"]) == 2
    )
    assert "near=7.0 and far=6.0: need 0 <= near < far" in capsys.readouterr().err
    assert not (tmp_path / "bad.npz").exists()
    assert (
        main(["convert", str(tmp_path / "s.npz"), "--to", str(tmp_path / "cm"), "--format", "colmap", "--near", "2"])
        == 2
    )
    assert "keeps no depth range" in capsys.readouterr().err


# ----------------------------------------------------------------------------- resampling


def test_output_size_rules():
    assert output_size(400, 300) == (400, 300)
    assert output_size(400, 300, size=200) == (200, 150)
    assert output_size(400, 300, downscale=4) == (100, 75)
    assert output_size(286, 214, downscale=2) == (143, 107)
    assert output_size(400, 300, downscale=1) == (400, 300)
    for kw in ({"size": 0}, {"downscale": 0}, {"downscale": -1}, {"size": 10, "downscale": 2}):
        with pytest.raises(NerfkitError):
            output_size(400, 300, **kw)
    # a divisor of at least 1: it never enlarges (1e-300 asked for 1e302-pixel images)
    for d, problem in (
        (0.5, "0.5 is below the minimum 1"),
        (1e-300, "1e-300 is below the minimum 1"),
        (float("nan"), "'nan' is not a finite number"),
        (float("inf"), "'inf' is not a finite number"),
    ):
        with pytest.raises(NerfkitError) as e:
            output_size(400, 300, downscale=d)
        assert str(e.value).startswith(f"--downscale: {problem}. "), str(e.value)
    # a view of a few pixels holds no scene: the largest divisor (or smallest size) that keeps 8
    assert output_size(400, 300, downscale=37.5) == (11, 8)
    for kw, hint in (({"downscale": 1000}, "Use --downscale 37.5 or less"), ({"size": 9}, "Use --size 11 or more")):
        with pytest.raises(NerfkitError, match="too small to hold a scene") as e:
            output_size(400, 300, **kw)
        assert str(e.value).endswith(hint)
    assert output_size(6, 4, downscale=2) == (3, 2)  # images already that small: as asked


def test_scaled_K_matches_resampled_pixels():
    """Rendering at 32 px with the scaled K matches area-downsampling a 128 px render much
    better than the classic half-pixel mistake (cx' = (cx + 0.5) s - 0.5 in this convention)."""
    K128 = intrinsics_matrix(140.0, 140.0, 64.0, 64.0)
    c2w = look_at(np.array([0.3, -3.5, 1.2]), np.zeros(3), np.array([0, 0, 1.0])).astype(np.float32)
    down = render_sphere(K128, c2w, 128, 128).astype(float).reshape(32, 4, 32, 4, 3).mean((1, 3))

    def err(K):
        return np.abs(render_sphere(K, c2w, 32, 32).astype(float) - down).mean()

    K32 = scale_intrinsics(K128, 128, 128, 32, 32)
    np.testing.assert_allclose(K32, intrinsics_matrix(35.0, 35.0, 16.0, 16.0))
    wrong = K32.copy()
    wrong[:2, 2] = (64.0 + 0.5) / 4 - 0.5  # 15.625: off by 3/8 px
    wrong_other_way = K32.copy()
    wrong_other_way[:2, 2] += 0.375
    assert err(K32) < 0.7 * min(err(wrong), err(wrong_other_way))


def test_resample_scene_projects_consistently():
    scene = sphere_scene(n_train=3, n_val=1, size=32, n_test=2)
    small = resample_scene(scene, size=20)
    assert (small.train.width, small.train.height) == (20, 20)
    assert small.test.images is None and small.test.K.shape == (2, 3, 3)
    X = np.array([0.3, -0.2, 0.4, 1.0])
    for v0, v1 in ((scene.train, small.train), (scene.test, small.test)):
        for i in range(len(v0)):
            x = np.linalg.inv(v0.c2w[i]) @ X
            uv0 = (v0.K[i] @ x[:3])[:2] / x[2]
            uv1 = (v1.K[i] @ x[:3])[:2] / x[2]
            np.testing.assert_allclose(uv1, uv0 * 20 / 32, rtol=1e-5)
    assert resample_scene(scene) is scene


def test_a_run_sees_rgba_images_on_its_own_background(tmp_path, capsys):
    """`train --background white` on RGBA images composites them on white, and so does every
    command that reads the run's dataset again (the run's fingerprint must match)."""
    from nerfkit.commands._common import scene_for_run
    from nerfkit.train.checkpoint import read_run

    make_blender(tmp_path / "rgba", n=(3, 1, 1))
    run = tmp_path / "run"
    assert (
        main(
            [
                "train",
                "--data",
                str(tmp_path / "rgba"),
                "--out",
                str(run),
                "--steps",
                "2",
                "--batch-rays",
                "64",
                "--background",
                "white",
                *tiny_vanilla(samples=4, width=8),
            ]
        )
        == 0
    )
    scene = scene_for_run(read_run(run), None)  # raises if training saw other pixels
    assert (scene.train.images[:, :7] == 255).all()  # the transparent top rows
    assert (scene_for_run(read_run(run), str(tmp_path / "rgba"), need="val").val.images[:, :7] == 255).all()


@pytest.mark.parametrize("damage", ["header", "cut"])
def test_a_damaged_ply_is_a_clear_error_naming_it_for_points_and_splats(tmp_path, damage):
    from nerfkit.data.ply import read_points_ply, write_points_ply
    from nerfkit.splat_files import read_splat_ply

    path = tmp_path / "points.ply"
    write_points_ply(path, np.random.default_rng(0).normal(size=(50, 3)), np.full((50, 3), 7, np.uint8))
    xyz, rgb = read_points_ply(path)  # the intact file reads back
    assert xyz.shape == (50, 3) and rgb is not None and (rgb == 7).all()
    data = path.read_bytes()
    # a header plyfile cannot parse, or the binary body cut short
    path.write_bytes(b"ply\nformat garbage\n" if damage == "header" else data[: len(data) - 100])
    for read in (read_points_ply, read_splat_ply):
        with pytest.raises(NerfkitError, match=r"points\.ply: not a readable PLY"):
            read(path)


def test_views_of_two_sizes_are_refused_by_the_writers_whose_readers_take_one(tmp_path, capsys):
    from dataclasses import replace

    scene = sphere_scene(n_train=4, n_val=2, size=16)
    scene.val = replace(scene.val, images=scene.val.images[:, :12], height=12)
    with pytest.raises(NerfkitError, match="the val images are 16x12, the training images 16x16"):
        save_npz(scene, tmp_path / "x.npz")
    assert not (tmp_path / "x.npz").exists()
    write_transforms_json(scene, tmp_path / "ns")  # transforms.json holds a size per frame
    assert main(["convert", str(tmp_path / "ns"), "--to", str(tmp_path / "cm"), "--format", "colmap"]) == 2
    assert "the views' images are of 2 sizes (16x12, 16x16)" in capsys.readouterr().err
