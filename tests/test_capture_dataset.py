"""The dataset step: undistortion geometry, splits, bounds, and files that load back."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from nerfkit.capture import aruco as A
from nerfkit.capture import synthetic as S
from nerfkit.capture.agreement import measure_agreement
from nerfkit.capture.camera import Camera, nerfkit_K
from nerfkit.capture.dataset import (
    FEW_TRAIN_VIEWS,
    MIN_TAG_SURFACE_POINTS,
    DatasetConfig,
    build_dataset,
    estimate_bounds,
    few_views_note,
    photo_agreement,
    plane_hit_distance,
    split_indices,
    tag_surface_height,
)
from nerfkit.capture.poses import PosedPhoto
from nerfkit.capture.undistort import make_undistorter
from nerfkit.cli import main
from nerfkit.data.colmap import SparsePoints
from nerfkit.data.nerfstudio import load_transforms_json
from nerfkit.data.npz import load_npz
from nerfkit.scene_extent import MIN_OBJECT_POINTS, inside_quads, sphere_radius

TAG = 0.06


@pytest.fixture(scope="module")
def obj():
    return S.cached_capture("object", 10, 1)


@pytest.fixture(scope="module")
def posed(obj, tmp_path_factory):
    folder = tmp_path_factory.mktemp("photos")
    paths = obj.write(folder, quality=98)
    cam = Camera(obj.K, obj.dist, obj.width, obj.height, "truth")
    return [PosedPhoto(n, p, c, 0.1, cam) for n, p, c in zip(obj.names, paths, obj.c2w)]


@given(st.integers(0, 200), st.integers(0, 12), st.integers(0, 12))
def test_split_indices_partition_deterministically(n, val_every, test_every):
    s = split_indices(n, val_every, test_every)
    assert len(s) == n and set(s) <= {"train", "val", "test"}
    assert s == split_indices(n, val_every, test_every)
    if n:
        assert "train" in s
    if val_every == 0:
        assert "val" not in s
    if n >= 20 and val_every >= 2:
        assert s.count("val") == len(range(val_every // 2, n, val_every))


def test_few_views_note_only_below_the_threshold():
    assert few_views_note(FEW_TRAIN_VIEWS) is None and few_views_note(129) is None
    note = few_views_note(20)
    assert note is not None and "20 training photos" in note and "50-100" in note
    from dataclasses import fields

    from nerfkit.models.fast import FastConfig

    assert "--table-cover-weight" in note and "table_cover_weight" in {f.name for f in fields(FastConfig)}


def project_pinhole_nerfkit(K_nk, c2w, X):
    """Pinhole projection in nerfkit's convention (pixel centres at +0.5)."""
    w2c = np.linalg.inv(c2w)
    x = X @ w2c[:3, :3].T + w2c[:3, 3]
    uv = x @ np.asarray(K_nk, np.float64).T
    return uv[:, :2] / uv[:, 2:]


def test_undistorted_views_are_exact_pinhole_images(obj):
    cam = Camera(obj.K, obj.dist, obj.width, obj.height)
    und = make_undistorter(cam)
    # Barrel distortion: the valid rectangle keeps more than the photo's frame, focal unchanged.
    assert und.size[0] >= obj.width and und.K[0, 0] == obj.K[0, 0]
    det = A.make_detector("DICT_4X4_50")
    errs = []
    for img, c2w in zip(obj.images, obj.c2w):
        out = und(img)
        assert out.shape[:2] == (und.size[1], und.size[0])
        assert out[[0, 0, -1, -1], [0, -1, 0, -1]].min() > 40  # corners have real pixels, not black fill
        d = A.detect(out, det)
        if len(d.ids):
            truth = project_pinhole_nerfkit(nerfkit_K(und.K), c2w, obj.layout.tags[0]) - 0.5  # to OpenCV pixels
            errs.append(np.linalg.norm(d.corners[0] - truth, axis=1))
    errs = np.concatenate(errs)
    assert len(errs) >= 24 and np.sqrt(np.mean(errs**2)) < 0.2


