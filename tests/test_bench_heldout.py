"""The held-out benchmark's pure helpers (benchmarks/heldout.py): the downscale the course
npz was made with, the Blender val views it reads, the scene training gets, the options."""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from nerfkit.cameras import opengl_to_opencv
from nerfkit.data.blender import load_blender
from nerfkit.data.scene import Scene, Views
from nerfkit.errors import NerfkitError

_spec = importlib.util.spec_from_file_location(
    "heldout", Path(__file__).resolve().parents[1] / "benchmarks" / "heldout.py"
)
heldout = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("heldout", heldout)  # dataclasses look their module up
_spec.loader.exec_module(heldout)


def test_downscale_averages_colour_and_alpha_apart_then_composites_on_black():
    # one 2x2 block: red opaque, blue transparent, white opaque, black transparent
    rgba = np.array([[[255, 0, 0, 255], [0, 0, 255, 0]], [[255, 255, 255, 255], [0, 0, 0, 0]]], np.uint8)
    out = heldout.downscale_rgba(rgba, 1, 1)
    # colour means (0.5, 0.25, 0.5) times the alpha mean 0.5
    assert out.shape == (1, 1, 3) and out.dtype == np.uint8
    assert out[0, 0].tolist() == [64, 32, 64]
    premultiplied = (rgba[..., :3] * (rgba[..., 3:] / 255.0)).mean((0, 1))
    assert not np.allclose(out[0, 0], premultiplied.round(), atol=1)  # a compositor's average differs


def test_downscale_of_opaque_or_rgb_images_is_the_block_mean():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (6, 4, 3), dtype=np.uint8)
    want = np.round(rgb.astype(np.float64).reshape(3, 2, 2, 2, 3).mean((1, 3))).astype(np.uint8)
    assert np.abs(heldout.downscale_rgba(rgb, 2, 3).astype(int) - want).max() <= 1
    opaque = np.concatenate([rgb, np.full((6, 4, 1), 255, np.uint8)], axis=-1)
    assert np.array_equal(heldout.downscale_rgba(opaque, 2, 3), heldout.downscale_rgba(rgb, 2, 3))
    with pytest.raises(ValueError):
        heldout.downscale_rgba(rgb[..., 0], 2, 3)


def _blender_folder(folder: Path, n: int = 3, size: int = 32) -> None:
    rng = np.random.default_rng(1)
    (folder / "val").mkdir(parents=True)
    frames = []
    for i in range(n):
        angle = 2 * math.pi * i / n
        eye = np.array([4 * math.cos(angle), 4 * math.sin(angle), 1.0])
        back = eye / np.linalg.norm(eye)  # OpenGL: the camera looks along -z, z points back at the eye
        right = np.cross([0.0, 0.0, 1.0], back)
        right /= np.linalg.norm(right)
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(back, right), back, eye
        frames.append({"file_path": f"./val/r_{i}", "transform_matrix": m.tolist()})
        Image.fromarray(rng.integers(0, 256, (size, size, 4), dtype=np.uint8), "RGBA").save(
            folder / "val" / f"r_{i}.png"
        )
    (folder / "transforms_val.json").write_text(json.dumps({"camera_angle_x": 0.69, "frames": frames}))
    # a train split for nerfkit's loader, the same views
    (folder / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.69, "frames": frames}))


def test_blender_views_have_the_loaders_cameras_and_the_npz_downscale(tmp_path):
    _blender_folder(tmp_path)
    views = heldout.blender_views(tmp_path, "val", 16, 16)
    loaded = load_blender(tmp_path, size=16)  # OpenGL -> OpenCV, K scaled: the project's reading
    assert (views.width, views.height, len(views)) == (16, 16, 3)
    np.testing.assert_allclose(views.c2w, loaded.val.c2w, atol=1e-6)
    np.testing.assert_allclose(views.K, loaded.val.K, rtol=1e-6)
    assert views.K[0, 0, 0] == pytest.approx(0.5 * 32 / math.tan(0.345) / 2, rel=1e-6)
    m = np.array(json.loads((tmp_path / "transforms_val.json").read_text())["frames"][1]["transform_matrix"])
    np.testing.assert_allclose(views.c2w[1], opengl_to_opencv(m), atol=1e-6)
    rgba = np.asarray(Image.open(tmp_path / "val" / "r_2.png"))
    assert np.array_equal(views.images[2], heldout.downscale_rgba(rgba, 16, 16))
    assert views.names == ["val/r_0", "val/r_1", "val/r_2"]
    # matching views to themselves in another order finds the permutation, poses equal
    order = [2, 0, 1]
    matched = heldout.match_views(views, views.subset(order))
    assert [m["match"] for m in matched] == [1, 2, 0]
    assert all(m["pose_diff"] == 0 and m["psnr"] == math.inf for m in matched)


