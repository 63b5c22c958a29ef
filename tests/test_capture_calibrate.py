"""Camera calibration from synthetic photos of a tag sheet with known K and distortion."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from nerfkit.capture import aruco as A
from nerfkit.capture import calibrate as C
from nerfkit.capture import synthetic as S
from nerfkit.capture.photos import PhotoRecord
from nerfkit.cli import main

SIZE = (640, 480)
TAG = 0.05  # the synthetic sheet's tag size


@pytest.fixture(scope="module")
def sheet():
    return S.cached_capture("sheet", 12, 5)


@pytest.fixture(scope="module")
def records(sheet):
    det = A.make_detector("DICT_4X4_50")
    return [PhotoRecord(n, None, A.detect(im, det)) for n, im in zip(sheet.names, sheet.images)]


def fresh(records):
    out = []
    for r in records:
        out.append(PhotoRecord(r.name, r.path, r.detection))
    return out


def rel_errors(K, K_true):
    return np.abs(
        [K[0, 0] / K_true[0, 0] - 1, K[1, 1] / K_true[1, 1] - 1, K[0, 2] / K_true[0, 2] - 1, K[1, 2] / K_true[1, 2] - 1]
    )


def test_every_photo_shows_several_tags(records):
    # The scenario under test: several tags per photo, layout unknown to the calibration.
    assert np.mean([len(r.detection.ids) >= 4 for r in records]) > 0.7


@pytest.mark.slow
def test_sheet_without_layout_recovers_intrinsics_within_1_percent(sheet, records):
    cal = C.calibrate_records(fresh(records), SIZE, TAG, None, C.CalibrateConfig())
    assert cal.target == "estimated layout"
    assert rel_errors(cal.K, sheet.K).max() < 0.01
    assert np.abs(cal.dist[:2] - sheet.dist[:2]).max() < 0.02
    assert cal.rms < 0.5
    assert cal.sanity["warnings"] == []


@pytest.mark.slow
def test_estimated_layout_matches_the_printed_sheet(sheet, records):
    cal = C.calibrate_records(fresh(records), SIZE, TAG, None, C.CalibrateConfig())
    est = cal.layout.tags
    ref = next(t for t, c in est.items() if np.allclose(c.mean(0)[:2], 0))  # (z: the flat sheet's ~0 heights)
    # Express the true layout in the reference tag's frame, as the estimate is.
    T = np.linalg.inv(A.tag_pose_in_layout(sheet.layout.tags[ref]))
    for t, corners in sheet.layout.tags.items():
        truth = corners @ T[:3, :3].T + T[:3, 3]
        assert np.abs(est[t] - truth).max() < 0.001, t  # within 1 mm


def test_naive_shared_corners_would_ruin_calibration(sheet, records):
    # Negative control: giving every tag the same 3D corners (the common mistake) is far off,
    # so the test above is sensitive to the problem it guards against.
    sq = A.square_corners(TAG)
    views = [(r.name, np.concatenate([sq] * len(r.detection.ids)), r.detection.corners.reshape(-1, 2)) for r in records]
    fit = C.fit_views(views, SIZE, C.calib_flags(C.CalibrateConfig(), "k1k2p1p2"), outlier_factor=0)
    assert fit.rms > 10 or rel_errors(fit.K, sheet.K).max() > 0.02


def test_tag_views_never_share_3d_points_within_a_view(records):
    views = C.tag_views(records, TAG)
    assert len(views) == sum(len(r.detection.ids) for r in records)
    for _name, obj, img in views:
        assert obj.shape == (4, 3) and img.shape == (4, 2)
        assert len({tuple(p) for p in np.round(obj, 9)}) == 4


@pytest.mark.slow
def test_per_tag_mode_and_known_layout_also_recover_intrinsics(sheet, records):
    per_tag = C.calibrate_records(fresh(records), SIZE, TAG, None, C.CalibrateConfig(per_tag=True))
    assert per_tag.target == "per-tag"
    assert rel_errors(per_tag.K, sheet.K).max() < 0.01
    known = C.calibrate_records(fresh(records), SIZE, TAG, sheet.layout, C.CalibrateConfig())
    assert known.target.startswith("layout")
    assert rel_errors(known.K, sheet.K).max() < 0.01


@pytest.mark.parametrize("n, per_tag", [(2, True), (4, False), (4, True)])
def test_too_few_photos_are_counted_as_photos_in_every_mode(records, n, per_tag):
    """Per tag, 2 photos are 10 tag views: the message counts photos, as it does in any mode."""
    from nerfkit.errors import NerfkitError

    with pytest.raises(NerfkitError, match=f"only {n} photos with tags found \\(need at least 5\\)"):
        C.calibrate_records(fresh(records)[:n], SIZE, TAG, None, C.CalibrateConfig(per_tag=per_tag))


def test_copies_of_one_view_are_refused_not_calibrated(records):
    """Six copies of two photos (a burst from a tripod) are two views: too few to measure a lens
    (it once fitted them to 0.000 px with an absurd focal length). Moved by a few pixels,
    photos still count as one view; the twelve photos of the sheet are twelve."""
    from dataclasses import replace

    from nerfkit.errors import NerfkitError

    two = fresh(records)[:2]
    copies = [PhotoRecord(f"{r.name}-{k}", None, r.detection) for r in two for k in range(3)]
    with pytest.raises(NerfkitError, match="the 6 photos with tags show them from 2 places.*Take 20-50"):
        C.calibrate_records(copies, SIZE, TAG, None, C.CalibrateConfig())
    nudged = [replace(r.detection, corners=r.detection.corners + 1.0) for r in two]
    tol = C.SAME_VIEW * float(np.hypot(*SIZE))
    assert tol > 1.0 and C.distinct_views([r.detection for r in two] + nudged, tol) == 2
    assert C.distinct_views([r.detection for r in records], tol) == len(records)


def test_outlier_photo_is_dropped_and_the_camera_recalibrated(sheet, records):
    recs = fresh(records)
    bad = recs[3]
    rng = np.random.default_rng(0)
    bad.detection = A.Detection(
        bad.detection.width,
        bad.detection.height,
        bad.detection.ids,
        bad.detection.corners + rng.normal(0, 3.0, bad.detection.corners.shape),
    )
    cal = C.calibrate_records(recs, SIZE, TAG, sheet.layout, C.CalibrateConfig())
    assert not bad.used and bad.reason.startswith("outlier")
    assert any("dropped 1 outlier" in n for n in cal.notes)
    assert all(r.used for r in recs if r is not bad)
    assert rel_errors(cal.K, sheet.K).max() < 0.01


def test_sanity_checks_flag_implausible_phone_calibrations():
    K = np.array([[1000.0, 0, 639.5], [0, 1000.0, 479.5], [0, 0, 1]])
    w, h = 1280, 960
    f35 = 1000.0 * 43.2666 / np.hypot(w, h)  # the EXIF focal length this fx implies
    good = C.sanity_checks(K, np.zeros(5), (w, h), 0.4, np.array([2.0, 2.0, 1.0, 1.0]), [f35], 1.0, 30)
    assert good["warnings"] == []
    assert good["fx_over_exif_fx"] == pytest.approx(1.0, abs=1e-3)
    # The real iPhone case from the issue: fx, fy 4% apart and the principal point 130 px off.
    K_bad = K.copy()
    K_bad[1, 1] = 1040.0
    K_bad[0, 2] += 130
    bad = C.sanity_checks(K_bad, np.zeros(5), (w, h), 0.58, np.array([2.0, 2.0, 1.0, 1.0]), [f35 * 1.2], 1.0, 30)
    text = " ".join(bad["warnings"])
    assert "fx and fy differ by 3.8%" in text
    assert "principal point is 130 px" in text and "--principal-point centre" in text
    assert "EXIF focal length" in text
    # Freed by the photos' held-out error, the advice says so instead of simply undoing it.
    freed = {
        "principal_point": {"chosen": "free", "heldout_rms": {"centre": 0.5, "free": 0.1}},
        "aspect": {"chosen": "free", "why": "given with --aspect"},
    }
    text = " ".join(
        C.sanity_checks(K_bad, np.zeros(5), (w, h), 0.58, np.array([2.0, 2.0, 1.0, 1.0]), [f35], 1.0, 30, freed)[
            "warnings"
        ]
    )
    assert "The photos hold it there (0.100 px held out against 0.500 px with --principal-point centre)" in text
    assert "re-run with --aspect square (or auto)" in text


@pytest.mark.slow
def test_calibrate_command_writes_camera_file_and_explains_skips(tmp_path, sheet, capsys):
    folder = tmp_path / "photos"
    sheet.write(folder)
    S.write_photo(folder / "zz_blank.jpg", np.full((480, 640, 3), 128, np.uint8))
    (folder / "zz_corrupt.jpg").write_bytes(b"\xff\xd8\xff\xe0 not really a jpeg")
    out = tmp_path / "cam" / "camera.json"
    assert main(["calibrate", str(folder), "--dict", "DICT_4X4_50", "--tag-size", str(TAG), "--out", str(out)]) == 0
    cam = json.loads(out.read_text())
    K = np.array(cam["K"])
    assert rel_errors(K, sheet.K).max() < 0.01
    assert cam["width"] == 640 and cam["height"] == 480 and 0 < cam["rms"] < 0.5
    by_file = {im["file"]: im for im in cam["images"]}
    assert by_file["zz_blank.jpg"]["used"] is False and "no tags" in by_file["zz_blank.jpg"]["reason"]
    assert by_file["zz_corrupt.jpg"]["used"] is False and "unreadable" in by_file["zz_corrupt.jpg"]["reason"]
    assert all(by_file[n]["used"] and by_file[n]["error_px"] < 0.5 for n in sheet.names)
    assert cam["layout"]["tags"] and cam["sanity"]["warnings"] == []
    assert cam["dist_model"] in C.DIST_MODELS and cam["heldout_rms"] < 0.5
    assert cam["model_selection"]["chosen"] == cam["dist_model"] and len(cam["model_selection"]["models"]) == 5
    for name, choice in (("principal_point", "free"), ("aspect", "square")):  # (the sheet's truth: 5 px off)
        c = cam["model_selection"][name]
        assert c["chosen"] == choice and set(c["heldout_rms"]) == set(C.CONSTRAINTS[name])
    printed = capsys.readouterr().out
    assert "zz_corrupt.jpg" in printed and "RMS reprojection error" in printed and "held-out px" in printed
    assert "principal point free: held out at" in printed and "pixels square: held out at" in printed
    # Second run reuses the detection cache: the cache file is there and results are identical.
    assert (out.parent / "camera.detections.json").exists()
    assert main(["calibrate", str(folder), "--tag-size", str(TAG), "--out", str(out), "--force"]) == 0
    assert json.loads(out.read_text())["K"] == cam["K"]
    # The estimated layout in the camera file serves as a layout file for the next calibration.
    out2 = tmp_path / "cam2.json"
    assert main(["calibrate", str(folder), "--layout", str(out), "--out", str(out2)]) == 0
    cam2 = json.loads(out2.read_text())
    assert cam2["target"].startswith("layout") and rel_errors(np.array(cam2["K"]), sheet.K).max() < 0.01


@pytest.mark.parametrize(
    "content", ['{"my": "notes"}', "not json at all", '{"format": "nerfkit-poses", "version": 1, "photos": []}']
)
@pytest.mark.slow
def test_a_file_of_the_users_where_the_detection_cache_goes_is_left_alone(tmp_path, sheet, capsys, content):
    folder = tmp_path / "photos"
    sheet.write(folder)
    out = tmp_path / "cam" / "camera.json"
    mine = out.parent / "camera.detections.json"
    mine.parent.mkdir()
    mine.write_text(content)
    assert main(["calibrate", str(folder), "--dict", "DICT_4X4_50", "--tag-size", str(TAG), "--out", str(out)]) == 0
    assert mine.read_text() == content and json.loads(out.read_text())["rms"] < 0.5
    assert "is not a nerfkit detection cache" in capsys.readouterr().err


@pytest.mark.slow
def test_charuco_board_calibration_uses_chessboard_corners():
    spec = {"board": "charuco", "squares_x": 5, "squares_y": 7, "square_length": 0.03, "marker_length": 0.022}
    layout = A.layout_from_json(spec, "charuco.json", "DICT_4X4_50")
    scene = S.SynthScene([S.charuco_sheet(layout)], table=S.table_texture(0))
    rng = np.random.default_rng(2)
    poses = S.sheet_views(8, S.DEFAULT_K, SIZE, 0.12, rng)
    rays = S.camera_rays(S.DEFAULT_K, S.DEFAULT_DIST, *SIZE)
    det = A.make_detector("DICT_4X4_50", layout)
    recs, errs = [], []
    for k, pose in enumerate(poses):
        d = A.detect(S.render(scene, rays, pose, noise=1.0, rng=rng), det)
        truth = S.project(S.DEFAULT_K, S.DEFAULT_DIST, pose, layout.charuco_corners[d.charuco_ids])
        errs.append(np.linalg.norm(d.charuco_corners - truth, axis=1))
        recs.append(PhotoRecord(f"c{k}.jpg", None, d))
    errs = np.concatenate(errs)
    assert len(errs) >= 8 * 15 and np.sqrt(np.mean(errs**2)) < 0.15
    cal = C.calibrate_records(recs, SIZE, 0.022, layout, C.CalibrateConfig())
    assert "charuco" in cal.target
    assert rel_errors(cal.K, S.DEFAULT_K).max() < 0.01


# ---------------------------------------------------------------- distortion model choice (issue 11)

K_SMALL = np.array([[270.0, 0, 161.2], [0, 270.0, 118.4], [0, 0, 1]])
SMALL = (320, 240)
LENSES = {
    "zero": np.zeros(5),
    "mild": np.array([-0.05, 0.0, 0, 0, 0]),
    "strong barrel": np.array([-0.2, 0.03, 0, 0, 0]),
}


def test_distortion_check_accepts_real_lenses_and_rejects_turning_polynomials():
    from nerfkit.capture.distortion import distortion_check

    K = S.DEFAULT_K
    for name, dist in LENSES.items():
        assert distortion_check(K, dist, SIZE)["ok"], name
    # The iPhone fit: fits the centre, then the radial mapping turns back inside the frame.
    turning = distortion_check(K, np.array([0.24, -0.90, 0, 0, 0]), SIZE)
    assert not turning["ok"] and not turning["monotonic"] and "not monotonic" in turning["reason"]
    # Monotonic but moving the corners by more than 10% of the diagonal.
    huge = distortion_check(K, np.array([0.8, 0, 0, 0, 0]), SIZE)
    assert huge["monotonic"] and not huge["ok"] and huge["corner_displacement_px"] > huge["limit_px"] == 80.0


@pytest.fixture(scope="module", params=list(LENSES))
def lens_capture(request):
    dist = LENSES[request.param]
    cap = S.make_calibration_capture(n=14, size=SMALL, K=K_SMALL, dist=dist, seed=3)
    det = A.make_detector("DICT_4X4_50")
    return request.param, cap, [PhotoRecord(n, None, A.detect(im, det)) for n, im in zip(cap.names, cap.images)]


@pytest.mark.slow
def test_auto_distortion_model_generalises_on_synthetic_lenses(lens_capture):
    name, cap, recs = lens_capture
    cal = C.calibrate_records(fresh(recs), SMALL, TAG, None, C.CalibrateConfig())
    sel = cal.selection
    assert set(sel["models"]) == set(C.DIST_MODELS) and sel["chosen"] == cal.dist_model
    assert rel_errors(cal.K, cap.K).max() < 0.01
    assert sel["models"][cal.dist_model]["heldout_rms"] < 0.2
    if name == "zero":
        assert cal.dist_model in ("none", "k1") and np.abs(cal.dist).max() < 0.01
    else:  # a radial model close to the truth, never the tangential or k3 ones
        assert cal.dist_model in ("k1", "k1k2")
        assert abs(cal.dist[0] - cap.dist[0]) < 0.03
        none = sel["models"]["none"]["heldout_rms"]
        assert none > 3 * sel["models"][cal.dist_model]["heldout_rms"]  # distortion matters, and was kept
    # The model chosen is plausible out to the image corners.
    assert sel["models"][cal.dist_model]["check"]["ok"]


def test_explicit_model_is_kept_and_checked(lens_capture):
    name, cap, recs = lens_capture
    if name != "strong barrel":
        pytest.skip("one lens is enough")
    cal = C.calibrate_records(fresh(recs), SMALL, TAG, None, C.CalibrateConfig(dist_model="k1"))
    assert cal.dist_model == "k1" and cal.selection["method"] == "given with --dist-model"
    assert "k1" in cal.selection["models"] and cal.dist[1] == 0


@pytest.mark.slow
@pytest.mark.parametrize("offset, aspect", [((0.0, 0.0), 1.0), ((9.0, -7.0), 1.0), ((0.0, 0.0), 1.03)])
def test_a_centred_principal_point_and_square_pixels_are_kept_unless_freeing_them_holds_out_better(offset, aspect):
    centre = np.array([(SMALL[0] - 1) / 2, (SMALL[1] - 1) / 2])
    K = K_SMALL.copy()
    K[:2, 2] = centre + offset
    K[1, 1] = K[0, 0] * aspect
    cap = S.make_calibration_capture(n=12, size=SMALL, K=K, dist=np.zeros(5), seed=5)
    det = A.make_detector("DICT_4X4_50")
    recs = [PhotoRecord(n, None, A.detect(im, det)) for n, im in zip(cap.names, cap.images)]
    cal = C.calibrate_records(recs, SMALL, TAG, None, C.CalibrateConfig())
    pp, px = cal.selection["principal_point"], cal.selection["aspect"]
    if offset == (0.0, 0.0):  # the truth: centred, within the margin of a fitted one
        assert pp["chosen"] == "centre" and pp["heldout_rms"]["centre"] <= 1.05 * pp["heldout_rms"]["free"]
        assert np.array_equal(cal.K[:2, 2], centre)
    else:  # 11 px off: centring it costs clearly more than the margin
        assert pp["chosen"] == "free" and pp["heldout_rms"]["centre"] > 1.5 * pp["heldout_rms"]["free"]
        assert np.abs(cal.K[:2, 2] - K[:2, 2]).max() < 1.0
    if aspect == 1.0:
        assert px["chosen"] == "square" and cal.K[0, 0] == cal.K[1, 1]
    else:  # pixels 3% taller than wide
        assert px["chosen"] == "free" and px["heldout_rms"]["square"] > 1.5 * px["heldout_rms"]["free"]
        assert abs(cal.K[1, 1] / cal.K[0, 0] - aspect) < 0.003
    assert rel_errors(cal.K, K)[:2].max() < 0.01
    # Either choice can be forced; the record says so.
    forced = C.calibrate_records(fresh(recs), SMALL, TAG, None, C.CalibrateConfig(principal_point="centre"))
    assert np.array_equal(forced.K[:2, 2], centre)
    assert forced.selection["principal_point"] == {"chosen": "centre", "why": "given with --principal-point"}


@pytest.mark.slow
def test_a_waved_sheets_heights_are_measured_and_its_photos_then_fit(monkeypatch):
    # Printed paper lies in gentle waves (steve's sheet: corners up to 1.7 mm off its plane).
    # Flat, the layout cannot fit them, and the error of held-out photos (0.96 px on steve)
    # hides how good the camera is. Here a sheet waved by up to 1.5 mm over 25 cm, seen
    # through a mildly distorting lens.
    cap = S.make_calibration_capture(n=16, dist=LENSES["mild"], seed=4, height=S.cockle(0.0015, 0.25, seed=4))
    det = A.make_detector("DICT_4X4_50")
    recs = [PhotoRecord(n, None, A.detect(im, det)) for n, im in zip(cap.names, cap.images)]
    cal = C.calibrate_records(fresh(recs), SIZE, TAG, None, C.CalibrateConfig())
    known = C.calibrate_records(fresh(recs), SIZE, TAG, cap.layout, C.CalibrateConfig())  # --layout
    monkeypatch.setattr(C, "HEIGHT_ROUNDS", 0)  # the sheet taken as flat, as before
    flat = C.calibrate_records(fresh(recs), SIZE, TAG, None, C.CalibrateConfig())
    known_flat = C.calibrate_records(fresh(recs), SIZE, TAG, cap.layout, C.CalibrateConfig())
    assert flat.layout.is_planar() and known_flat.layout.is_planar() and not cal.layout.is_planar()
    # a layout given keeps its printed places; only the heights are measured
    assert all(np.array_equal(known.layout.tags[t][:, :2], cap.layout.tags[t][:, :2]) for t in cap.layout.tags)
    assert known.target == known_flat.target == f"layout ({cap.layout.source})"

    def held_out(c):
        return c.selection["models"][c.dist_model]["heldout_rms"]

    assert held_out(known) < 0.7 * held_out(known_flat), (held_out(known), held_out(known_flat))

    def deplaned(z, xy):  # heights less their best-fit plane (each layout has its own frame)
        A_ = np.column_stack([xy, np.ones(len(xy))])
        return z - A_ @ np.linalg.lstsq(A_, z, rcond=None)[0]

    ids = sorted(cal.layout.tags)
    est = np.concatenate([cal.layout.tags[t] for t in ids])
    printed = np.concatenate([cap.layout.tags[t] for t in ids])
    truth = cap.scene.height(printed[:, 0], printed[:, 1])
    assert np.abs(truth).max() > 0.001
    err = np.abs(deplaned(est[:, 2], est[:, :2]) - deplaned(truth, printed[:, :2])).max()
    assert err < 0.0004, err
    held, held_flat = held_out(cal), held_out(flat)
    assert held < 0.7 * held_flat, (held, held_flat)  # measured 0.57 against 1.01 px (the rest: the tags' own
    assert rel_errors(cal.K, cap.K).max() < 0.01  # bending, which their corners' straight edges miss)
    assert any("not quite flat" in n for n in cal.notes)
    # The camera file keeps the printed sheet for `poses` (the paper lies otherwise next time)
    # and the heights beside it.
    out = C.calibration_json(cal, fresh(recs), "DICT_4X4_50", TAG, "photos")
    assert all(z == 0 for c in out["layout"]["tags"].values() for *_, z in c)
    assert np.allclose([z for t in ids for z in out["sheet_heights_m"][str(t)]], est[:, 2], atol=1e-6)


def test_a_flat_sheet_stays_flat(sheet, records):
    cal = C.calibrate_records(fresh(records), SIZE, TAG, None, C.CalibrateConfig())
    assert max(np.abs(c[:, 2]).max() for c in cal.layout.tags.values()) < 0.0001  # 0.1 mm
    assert any(n.startswith("the sheet lies flat") for n in cal.notes), cal.notes


def test_folds_keep_the_views_of_a_photo_together():
    views = [(f"p{k // 3}#{k % 3}", None, None) for k in range(15)]
    folds = C.photo_folds(views, 5, lambda key: key.rsplit("#", 1)[0])
    assert sorted(j for f in folds for j in f) == list(range(15))
    for f in folds:
        assert len({views[j][0].split("#")[0] for j in f}) == 1


@pytest.mark.slow
def test_calibration_turns_photos_held_the_other_way(tmp_path, sheet):
    # A phone held the other way stores the same sensor image and flags it (EXIF 6 or 8);
    # upright, the photo is portrait. Turned back by its flag it joins the others.
    folder = tmp_path / "photos"
    folder.mkdir()
    for i, (name, img) in enumerate(zip(sheet.names, sheet.images)):
        if i in (1, 4):
            S.write_photo(folder / name, np.rot90(img, -1), orientation=6, f35=26)  # shown turned clockwise
        elif i == 7:
            S.write_photo(folder / name, np.rot90(img, 1), orientation=8, f35=26)  # shown turned counter-clockwise
        else:
            S.write_photo(folder / name, img, f35=26)
    S.write_photo(folder / "zz_edited.jpg", np.ascontiguousarray(np.rot90(sheet.images[2], -1)))  # no flag
    S.write_photo(folder / "zz_tele.jpg", sheet.images[3], f35=52)  # the 2x lens: another camera
    out = tmp_path / "camera.json"
    assert main(["calibrate", str(folder), "--tag-size", str(TAG), "--out", str(out)]) == 0
    cam = json.loads(out.read_text())
    by_file = {im["file"]: im for im in cam["images"]}
    for i, turned in ((1, 270), (4, 270), (7, 90)):
        im = by_file[sheet.names[i]]
        assert im["used"] and im["turned_deg"] == turned and im["size"] == [640, 480]
        assert im["error_px"] < 0.5  # turned the right way: its corners fit the shared camera
    assert "turned_deg" not in by_file[sheet.names[0]]
    assert not by_file["zz_edited.jpg"]["used"] and "no EXIF orientation" in by_file["zz_edited.jpg"]["reason"]
    assert not by_file["zz_tele.jpg"]["used"] and "another lens or zoom" in by_file["zz_tele.jpg"]["reason"]
    assert cam["sanity"]["exif_focal_35mm"] == 26
    assert cam["width"] == 640 and cam["height"] == 480 and cam["sensor_turns"] == 0  # as the sensor stores
    assert rel_errors(np.array(cam["K"]), sheet.K).max() < 0.01


def test_a_detection_turns_with_its_photo():
    img = np.zeros((4, 6), np.uint8)  # H 4, W 6
    img[1, 5] = 1  # x 5, y 1
    det = A.Detection(6, 4, np.array([3]), np.array([[[5.0, 1.0], [0.0, 0.0], [5.0, 3.0], [2.5, 1.5]]]))
    for k in range(5):
        t = det.turned(k)
        turned = np.rot90(img, -k)  # clockwise
        y, x = np.argwhere(turned == 1)[0]
        assert (t.width, t.height) == (turned.shape[1], turned.shape[0])
        assert t.corners[0, 0].tolist() == [x, y]  # the marked pixel moved with the image
    np.testing.assert_allclose(det.turned(4).corners, det.corners)
    np.testing.assert_allclose(det.turned(1).turned(3).corners, det.corners)


# ---------------------------------------------------------------- the whole camera chosen together (issue 63)

CAMERAS = {
    f"{m}/{p}/{a}" for m in C.DIST_MODELS for p in C.CONSTRAINTS["principal_point"] for a in C.CONSTRAINTS["aspect"]
}


def grid_views(K, dist, size, n, noise, reach, seed):
    """``n`` views ``(name, obj (48, 3), img (48, 2))`` of a flat 8 x 6 grid of 2 cm pitch,
    tilted up to 34 degrees, 0.35-0.5 m away, its centre aimed within ``reach`` of the
    half-frame around the image centre; corners projected with ``K, dist`` plus Gaussian
    noise of ``noise`` px. (Points, not photos: the edge rule's cases need noise and reach
    set exactly.)"""
    import cv2

    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.arange(8) * 0.02 - 0.07, np.arange(6) * 0.02 - 0.05)
    obj = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    w, h = size
    views = []
    while len(views) < n:
        rvec = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-np.pi, np.pi)])
        aim = (w / 2 + rng.uniform(-1, 1) * reach * w / 2, h / 2 + rng.uniform(-1, 1) * reach * h / 2, 1.0)
        tvec = np.linalg.solve(K, aim) * rng.uniform(0.35, 0.5)
        img = cv2.projectPoints(obj, rvec, tvec, K, dist)[0].reshape(-1, 2)
        if img.min() >= 0 and np.all(img <= [w - 1, h - 1]):
            views.append((f"v{len(views):02d}", obj, img + rng.normal(0, noise, img.shape)))
    return views


@pytest.mark.slow
def test_the_whole_camera_is_chosen_together_distortion_and_an_offset_principal_point():
    # A lens with barrel distortion and its principal point 15 px off centre: the camera chosen
    # must have both, each fitted with the other (not the principal point chosen under one
    # model and kept with another).
    K = K_SMALL.copy()
    K[:2, 2] = np.array([(SMALL[0] - 1) / 2 + 12, (SMALL[1] - 1) / 2 - 9])
    dist = np.array([-0.12, 0, 0, 0, 0])
    cap = S.make_calibration_capture(n=14, size=SMALL, K=K, dist=dist, seed=6)
    det = A.make_detector("DICT_4X4_50")
    recs = [PhotoRecord(n, None, A.detect(im, det)) for n, im in zip(cap.names, cap.images)]
    cal = C.calibrate_records(recs, SMALL, TAG, None, C.CalibrateConfig())
    sel = cal.selection
    by = {r["name"]: r for r in sel["candidates"]}
    assert set(by) == CAMERAS  # every combination tried, each on its own
    chosen = by[sel["camera"]]
    assert chosen["chosen"] and sum(r["chosen"] for r in by.values()) == 1
    assert sel["camera"] == f"{cal.dist_model}/free/square" and cal.dist_model in ("k1", "k1k2")
    assert abs(cal.dist[0] - dist[0]) < 0.02
    assert np.abs(cal.K[:2, 2] - K[:2, 2]).max() < 1.0 and cal.K[0, 0] == cal.K[1, 1]
    assert rel_errors(cal.K, K).max() < 0.01
    # The camera is that candidate's own fit, nothing carried over from another.
    assert [chosen["fx"], chosen["cx"], chosen["cy"]] == pytest.approx(
        [cal.K[0, 0], cal.K[0, 2], cal.K[1, 2]], abs=0.01
    )
    # Held out near the corners' noise: as well as the best camera tried, and far better than
    # without the distortion or without the offset.
    best = min(r["heldout_rms"] for r in by.values() if r["eligible"])
    assert chosen["heldout_rms"] <= 1.05 * best and chosen["heldout_rms"] < 0.1
    assert by["none/free/square"]["heldout_rms"] > 5 * chosen["heldout_rms"]
    assert by[f"{cal.dist_model}/centre/square"]["heldout_rms"] > 1.5 * chosen["heldout_rms"]
    for r in by.values():  # every verdict in words
        assert (r["rejected"] is None) == r["eligible"] and (r.get("verdict") if r["eligible"] else r["rejected"])
    # The records of each choice hold the chosen camera against one change of it.
    assert sel["principal_point"]["chosen"] == "free" and sel["aspect"]["chosen"] == "square"
    assert sel["principal_point"]["heldout_rms"]["free"] == chosen["heldout_rms"]
    assert sel["models"][cal.dist_model] is chosen and set(sel["models"]) == set(C.DIST_MODELS)


SIZE_EDGE = (640, 480)
K_EDGE = np.array([[520.0, 0, 319.5], [0, 520.0, 239.5], [0, 0, 1]])


@pytest.mark.parametrize("k1, reach, seed, kept", [(-0.15, 0.35, 2, True), (-0.10, 0.30, 4, False)])
def test_the_edge_rule_weighs_the_folds_disagreement_against_what_the_simpler_model_gets_wrong(k1, reach, seed, kept):
    # The photos' corners stay near the centre, so the folds' k1 differ a little at the frame's
    # edges: more than a fixed limit (1 px, twice k1's held-out error) allows. Where k1 holds
    # out far better than none, that disagreement is smaller than what none gets wrong at the
    # photos' edges, and k1 is kept; where k1 gains little, it is not.
    views = grid_views(K_EDGE, np.array([k1, 0, 0, 0, 0]), SIZE_EDGE, 12, 0.3, reach, seed)
    camera, sel = C.select_camera(views, SIZE_EDGE, C.CalibrateConfig(principal_point="centre", aspect="square"))
    one, none = sel["models"]["k1"], sel["models"]["none"]
    assert one["frame_spread_px"] > max(1.0, 2 * one["heldout_rms"])  # a fixed limit would reject it
    assert one["edge_limit_px"] == pytest.approx(2 * none["edge_heldout_rms"], abs=2e-3)
    assert one["edge_reference"] == "none/centre/square"
    if kept:
        assert none["heldout_rms"] > 1.25 * one["heldout_rms"]
        assert one["eligible"] and camera == C.Candidate("k1", "centre", "square") and one["chosen"]
        assert abs(one["dist"][0] - k1) < 0.03
    else:
        assert not one["eligible"] and "unstable at the frame's edges" in one["rejected"]
        assert camera.model == "none"


def test_without_distortion_the_simplest_camera_is_still_chosen():
    # Square pixels, a centred principal point, no distortion: every richer camera holds out
    # within the noise, and the simplest is chosen.
    views = grid_views(K_EDGE, np.zeros(5), SIZE_EDGE, 12, 0.3, 0.6, 5)
    camera, sel = C.select_camera(views, SIZE_EDGE, C.CalibrateConfig())
    assert camera == C.Candidate("none", "centre", "square") and sel["camera"] == "none/centre/square"
    assert {r["name"] for r in sel["candidates"]} == CAMERAS
    held = [r["heldout_rms"] for r in sel["candidates"] if r["eligible"]]
    assert sel["models"]["none"]["heldout_rms"] <= 1.05 * min(held)
    assert sel["principal_point"]["chosen"] == "centre" and sel["aspect"]["chosen"] == "square"


def test_a_camera_no_lens_makes_is_never_chosen_nor_read():
    from nerfkit.capture.camera import MAX_ASPECT_OFFSET, MAX_CENTRE_OFFSET, camera_from_dict, implausible
    from nerfkit.errors import NerfkitError

    w, h = 640, 480
    cx, cy = (w - 1) / 2, (h - 1) / 2

    def K(fx, fy, x, y):
        return np.array([[fx, 0, x], [0, fy, y], [0, 0, 1.0]])

    assert implausible(K(500, 500, cx, cy), (w, h)) == ""
    assert implausible(K(500, 500 / 1.04, cx + 0.1 * w, cy - 0.1 * h), (w, h)) == ""  # an iPhone's 4%, 10% off
    assert "off the centre" in implausible(K(500, 500, cx, cy + (MAX_CENTRE_OFFSET + 0.01) * h), (w, h))
    assert "as wide as tall" in implausible(K(500 * (1 + MAX_ASPECT_OFFSET + 0.01), 500, cx, cy), (w, h))
    # a camera file whose width and height are not those of its K (here 4x larger) is refused
    data = {"K": K(500, 500, cx, cy).tolist(), "dist": [0] * 5, "width": 4 * w, "height": 4 * h}
    with pytest.raises(NerfkitError, match="2560x1920 photos is no lens's.*width and height are those K"):
        camera_from_dict(data, "camera.json")
    assert camera_from_dict({**data, "width": w, "height": h}, "camera.json").width == w


def test_a_tag_of_another_size_among_the_sheets_is_found_from_photos_of_three_tags_or_more():
    from nerfkit.capture.aruco import Detection

    def det(sides):
        squares = [np.array([[0, 0], [s, 0], [s, s], [0, s]], float) + 200 * k for k, s in enumerate(sides)]
        return Detection(640, 480, np.arange(len(sides)), np.stack(squares))

    # tag 3 twice the others' side; perspective (10% between tags) is not another size
    photos = [det([50, 55, 45, 100]), det([40, 44, 38, 82]), det([60, 54, 66, 118])]
    odd = C.odd_sized_tags(photos)
    assert list(odd) == [3] and odd[3] == pytest.approx(np.median([100 / 50, 82 / 40, 118 / 60]))
    assert C.odd_sized_tags([det([50, 100]), det([40, 80])]) == {}  # two tags: which one is odd is unknown
    assert C.odd_sized_tags([det([50, 55, 45, 60])]) == {}


@pytest.mark.parametrize(
    "doc, said",
    [
        ({"format": "nerfkit-poses", "version": 1, "camera": "camera.json"}, "the report `nerfkit poses` writes"),
        ({"version": 5, "settings": {}, "photos": {}}, "a cache of tag detections"),
        ({"inputs": {"photos": "x"}}, "a capture's record"),
        ({"train": {}, "model": {}, "bounds": {}}, "a trained run's config.json"),
    ],
)
def test_another_nerfkit_file_given_as_the_camera_is_named_for_what_it_is(tmp_path, doc, said):
    """A user who passes the wrong JSON to --camera is told what the file is and which one to give."""
    from nerfkit.capture.camera import load_camera
    from nerfkit.errors import NerfkitError

    path = tmp_path / "wrong.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(NerfkitError, match=f"is {re.escape(said)}.*not a camera file.*nerfkit calibrate wrote") as e:
        load_camera(path)
    assert "by hand" not in str(e.value)