def test_bounds_contain_the_object_from_every_camera(obj):
    K = nerfkit_K(obj.K)
    sphere_c, sphere_r = obj.scene.spheres[0].center, obj.scene.spheres[0].radius
    center = np.array([0.07, 0.02, 0.02])
    near, far, radius = estimate_bounds(obj.c2w, center, TAG, K, (obj.width, obj.height))
    d = np.linalg.norm(obj.c2w[:, :3, 3] - sphere_c, axis=1)
    assert 0 < near < (d - sphere_r).min()
    assert far > (d + sphere_r).max()
    d_tag = np.linalg.norm(obj.c2w[:, :3, 3], axis=1)
    assert far > (d_tag + TAG).max() and near < (d_tag - TAG).min()


@pytest.mark.slow
def test_dataset_files_load_back_with_the_same_cameras(posed, obj, tmp_path):
    out = tmp_path / "ds"
    standing = obj.layout.corners()[0] @ np.array([[1.0, 0, 0], [0, 0, 1], [0, 1, 0]]) + [0.2, 0, 0.05]  # not on it
    scene, summary = build_dataset(
        posed,
        out,
        DatasetConfig(max_side=400, val_every=4, test_every=5),
        TAG,
        jobs=2,
        progress=False,
        tags=np.stack([obj.layout.corners()[0], standing]),
    )
    assert summary["views"] == {"train": 6, "val": 2, "test": 2} and summary["tags_on_table"] == 1
    a = load_npz(out / "dataset.npz")
    b = load_transforms_json(out)
    for split in ("train", "val", "test"):
        va, vb, vs = a.splits[split], b.splits[split], scene.splits[split]
        assert va.names == vb.names == vs.names and len(va) > 0
        assert set(va.names) <= set(obj.names)  # each view traces back to its photo
        np.testing.assert_allclose(va.c2w, vs.c2w, atol=1e-6)
        np.testing.assert_allclose(vb.c2w, vs.c2w, atol=1e-6)
        np.testing.assert_allclose(va.K, vb.K, rtol=1e-6)
        assert np.array_equal(va.images, vs.images)
        assert np.abs(vb.images.astype(int) - va.images).mean() < 2.0  # JPEG q95 copies
        for name, c2w in zip(va.names, va.c2w):
            np.testing.assert_allclose(c2w, obj.c2w[obj.names.index(name)], atol=1e-6)
    assert max(a.train.width, a.train.height) == 400
    for s in (a, b):
        assert (s.near, s.far) == pytest.approx((scene.near, scene.far), rel=1e-6)
        np.testing.assert_allclose(s.up, [0, 0, 1])
        np.testing.assert_allclose(s.center, scene.center, atol=1e-6)
        np.testing.assert_allclose(s.tags, [obj.layout.tags[0]], atol=1e-6)  # the printed tag, on the table
    tj = json.loads((out / "transforms.json").read_text())
    assert all(f["file_path"] == f"images/{f['name']}" for f in tj["frames"])
    assert tj["nerfkit"]["tag_size"] == TAG
    # where the photos look from: the chart beside the files, and the widest gaps named by photo
    cov = tj["nerfkit"]["coverage"]
    assert cov == summary["coverage"] and (out / cov["plot"]).stat().st_size > 1000
    assert set(cov["widest_gap"]["nearest_photos"]) <= set(obj.names)
    assert set(cov["widest_gap_of_training_photos"]["nearest_photos"]) <= set(scene.train.names)
    assert cov["widest_gap_of_training_photos"]["radius_deg"] >= cov["widest_gap"]["radius_deg"]
    # how well the training photos agree on the table: not measured without an object box (six
    # photos of the sphere give too few points on it), where the sphere would count as table
    assert summary["object_points"] < MIN_OBJECT_POINTS
    assert "agreement" not in tj["nerfkit"] and "agreement" not in summary and photo_agreement(a) is None
    # given points on the sphere, its box is left out, and the photos agree better than with
    # the sphere counted as table
    sphere = obj.scene.spheres[0]
    u = np.random.default_rng(0).normal(size=(200, 3))
    u[:, 2] = np.abs(u[:, 2])
    on_sphere = sphere.center + sphere.radius * u / np.linalg.norm(u, axis=1, keepdims=True)
    boxed = photo_agreement(a, on_sphere)
    unboxed = measure_agreement(a.train, a.center, a.table, sphere_radius(a))
    assert boxed is not None and unboxed is not None and boxed.psnr > unboxed.psnr + 1
    assert boxed.photos_per_point >= 3 and 10 < boxed.psnr < 60
    # too few points triangulated on the tag to move the table off the tag's plane
    np.testing.assert_array_equal(a.table, [0, 0, 1, 0])
    assert tj["nerfkit"]["table_from"] == summary["table_from"] == "the tags' plane, z = 0"


