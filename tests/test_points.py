"""Sparse 3D points: stored in the dataset formats, triangulated from posed views, and
used to start Gaussian splatting."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
import torch

from nerfkit.cameras import intrinsics_matrix, look_at
from nerfkit.data.npz import load_npz, save_npz
from nerfkit.data.scene import Scene, Views
from nerfkit.data.synthetic import tabletop_scene
from nerfkit.errors import NerfkitError


def _scene_with_points(m: int = 50, seed: int = 0) -> Scene:
    scene = tabletop_scene(n_train=4, n_val=1, size=16)
    rng = np.random.default_rng(seed)
    scene.points = rng.normal(size=(m, 3)).astype(np.float32)
    scene.point_colors = rng.integers(0, 256, (m, 3)).astype(np.uint8)
    return scene


def test_npz_round_trip_keeps_points(tmp_path):
    scene = _scene_with_points()
    save_npz(scene, tmp_path / "d.npz")
    back = load_npz(tmp_path / "d.npz")
    np.testing.assert_array_equal(back.points, scene.points)
    np.testing.assert_array_equal(back.point_colors, scene.point_colors)
    assert load_npz(_without_points(scene, tmp_path)).points is None


def _without_points(scene: Scene, tmp_path) -> str:
    scene.points = scene.point_colors = None
    save_npz(scene, tmp_path / "plain.npz")
    return str(tmp_path / "plain.npz")


def test_transforms_json_writes_nerfstudio_sparse_pc_ply(tmp_path):
    from plyfile import PlyData

    from nerfkit.data.nerfstudio import load_transforms_json, write_transforms_json

    scene = _scene_with_points()
    path = write_transforms_json(scene, tmp_path)
    import json

    assert json.loads(path.read_text())["ply_file_path"] == "sparse_pc.ply"
    v = PlyData.read(str(tmp_path / "sparse_pc.ply"))["vertex"]
    assert {p.name for p in v.properties} == {"x", "y", "z", "red", "green", "blue"}
    back = load_transforms_json(path)
    np.testing.assert_allclose(back.points, scene.points, rtol=0, atol=0)
    np.testing.assert_array_equal(back.point_colors, scene.point_colors)


def test_ply_file_path_outside_the_dataset_is_refused(tmp_path):
    import json

    from nerfkit.data.nerfstudio import load_transforms_json, write_transforms_json

    scene = _scene_with_points()
    path = write_transforms_json(scene, tmp_path / "d")
    data = json.loads(path.read_text())
    for bad, why in (("../elsewhere.ply", "outside"), ("missing.ply", "does not exist"), (3, "expected a file")):
        data["ply_file_path"] = bad
        path.write_text(json.dumps(data))
        with pytest.raises(NerfkitError, match=why):
            load_transforms_json(path)


@pytest.mark.parametrize(
    "xyz, rgb, why",
    [
        (np.array([[0.0, np.nan, 0.0]]), None, "non-finite"),
        (np.zeros((3, 2)), None, r"\(m, 3\)"),
        (np.zeros((3, 3)), np.zeros((2, 3), np.uint8), "colours"),
        (np.zeros((3, 3)), np.full((3, 3), 300), "colours"),
    ],
)
def test_bad_points_get_a_clear_error(tmp_path, xyz, rgb, why):
    scene = _scene_with_points()
    arrays = dict(np.load(_npz(scene, tmp_path)))
    arrays["points_xyz"] = xyz
    if rgb is None:
        arrays.pop("points_rgb")
    else:
        arrays["points_rgb"] = rgb
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(NerfkitError, match=why):
        load_npz(tmp_path / "bad.npz")


def _npz(scene: Scene, tmp_path) -> str:
    save_npz(scene, tmp_path / "ok.npz")
    return str(tmp_path / "ok.npz")


def test_camera_neighbours_join_each_camera_to_its_nearest():
    from nerfkit.capture.points import camera_neighbours

    n = 12
    ang = np.arange(n) * 2 * np.pi / n
    eyes = np.stack([3 * np.cos(ang), 3 * np.sin(ang), np.ones(n)], 1)
    c2w = np.stack([look_at(e, np.zeros(3), np.array([0.0, 0, 1])) for e in eyes])
    pairs = camera_neighbours(c2w, 2)
    for i in range(n):  # the two ring neighbours, and nobody further
        assert (min(i, (i + 1) % n), max(i, (i + 1) % n)) in pairs
    assert len(pairs) == n and all(min((j - i) % n, (i - j) % n) == 1 for i, j in pairs)


def _plane_views(n: int, size: tuple[int, int] = (200, 150), seed: int = 0) -> tuple[Views, np.ndarray]:
    """Photos of a textured square (z = 0, side 2) from cameras above it; the texture."""
    import cv2

    rng = np.random.default_rng(seed)
    tex = cv2.resize(rng.integers(0, 256, (48, 48, 3)).astype(np.uint8), (512, 512), interpolation=cv2.INTER_NEAREST)
    tex = cv2.GaussianBlur(tex, (5, 5), 1.0)
    w, h = size
    K = intrinsics_matrix(180.0, 180.0, w / 2, h / 2)
    c2ws, images = [], []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = np.array([0.6 * np.cos(a), 0.6 * np.sin(a), 2.2])
        c2w = look_at(eye, np.array([0.1 * np.cos(a), 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
        u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1) @ c2w[:3, :3].T
        t = -c2w[2, 3] / d[..., 2]
        x, y = c2w[0, 3] + t * d[..., 0], c2w[1, 3] + t * d[..., 1]
        mx, my = ((x + 1) / 2 * 512 - 0.5).astype(np.float32), ((1 - (y + 1) / 2) * 512 - 0.5).astype(np.float32)
        images.append(cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0))
        c2ws.append(c2w)
    return Views(
        np.stack(c2ws).astype(np.float32), np.repeat(K[None], n, 0).astype(np.float32), w, h, np.stack(images)
    ), tex


@pytest.mark.slow
def test_triangulated_points_lie_on_the_photographed_plane_with_its_colours(tmp_path):
    pytest.importorskip("pycolmap")
    from nerfkit.capture.points import triangulate_views

    views, tex = _plane_views(8)
    pts = triangulate_views(views, tmp_path)
    assert len(pts) > 100
    assert np.median(np.abs(pts.xyz[:, 2])) < 0.005 and np.quantile(np.abs(pts.xyz[:, 2]), 0.9) < 0.02
    assert np.abs(pts.xyz[:, :2]).max() < 1.15  # on the square (corners at its edge), not beyond
    col = (1 - (pts.xyz[:, 1] + 1) / 2) * 512, (pts.xyz[:, 0] + 1) / 2 * 512
    truth = tex[np.clip(col[0].astype(int), 0, 511), np.clip(col[1].astype(int), 0, 511)].astype(float)
    assert np.median(np.abs(truth - pts.rgb).mean(1)) < 25  # a random texture differs by ~85
    assert pts.track.min() >= 3 and pts.error.max() <= 2.0
    # who saw each point: the views of its track (a view may give it two features), each with
    # the point in its image
    assert len(pts.seen_by) == len(pts) and all(2 <= len(s) <= t for s, t in zip(pts.seen_by, pts.track))
    for p, seen in zip(pts.xyz.astype(np.float64), pts.seen_by):
        for name in seen:
            c2w = views.c2w[int(name)].astype(np.float64)
            x = c2w[:3, :3].T @ (p - c2w[:3, 3])
            u, v = (views.K[0].astype(np.float64) @ (x / x[2]))[:2]
            assert x[2] > 0 and -1 <= u <= views.width and -1 <= v <= views.height
    assert list(tmp_path.iterdir()) == []  # COLMAP's scratch folder is gone


@pytest.mark.slow
def test_many_views_are_matched_with_their_neighbours_only(tmp_path, monkeypatch):
    pytest.importorskip("pycolmap")
    import nerfkit.capture.points as triangulate

    matched = []
    real = triangulate.match_pairs
    monkeypatch.setattr(triangulate, "EXHAUSTIVE_MAX", 4)  # 8 views are "many"
    monkeypatch.setattr(triangulate, "match_pairs", lambda *a: matched.extend(a[2]) or real(*a))
    views, _ = _plane_views(8)
    pts = triangulate.triangulate_views(views, tmp_path, neighbours=3)
    assert 8 <= len(matched) < 8 * 7 // 2  # each view's 3 nearest, not every pair
    assert len(pts) > 100 and np.median(np.abs(pts.xyz[:, 2])) < 0.005


def test_neighbour_scales_on_a_lattice_are_the_spacing():
    from nerfkit.models.splat import neighbour_scales

    h = 0.25
    g = torch.stack(torch.meshgrid(*[torch.arange(5.0)] * 3, indexing="ij"), -1).reshape(-1, 3) * h
    s = neighbour_scales(g, chunk=17)
    assert torch.allclose(s, torch.full_like(s, h), atol=1e-6)  # every point has >= 3 neighbours at h
    assert neighbour_scales(torch.zeros(1, 3)).shape == (1,)


def test_splat_starts_from_the_dataset_points(monkeypatch):
    from nerfkit.models.base import SceneBounds
    from nerfkit.models.splat import SplatConfig, SplatModel

    scene = _scene_with_points(m=300)
    model = SplatModel(SplatConfig(), SceneBounds.from_scene(scene))
    note = model.init_from_scene(scene, torch.zeros(3))
    assert "300 sparse points" in note
    torch.testing.assert_close(model.means.detach(), torch.as_tensor(scene.points))
    rgb = model.sh_dc.detach()[:, 0] * 0.28209479177387814 + 0.5
    torch.testing.assert_close(rgb, torch.as_tensor(scene.point_colors).float() / 255, atol=1e-5, rtol=0)
    scene.points, scene.point_colors = scene.points[:10], scene.point_colors[:10]  # too few: random in the box
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None)  # (no pycolmap: nothing to triangulate)
    assert "random" in model.init_from_scene(scene, torch.zeros(3))
    model.config.init = "points"
    scene.points = None
    with pytest.raises(NerfkitError, match="no sparse points"):
        model.init_from_scene(scene, torch.zeros(3))


@pytest.mark.slow
def test_splat_without_points_starts_from_points_triangulated_at_the_given_poses(tmp_path):
    pytest.importorskip("pycolmap")
    from nerfkit.models.base import SceneBounds
    from nerfkit.models.splat import SplatConfig, SplatModel

    views, _ = _plane_views(8)
    scene = Scene(views, Views.empty(200, 150), Views.empty(200, 150), 1.0, 4.0)
    model = SplatModel(SplatConfig(init_points=400), SceneBounds.from_scene(scene))
    note = model.init_from_scene(scene, torch.ones(3), tmp_path)  # textured to the border: no hull
    assert "triangulated from the 8 training photos" in note
    z = model.means.detach()[:, 2].abs()
    assert len(z) == 400 and float(z.median()) < 0.01  # on the photographed plane, not in a ball
    assert list(tmp_path.iterdir()) == []  # COLMAP's scratch folder is gone


def test_points_init_subsamples_to_the_requested_count():
    from nerfkit.models.splat import points_init

    xyz = np.arange(30, dtype=np.float32).reshape(10, 3)
    pts, cols = points_init(xyz, None, 4, torch.Generator().manual_seed(0))
    assert pts.shape == (4, 3) and torch.all(cols == 0.5)
    assert {tuple(p.tolist()) for p in pts} <= {tuple(p) for p in xyz.tolist()}
    assert math.isclose(float(points_init(xyz, None, 100, torch.Generator())[0].sum()), float(xyz.sum()))


@pytest.mark.skipif(importlib.util.find_spec("pycolmap") is None, reason="pycolmap not installed")
def test_colmap_leaves_no_log_files_in_the_temporary_folder(tmp_path):
    import os
    import subprocess
    import sys

    def logged(quiet: bool) -> list[str]:
        folder = tmp_path / str(quiet)
        folder.mkdir()
        call = "pycolmap.logging.error('x')"
        code = "import pycolmap\nfrom nerfkit.capture.points import quiet_colmap\n" + (
            f"with quiet_colmap(False):\n    {call}" if quiet else call
        )
        env = {**os.environ, "TMPDIR": str(folder)}
        subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True)
        return [p.name for p in folder.iterdir()]

    assert logged(quiet=False)  # COLMAP's logging library on its own: .HOST.USER.log.ERROR... files
    assert logged(quiet=True) == []