def test_blender_views_refuse_a_folder_without_the_split(tmp_path):
    with pytest.raises(NerfkitError, match="transforms_val.json"):
        heldout.blender_views(tmp_path, "val", 4, 4)


def test_training_gets_no_heldout_view():
    def views(n, images=True):
        return Views(
            np.tile(np.eye(4, dtype=np.float32), (n, 1, 1)),
            np.tile(np.eye(3, dtype=np.float32), (n, 1, 1)),
            6,
            5,
            np.zeros((n, 5, 6, 3), np.uint8) if images else None,
        )

    scene = Scene(views(4), views(2), views(3, images=False), 1.0, 5.0)
    train = heldout.without_heldout(scene)
    assert train.train is scene.train
    assert len(train.val) == 0 and len(train.test) == 0 and not train.val.has_images
    assert (train.val.width, train.val.height) == (6, 5)
    assert len(scene.val) == 2 and len(scene.test) == 3  # the original keeps them for scoring


def test_options():
    assert heldout.parse_list("60, 300,", float) == [60.0, 300.0]
    with pytest.raises(NerfkitError, match="--seconds: 'abc' is not a float"):
        heldout.parse_list("60,abc", float, "--seconds")
    with pytest.raises(NerfkitError, match="--models: ' , ' names nothing"):
        heldout.parse_list(" , ", str, "--models")
    assert heldout.parse_models("fast, splat", []) == ["fast", "splat"]
    assert heldout.parse_models("splat", ["splat+x:lr=4"]) == ["splat"]
    assert heldout.parse_models("", ["splat+x:lr=4"]) == []  # only the variant
    with pytest.raises(NerfkitError, match="--models: '' names nothing"):
        heldout.parse_models("", [])
    assert heldout.parse_captures(["steve=a/b", "labubu=c"]) == {"steve": Path("a/b"), "labubu": Path("c")}
    for bad, message in (
        (["steve"], "'steve' is not NAME=PATH"),
        (["=a"], "'=a' is not NAME=PATH"),
        (["steve=a", "steve=b"], "the name 'steve' is taken"),  # twice
        (["flower=a"], "the name 'flower' is taken"),  # a scene's
    ):
        with pytest.raises(NerfkitError, match=f"--capture: {message}"):
            heldout.parse_captures(bad)
    have = {"lego200": True, "lego400": True, "flower": False}
    assert heldout.choose_scenes(None, have, ["steve"]) == ["lego200", "lego400", "steve"]
    assert heldout.choose_scenes(["captures", "lego400", "steve"], have, ["steve", "x"]) == ["steve", "x", "lego400"]
    with pytest.raises(NerfkitError, match="--llff"):
        heldout.choose_scenes(["flower"], have, [])
    with pytest.raises(NerfkitError, match="unknown scene"):
        heldout.choose_scenes(["chair"], have, [])
    with pytest.raises(NerfkitError, match="no scene"):
        heldout.choose_scenes(None, {k: False for k in have}, [])
    have = {**have, **dict.fromkeys(heldout.FORWARD, True)}
    assert heldout.choose_scenes(None, have, []) == ["lego200", "lego400", "flower"]  # the subsets on request
    assert heldout.choose_scenes(["forward", "flower17"], have, []) == ["flower", "flower17", "flower17b"]
    with pytest.raises(NerfkitError, match="--capture: the name 'forward' is taken"):  # a group of scenes
        heldout.parse_captures(["forward=a"])
    assert heldout.budget_label(60.0, None) == "60 s" and heldout.budget_label(None, 100) == "100 steps"


def test_table_shows_the_npz_val_figure_only_where_there_is_one():
    row = {
        "scene": "flower",
        "model": "fast",
        "budget": "5 s",
        "steps": 9,
        "psnr": 12.345,
        "ssim": 0.4,
        "fps": 2.0,
        "model_mb": 1.5,
    }
    text = heldout.markdown_table([{**row, "scene": "lego200", "psnr_npz_val": 13.0}, row])
    lines = text.splitlines()
    assert lines[2].endswith("| 12.35 | 0.400 | 2.0 | 1.50 | 13.00 |")
    assert lines[3].endswith("| 1.50 | - |")