def test_table_moves_to_the_points_on_the_tag(posed, obj, tmp_path):
    rng = np.random.default_rng(1)
    n = MIN_TAG_SURFACE_POINTS + 10
    half = 0.45 * TAG
    on_tag = np.c_[rng.uniform(-half, half, (n, 2)), np.full(n, 0.0005)]  # a tag printed on card
    floor = np.c_[rng.uniform(0.05, 0.1, (50, 2)), np.zeros(50)]
    xyz = np.concatenate([on_tag, floor]).astype(np.float32)
    seen = [tuple(obj.names[:3])] * len(xyz)
    points = SparsePoints(xyz, np.full((len(xyz), 3), 128, np.uint8), np.zeros(len(xyz)), np.full(len(xyz), 3), seen)
    out = tmp_path / "ds"
    cfg = DatasetConfig(max_side=200, val_every=0, test_every=0)
    scene, summary = build_dataset(posed, out, cfg, TAG, progress=False, points=points, tags=obj.layout.corners()[:1])
    np.testing.assert_allclose(scene.table, [0, 0, 1, -0.0005], atol=1e-7)
    assert summary["table_from"] == f"z = +0.50 mm, the median height of the {n} sparse points on the tags"
    for back in (load_npz(out / "dataset.npz"), load_transforms_json(out)):
        np.testing.assert_allclose(back.table, scene.table, atol=1e-7)
        np.testing.assert_allclose(back.tags, [obj.layout.tags[0]], atol=1e-6)  # the tag itself stays put


def test_inside_quads_either_winding():
    quad = np.array([[[0.0, 1], [1, 0], [0, -1], [-1, 0]]])  # a diamond
    xy = np.array([[0.0, 0], [0.4, 0.4], [0.6, 0.6], [2, 0], [0, -0.9]])
    expected = [True, True, False, False, True]
    assert inside_quads(xy, quad).tolist() == expected
    assert inside_quads(xy, quad[:, ::-1]).tolist() == expected
    assert inside_quads(xy, np.concatenate([quad + [5, 0], quad])).tolist() == expected


def test_tag_surface_height_is_the_median_of_the_points_on_the_tags():
    rng = np.random.default_rng(0)
    tag = np.array([[[-0.05, 0.05, 0], [0.05, 0.05, 0], [0.05, -0.05, 0], [-0.05, -0.05, 0]]])
    on = np.c_[rng.uniform(-0.045, 0.045, (40, 2)), 0.001 + rng.normal(0, 1e-4, 40)]  # 1 mm over the tag
    floor = np.c_[rng.uniform(0.06, 0.2, (200, 2)), np.full(200, -0.002)]  # beside the tag: not counted
    above = np.c_[rng.uniform(-0.04, 0.04, (100, 2)), rng.uniform(0.01, 0.1, 100)]  # an object on the tag
    height, count = tag_surface_height(np.concatenate([on, floor, above]), tag)
    assert count == 40 and height == pytest.approx(np.median(on[:, 2]))
    few = on[: MIN_TAG_SURFACE_POINTS - 1]
    assert tag_surface_height(np.concatenate([few, floor]), tag) == (0.0, MIN_TAG_SURFACE_POINTS - 1)


@pytest.mark.slow
def test_dataset_cameras_project_the_tag_onto_its_pixels(posed, obj, tmp_path):
    # The whole chain (undistort, crop, resize, +0.5 convention): the npz's K and c2w must put
    # the tag's true corners where the tag is in the npz's own images.
    scene, _ = build_dataset(
        posed, tmp_path / "ds", DatasetConfig(max_side=480, val_every=0, test_every=0), TAG, jobs=1, progress=False
    )
    s = load_npz(tmp_path / "ds" / "dataset.npz")
    det = A.make_detector("DICT_4X4_50")
    errs = []
    for img, K, c2w in zip(s.train.images, s.train.K, s.train.c2w):
        d = A.detect(img, det)
        if len(d.ids):
            truth = project_pinhole_nerfkit(K, c2w.astype(np.float64), obj.layout.tags[0]) - 0.5
            errs.append(np.linalg.norm(d.corners[0] - truth, axis=1))
    errs = np.concatenate(errs)
    assert len(errs) >= 24 and np.sqrt(np.mean(errs**2)) < 0.3


