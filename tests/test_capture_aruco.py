"""Tag detection accuracy, downscaled detection, layouts and the detection cache."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from nerfkit.capture import aruco as A
from nerfkit.capture import photos as P
from nerfkit.capture import synthetic as S
from nerfkit.errors import NerfkitError


def corner_errors(cap, dets):
    errs = []
    for det, c2w in zip(dets, cap.c2w):
        for i, t in enumerate(det.ids):
            truth = S.project(cap.K, cap.dist, c2w, cap.layout.tags[int(t)])
            errs.append(np.linalg.norm(det.corners[i] - truth, axis=1))
    return np.concatenate(errs)


def test_corners_are_sub_pixel_accurate_on_synthetic_photos():
    cap = S.cached_capture("sheet", 12, 5)
    det = A.make_detector("DICT_4X4_50")
    dets = [A.detect(im, det) for im in cap.images]
    errs = corner_errors(cap, dets)
    assert len(errs) >= 4 * 40
    assert np.sqrt(np.mean(errs**2)) < 0.15 and errs.max() < 0.8
    # Every detected id is one of the sheet's, and each appears at most once per photo.
    for d in dets:
        assert set(d.ids.tolist()) <= set(cap.layout.ids) and len(set(d.ids.tolist())) == len(d.ids)


@pytest.mark.slow
def test_downscaled_detection_is_refined_at_full_resolution():
    # A 1280x960 photo detected on a 500 px copy: corners must still be sub-pixel at full size.
    K = S.DEFAULT_K.copy()
    K[:2] *= 2.0
    K[:2, 2] += 0.5  # OpenCV pixel centres: (c + 0.5) * 2 - 0.5
    cap = S.make_calibration_capture(n=2, size=(1280, 960), K=K, supersample=1, seed=11)
    det = A.make_detector("DICT_4X4_50")
    small = [A.detect(im, det, detect_side=500) for im in cap.images]
    errs = corner_errors(cap, small)
    assert len(errs) >= 16
    assert np.sqrt(np.mean(errs**2)) < 0.25


@pytest.mark.slow
def test_a_corner_under_an_object_is_found_from_the_visible_edges():
    # A ball resting on a tag's corner hides it from every view above; the detector's outline
    # bends round the ball. The lines through the rest of the two edges meet at the true corner.
    from nerfkit.cameras import look_at

    decal, layout = S.tag_sheet([0], 0.06, 1, 0.0, margin=0.01)
    corner = layout.tags[0][1]
    scene = S.SynthScene([decal], [S.Sphere(corner + [0.0, 0.0, 0.009], 0.009)], table=S.table_texture(0))
    rays = S.camera_rays(S.DEFAULT_K, S.DEFAULT_DIST, 640, 480, 2)
    det = A.make_detector("DICT_4X4_50")
    for az in np.radians([200, 240, 280]):
        c2w = look_at(np.array([0.3 * np.cos(az), 0.3 * np.sin(az), 0.25]), np.zeros(3), np.array([0.0, 0.0, 1.0]))
        img = S.render(scene, rays, c2w, 2, noise=1.0, rng=np.random.default_rng(0))
        found = A.detect(img, det)
        found = found if len(found.ids) else A.detect_careful(img, "DICT_4X4_50")
        assert list(found.ids) == [0]
        truth = S.project(S.DEFAULT_K, S.DEFAULT_DIST, c2w, layout.tags[0])
        # Before the edges were fitted round the ball: 3.4-8.4 px off.
        assert np.linalg.norm(found.corners[0] - truth, axis=1).max() < 0.25


def test_layout_file_forms(tmp_path):
    spec = {
        "tag_size": 0.04,
        "tags": {
            "3": {"center": [0.1, 0.2], "rotation_deg": 90},
            "7": [[0, 0.02, 0], [0.02, 0.02, 0], [0.02, 0, 0], [0, 0, 0]],
        },
    }
    f = tmp_path / "layout.json"
    f.write_text(json.dumps(spec))
    lay = A.load_layout(f, "DICT_4X4_50")
    assert lay.ids == [3, 7] and lay.is_planar()
    # Rotating by 90 degrees moves the top-left corner (-s/2, s/2) to (-s/2, -s/2).
    np.testing.assert_allclose(lay.tags[3][0], [0.1 - 0.02, 0.2 - 0.02, 0], atol=1e-12)
    np.testing.assert_allclose(lay.tags[3].mean(0), [0.1, 0.2, 0], atol=1e-12)
    # The pose fitted to a tag's corners maps its own square onto them.
    T = A.tag_pose_in_layout(lay.tags[3])
    np.testing.assert_allclose(A.square_corners(0.04) @ T[:3, :3].T + T[:3, 3], lay.tags[3], atol=1e-12)


def test_grid_board_layout_is_in_nerfkit_axes():
    spec = {
        "board": "grid",
        "markers_x": 2,
        "markers_y": 3,
        "marker_length": 0.06,
        "marker_separation": 0.02,
        "first_id": 10,
    }
    lay = A.layout_from_json(spec, "board.json", "DICT_4X4_50")
    assert lay.ids == list(range(10, 16))
    centres = {t: c.mean(0) for t, c in lay.tags.items()}
    assert centres[11][0] - centres[10][0] == pytest.approx(0.08)  # +x to the right
    assert centres[10][1] - centres[12][1] == pytest.approx(0.08)  # the first row is at the top: +y up
    np.testing.assert_allclose(np.mean(list(centres.values()), axis=0), 0, atol=1e-6)  # centred
    c = lay.tags[10]  # top-left, top-right, bottom-right, bottom-left as printed
    assert c[1][0] > c[0][0] and c[3][1] < c[0][1]


def test_charuco_layout_has_chessboard_corners():
    spec = {"board": "charuco", "squares_x": 5, "squares_y": 7, "square_length": 0.04, "marker_length": 0.03}
    lay = A.layout_from_json(spec, "charuco.json", "DICT_4X4_50")
    assert lay.charuco is not None and lay.charuco_corners.shape == (4 * 6, 3)
    assert np.abs(lay.charuco_corners[:, 2]).max() == 0


@pytest.mark.parametrize(
    "spec, message",
    [
        ({"tags": {}}, "non-empty"),
        ({"tags": {"a": [[0, 0, 0]] * 4}}, "not an integer"),
        ({"tags": {"1": [[0, 0, 0], [1, 0, 0], [1, 3, 0], [0, 1, 0]]}}, "not a square"),
        ({"tags": {"1": {"center": [0, 0]}}}, 'needs "center" and a size'),
        ({"board": "hexagon"}, "unknown board type"),
        ({"board": "grid", "markers_x": 2}, "missing the key"),
    ],
)
def test_bad_layouts_are_one_line_errors(spec, message):
    with pytest.raises(NerfkitError, match=message) as e:
        A.layout_from_json(spec, "layout.json", "DICT_4X4_50")
    assert "\n" not in str(e.value) and str(e.value).startswith("layout.json")


def test_detection_json_round_trip():
    d = A.Detection(640, 480, np.array([3, 9]), np.random.default_rng(0).uniform(0, 400, (2, 4, 2)), 12.5)
    back = A.Detection.from_json(json.loads(json.dumps(d.to_json())))
    assert back.ids.tolist() == [3, 9] and (back.width, back.height) == (640, 480)
    np.testing.assert_allclose(back.corners, d.corners, atol=1e-4)


def test_dictionary_names():
    assert A.smallest_dictionary_for("DICT_4X4_1000", 57) == "DICT_4X4_100"
    assert A.smallest_dictionary_for("DICT_4X4_1000", 3) == "DICT_4X4_50"
    assert A.get_dictionary("4x4_50").markerSize == 4
    with pytest.raises(NerfkitError, match="unknown ArUco dictionary"):
        A.get_dictionary("DICT_9X9_7")


@pytest.mark.slow
def test_detection_cache_reuses_unchanged_photos(tmp_path, monkeypatch):
    cap = S.cached_capture("sheet", 12, 5)
    folder = tmp_path / "p"
    folder.mkdir()
    paths = [S.write_photo(folder / n, im) for n, im in zip(cap.names[:3], cap.images[:3])]
    cache = tmp_path / "cache.json"
    calls = []
    real = P._detect_one
    monkeypatch.setattr(P, "_detect_one", lambda path, *a, **k: calls.append(path.name) or real(path, *a, **k))
    first = P.scan_photos(folder, "DICT_4X4_50", cache_path=cache, jobs=1, progress=False)
    assert len(calls) == 3 and cache.exists()
    calls.clear()
    again = P.scan_photos(folder, "DICT_4X4_50", cache_path=cache, jobs=2, progress=False)
    assert calls == []
    assert [r.detection.ids.tolist() for r in again] == [r.detection.ids.tolist() for r in first]
    st = paths[1].stat()
    os.utime(paths[1], ns=(st.st_atime_ns, st.st_mtime_ns + 10_000_000))
    P.scan_photos(folder, "DICT_4X4_50", cache_path=cache, jobs=1, progress=False)
    assert calls == [paths[1].name]
    calls.clear()
    P.scan_photos(folder, "DICT_4X4_100", cache_path=cache, jobs=1, progress=False)  # other settings: redo
    assert len(calls) == 3


def test_a_copy_of_a_photo_is_skipped_naming_the_photo_it_copies(tmp_path):
    import shutil

    cap = S.cached_capture("sheet", 12, 5)
    folder = tmp_path / "photos"
    folder.mkdir()
    for n, im in zip(cap.names[:3], cap.images[:3]):
        S.write_photo(folder / n, im)
    shutil.copy(folder / cap.names[1], folder / "z_copy.png")  # a copy, sorted last
    recs = {r.name: r for r in P.scan_photos(folder, "DICT_4X4_50", jobs=1, progress=False)}
    assert recs["z_copy.png"].detection is None and not recs["z_copy.png"].used
    assert recs["z_copy.png"].reason.startswith(f"a copy of {cap.names[1]} (the same bytes)")
    assert all(recs[n].detection is not None and not recs[n].reason for n in cap.names[:3])


def test_mixed_sizes_keep_the_main_group_and_explain_the_rest():
    def rec(name, w, h):
        return P.PhotoRecord(name, None, A.Detection(w, h, np.zeros(0, np.int64), np.zeros((0, 4, 2))))

    recs = [rec("a", 4032, 3024), rec("b", 4032, 3024), rec("c", 3024, 4032), rec("d", 1920, 1080)]
    size, kept = P.group_by_size(recs)
    assert size == (4032, 3024) and [r.name for r in kept] == ["a", "b"]
    assert "portrait 3024x4032" in recs[2].reason and "1920x1080" in recs[3].reason
    # with resize: a photo of the same shape at another size is kept, its corners resized
    recs = [rec("a", 4032, 3024), rec("b", 4032, 3024), rec("e", 1008, 756), rec("d", 1920, 1080)]
    recs[2].detection = A.Detection(
        1008, 756, np.array([0]), np.array([[[0.0, 0], [99.5, 0], [99.5, 49.5], [0, 49.5]]])
    )
    size, kept = P.group_by_size(recs, resize=True)
    assert [r.name for r in kept] == ["a", "b", "e"] and recs[2].info["resized_from"] == "1008x756"
    assert (recs[2].detection.width, recs[2].detection.height) == (4032, 3024)
    np.testing.assert_allclose(recs[2].detection.corners[0, 2], [(99.5 + 0.5) * 4 - 0.5, (49.5 + 0.5) * 4 - 0.5])
    assert "1920x1080" in recs[3].reason  # another shape


def test_the_common_size_does_not_depend_on_the_photos_order():
    from nerfkit.images import common_size

    assert common_size([]) is None
    assert common_size([(640, 480), (1024, 768), (640, 480)]) == (640, 480)  # the most photos
    for tie in ([(640, 480), (1024, 768)], [(1024, 768), (640, 480)]):
        assert common_size(tie) == (1024, 768)  # a tie: the larger
    for tie in ([(768, 1024), (1024, 768)], [(1024, 768), (768, 1024)]):
        assert common_size(tie) == (1024, 768)  # as large: the wider


def test_second_detection_pass_recovers_missed_tags_of_known_ids_only(tmp_path, monkeypatch):
    import cv2

    d = A.get_dictionary("DICT_4X4_50")
    for k, (name, tag) in enumerate((("a.png", 0), ("b.png", 0), ("c.png", 7))):
        img = np.full((240, 320, 3), 230 - k, np.uint8)  # (b.png is another photo, not a copy of a.png)
        img[70:150, 120:200] = cv2.aruco.generateImageMarker(d, tag, 80)[..., None]
        S.write_photo(tmp_path / name, img)
    first = P.detect

    def missing_b_and_c(image, detector, *args, **kwargs):  # the first pass misses b.png and c.png
        det = first(image, detector, *args, **kwargs)
        if kwargs.get("upscale") or image[0, 0, 0] == 230:  # a.png's paper
            return det
        return A.Detection(det.width, det.height, det.ids[:0], det.corners[:0], det.sharpness)

    monkeypatch.setattr(P, "detect", missing_b_and_c)
    recs = {r.name: r for r in P.scan_photos(tmp_path, "DICT_4X4_50", jobs=1, progress=False)}
    assert list(recs["a.png"].detection.ids) == [0] and "detection" not in recs["a.png"].info
    assert list(recs["b.png"].detection.ids) == [0] and recs["b.png"].info["detection"].startswith("second pass")
    # Tag 7 appears in no first-pass detection: a permissive detector's find is not trusted.
    assert len(recs["c.png"].detection.ids) == 0 and recs["c.png"].info["second_pass_ignored_ids"] == [7]


def test_the_second_pass_waits_for_a_tag_in_some_photo(tmp_path, monkeypatch):
    import cv2

    careful = []
    real = P.detect_careful
    monkeypatch.setattr(P, "detect_careful", lambda image, *a: careful.append(image.shape) or real(image, *a))
    for k in range(3):  # paper without a tag: a second pass could only read false ids
        S.write_photo(tmp_path / f"blank{k}.png", np.full((240, 320, 3), 230 - k, np.uint8))
    cache = tmp_path / "cache.json"
    recs = P.scan_photos(tmp_path, "DICT_4X4_50", cache_path=cache, jobs=1, progress=False)
    assert careful == [] and all(len(r.detection.ids) == 0 for r in recs)
    img = np.full((240, 320, 3), 200, np.uint8)
    img[70:150, 120:200] = cv2.aruco.generateImageMarker(A.get_dictionary("DICT_4X4_50"), 3, 80)[..., None]
    S.write_photo(tmp_path / "tag.png", img)
    recs = P.scan_photos(tmp_path, "DICT_4X4_50", cache_path=cache, jobs=1, progress=False)
    assert len(careful) == 3  # the cached photos' second pass, due since the first run
    assert [list(r.detection.ids) for r in recs] == [[], [], [], [3]]
    P.scan_photos(tmp_path, "DICT_4X4_50", cache_path=cache, jobs=1, progress=False)
    assert len(careful) == 3  # done, and cached


def test_a_sheet_repeating_a_tag_id_is_refused_naming_the_id():
    from nerfkit.errors import NerfkitError

    def rec(name, ids):
        corners = np.zeros((len(ids), 4, 2))
        return P.PhotoRecord(name, None, A.Detection(640, 480, np.array(ids, np.int64), corners))

    with pytest.raises(NerfkitError, match=r"tag 1 appears more than once in 2 of 3 photos with tags"):
        P.require_tags([rec("a", [0, 1, 1]), rec("b", [1, 2, 1]), rec("c", [0, 2])], "photos", "DICT_4X4_50")
    P.require_tags([rec("a", [0, 1, 1]), rec("b", [1, 2]), rec("c", [0, 2])], "photos", "DICT_4X4_50")  # one photo