def test_a_variant_changes_the_named_settings_in_whichever_config_has_them():
    from nerfkit.models.fast_config import FastConfig
    from nerfkit.train.config import TrainConfig

    label, base, changes = heldout.parse_variant("fast+tv:tv_weight=1e-4,lr=0.02,rgb_loss=charbonnier")
    assert (label, base) == ("fast+tv", "fast")
    assert changes == {"tv_weight": 1e-4, "lr": 0.02, "rgb_loss": "charbonnier"}
    cfg, model_cfg = heldout.apply_changes(TrainConfig(), FastConfig(), changes, label)
    assert (model_cfg.tv_weight, model_cfg.rgb_loss, cfg.lr) == (1e-4, "charbonnier", 0.02)
    assert TrainConfig().lr != 0.02 and FastConfig().tv_weight != 1e-4
    with pytest.raises(NerfkitError, match="no setting named 'nope'"):
        heldout.apply_changes(TrainConfig(), FastConfig(), {"nope": 1}, label)
    # a value may hold commas: a comma starts a new setting only before NAME=
    _, _, changes = heldout.parse_variant("fast+g:upsample_steps='60,300,1000',resolutions='32,64',lr=0.1")
    assert changes == {"upsample_steps": "60,300,1000", "resolutions": "32,64", "lr": 0.1}
    for bad in ("fast", "fast+x:", "fast+x:tv_weight"):
        with pytest.raises(NerfkitError):
            heldout.parse_variant(bad)


def test_even_subsets_spread_over_the_photos_and_differ_by_offset():
    # pick i of k = 17 from n = 29 at offset 0 is floor(29 i / 17) (in integers: exact)
    assert heldout.even_subset(29, 17).tolist() == [i * 29 // 17 for i in range(17)]
    a, b = heldout.even_subset(29, 17, 0.0), heldout.even_subset(29, 17, 0.5)
    assert b.tolist() == [(2 * i + 1) * 29 // 34 for i in range(17)] and b[-1] == 28
    # The two sparse cases share few photos. With r = 29 i mod 17, b_i = floor(29 i / 17 + 14.5 / 17)
    # is a_i when r < 2.5, else a_i + 1, which is a_{i+1} when r < 5 (a_{i+1} = a_i + 1 + [r >= 5]):
    # b_i is one of a's photos exactly when r is 0..4, and r takes each residue once (29, 17 coprime)
    assert sorted(set(a) & set(b)) == [0, 5, 11, 17, 23]  # i = 0, 3, 6, 10, 13: r = 0, 2, 4, 1, 3
    for n, k, off in ((29, 17, 0.0), (29, 17, 0.5), (10, 10, 0.9), (7, 1, 0.5), (100, 3, 0.99)):
        picks = heldout.even_subset(n, k, off)
        assert len(picks) == k and picks.min() >= 0 and picks.max() < n and np.all(np.diff(picks) > 0)
        gaps = np.diff(picks, append=picks[0] + n)
        assert gaps.max() - gaps.min() <= 1  # even: gaps of floor(n/k) or one more
    assert heldout.even_subset(5, 5).tolist() == [0, 1, 2, 3, 4]
    for bad in ((5, 0, 0.0), (5, 6, 0.0), (5, 2, 1.0), (5, 2, -0.1)):
        with pytest.raises(ValueError):
            heldout.even_subset(*bad)


def test_flower_subsets_train_on_fewer_photos_and_score_the_same_ones(tmp_path):
    from test_llff import forward_facing_cameras, write_llff

    c2w = forward_facing_cameras(34)  # as many photos as flower: 5 held out, 29 to train on
    bounds = np.stack([np.full(34, 2.0), np.full(34, 6.0)], axis=1)
    folder = write_llff(tmp_path / "ff", c2w, bounds)
    full = heldout.load_flower(folder, 1.0)
    assert len(full.train.train) == 29 and len(full.heldout) == 5 and len(full.train.val) == 0
    for name, (k, offset) in heldout.FLOWER_SUBSETS.items():
        sub = heldout.load_flower(folder, 1.0, name)
        assert sub.name == name and len(sub.train.train) == k and len(sub.train.val) == 0
        assert sub.heldout.names == full.heldout.names
        np.testing.assert_array_equal(sub.heldout.images, full.heldout.images)
        picks = heldout.even_subset(29, k, offset)
        assert sub.train.train.names == [full.train.train.names[i] for i in picks]
        np.testing.assert_array_equal(sub.train.train.c2w, full.train.train.c2w[picks])
    few = write_llff(tmp_path / "few", c2w[:12], bounds[:12])  # 10 to train on: too few for 17
    with pytest.raises(NerfkitError, match="keeps 17"):
        heldout.load_flower(few, 1.0, "flower17")