def test_dataset_settings_are_checked_before_any_photo_is_read(tmp_path, capsys):
    """A malformed --center or --near above --far is refused before posing, so no poses.json is
    left behind to block the corrected command."""
    for bad, message in (
        (["--center", "1,2"], "--center: expected three numbers 'x,y,z', got '1,2'"),
        (["--near", "5", "--far", "1"], "--near/--far: near=5 and far=1: need near < far"),
    ):
        out = tmp_path / "ds"
        argv = ["poses", str(tmp_path / "no_photos_here"), "--tag-size", "0.06", "--out", str(out), *bad]
        assert main(argv) == 2
        assert message in capsys.readouterr().err
        assert not out.exists()


def test_a_center_in_other_units_than_metres_is_refused():
    """Cameras about 0.4 m from the tag: 0.1,0,0.05 (metres) is taken, 100,100,100 (centimetres
    or millimetres) is refused with what to give instead."""
    from nerfkit.cameras import look_at
    from nerfkit.capture.dataset import given_center
    from nerfkit.errors import NerfkitError

    c2w = np.stack(
        [
            look_at(np.array([0.4 * np.cos(a), 0.4 * np.sin(a), 0.25]), np.zeros(3), np.array([0, 0, 1.0]))
            for a in range(8)
        ]
    )
    assert given_center("", c2w) is None
    np.testing.assert_allclose(given_center("0.1,0,0.05", c2w), [0.1, 0, 0.05], atol=1e-7)
    with pytest.raises(NerfkitError, match="lies 173 m from the cameras.*Give it in metres"):
        given_center("100,100,100", c2w)


@pytest.mark.slow
def test_center_override_and_dataset_command_rebuild(posed, tmp_path, capsys):
    from nerfkit.capture.dataset import write_poses_json
    from nerfkit.capture.photos import PhotoRecord

    out = tmp_path / "ds"
    recs = []
    for p in posed:
        r = PhotoRecord(
            p.name, p.path, A.Detection(p.camera.width, p.camera.height, np.zeros(0, np.int64), np.zeros((0, 4, 2)))
        )
        r.used, r.error_px = True, 0.1
        recs.append(r)
    layout = A.Layout.single(3, TAG)
    write_poses_json(
        out / "poses.json",
        recs,
        posed,
        posed[0].camera,
        {"photos_dir": str(posed[0].path.parent), "tag_size": TAG, "layout": layout.to_json()},
    )
    assert main(["dataset", str(out), "--max-side", "320", "--center", "0.1,0.02,0.03", "--near", "0.05"]) == 0
    said = capsys.readouterr().out  # no points on the sphere: no box, and no agreement measured
    assert "agreement: the training photos show the table" not in said
    assert "how well the photos agree on the table is not measured" in said
    s = load_npz(out / "dataset.npz")
    np.testing.assert_allclose(s.tags, layout.corners(), atol=1e-7)  # the recorded layout's tag
    np.testing.assert_allclose(s.center, [0.1, 0.02, 0.03], atol=1e-7)
    assert s.near == pytest.approx(0.05) and max(s.train.width, s.train.height) == 320
    assert main(["dataset", str(out), "--max-side", "160", "--out", str(tmp_path / "small")]) == 0
    small = load_npz(tmp_path / "small" / "dataset.npz")
    ratio = small.train.width / s.train.width
    np.testing.assert_allclose(small.train.K[0, 0, 0], s.train.K[0, 0, 0] * ratio, rtol=2e-2)


def test_plane_hit_distance_is_the_nearest_border_ray_to_the_table():
    # 2x2 image, f = 1: the corners' rays leave the axis at 54.7 degrees, the edges' at 45
    K = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    down = np.diag([1.0, -1.0, -1.0, 1.0])  # the camera's +z along the world's -z
    down[2, 3] = 1.0  # one unit above z = 0
    assert plane_hit_distance(down, K, (2, 2)) == pytest.approx(np.sqrt(2.0))
    up = down.copy()
    up[:3, :3] = np.eye(3)  # looking straight up: no border ray meets the table
    assert plane_hit_distance(up, K, (2, 2)) == np.inf
    under = down.copy()
    under[2, 3] = -1.0  # under the table looking down: it sees the table's back, not its top
    assert plane_hit_distance(under, K, (2, 2)) == np.inf
