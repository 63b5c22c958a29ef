"""The camera file's focal length against the one the object photos want (`nerfkit.capture.focal`)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from nerfkit.capture import synthetic as S
from nerfkit.capture.camera import Camera
from nerfkit.capture.focal import (
    FOCAL_AGREE,
    FOCAL_SIGMAS,
    MIN_PHOTOS,
    SFM,
    TAGS,
    FocalCheck,
    check_focal,
    focal_check,
    focal_tolerance,
)
from nerfkit.capture.poses import TagFocal
from nerfkit.cli import main


def test_the_tolerance_is_the_floor_or_the_estimates_own_uncertainty():
    assert focal_tolerance(None) == FOCAL_AGREE
    assert focal_tolerance(float("nan")) == FOCAL_AGREE
    assert focal_tolerance(0.001) == FOCAL_AGREE  # a well pinned estimate: the floor (focus, lens models)
    assert focal_tolerance(0.03) == pytest.approx(FOCAL_SIGMAS * 0.03)  # a loose one: its own spread
    assert FOCAL_SIGMAS * 0.03 > FOCAL_AGREE  # (so the case above tests the second branch)


@pytest.mark.parametrize(
    "ratio, std, disagree",
    [
        (1.0, None, False),
        (1.0 + 0.99 * FOCAL_AGREE, None, False),
        (1.0 - 0.99 * FOCAL_AGREE, None, False),
        (1.0 + 1.01 * FOCAL_AGREE, None, True),
        (1.0 - 1.01 * FOCAL_AGREE, None, True),
        (1 / 1.2, None, True),  # a camera file 20% long
        (1.2, 0.005, True),
        (0.5, None, True),  # the 0.5x lens's photos with the 1x lens's file
        # 8% off with a 3% standard error is within 3 of them; with 1% it is not
        (1.08, 0.03, False),
        (1.08, 0.01, True),
    ],
)
def test_the_photos_focal_length_disagrees_beyond_the_tolerance(ratio, std, disagree):
    check = check_focal(1500.0, [(SFM, 1500.0 * ratio, 30, std)])
    assert check is not None
    assert check.ratio == pytest.approx(ratio)
    assert check.disagree is disagree
    line = check.line()
    assert line.startswith("WARNING") is disagree
    assert f"ratio {ratio:.3f}" in line and "1500.0 px" in line
    if disagree:  # what it likely means and what to do
        assert "another phone, lens (1x/0.5x/3x), zoom, orientation or resolution" in line
        assert "Calibrate again with the same phone" in line and "without --camera" in line
    else:
        assert f"within {check.tolerance * 100:.0f}%" in line


def test_the_check_round_trips_through_json():
    check = check_focal(1000.0, [(SFM, 830.0, 31, None), (TAGS, 845.0, 28, 0.007)])
    assert check is not None and check.disagree
    data = json.loads(json.dumps(check.as_json()))
    assert data["ratio"] == 0.83 and data["disagree"] is True and data["tolerance"] == FOCAL_AGREE
    assert data["other"] == {"source": TAGS, "photos_px": 845.0, "ratio": 0.845, "photos": 28, "std": 0.007}
    back = FocalCheck.from_json(data)
    assert back.line() == check.line() and back.disagree


def _camera(fx, width=1000, height=750):
    K = np.array([[fx, 0, (width - 1) / 2], [0, fx, (height - 1) / 2], [0, 0, 1.0]])
    return Camera(K, np.zeros(5), width, height, "camera.json")


def test_the_pinned_tags_come_first_else_sfm_at_the_camera_files_size():
    # SfM worked on photos half the camera file's size: its 400 px are the file's 800
    sfm = (400.0, 500, 375, 30)
    pinned, loose = TagFocal(810.0, 0.004, 20), TagFocal(810.0, 0.02, 20)
    check = focal_check(_camera(800.0), pinned, sfm)  # the tags pin it: theirs, lens model for lens model
    assert check is not None and check.source == TAGS and check.photos == 20 and check.std == 0.004
    assert check.ratio == pytest.approx(1.0125) and not check.disagree
    assert check.other is not None and check.other["source"] == SFM
    assert check.other["photos_px"] == pytest.approx(800.0) and check.other["ratio"] == pytest.approx(1.0)
    check = focal_check(_camera(800.0), loose, sfm)  # loosely: SfM's
    assert check is not None and check.source == SFM and check.photos == 30 and check.std is None
    assert check.photos_px == pytest.approx(800.0) and check.other["source"] == TAGS
    # the camera file 20% long: warned, by either estimate
    for tags in (pinned, loose, None):
        assert focal_check(_camera(960.0), tags, sfm).disagree
        assert focal_check(_camera(960.0), tags or pinned).disagree
    # SfM on too few photos is left out: the tags' then, however loose
    few = focal_check(_camera(800.0), loose, (400.0, 500, 375, MIN_PHOTOS - 1))
    assert few is not None and few.source == TAGS and few.std == 0.02 and few.other is None
    assert few.tolerance == pytest.approx(FOCAL_SIGMAS * 0.02)
    # no camera file, or no estimate: nothing to check
    assert focal_check(None, pinned, sfm) is None
    assert focal_check(_camera(800.0)) is None
    assert focal_check(_camera(800.0), TagFocal(810.0, 0.004, MIN_PHOTOS - 1)) is None


@pytest.mark.parametrize(
    "capture, tags, std, sfm",
    [("sreeram", 1.0133, 0.0068, 0.9933), ("steve", 1.0286, 0.0015, 1.0429), ("labubu", 0.9989, 0.0057, 1.036)],
)
def test_the_dev_captures_right_camera_files_agree_and_20_percent_long_ones_do_not(capture, tags, std, sfm):
    # the ratios measured on the dev captures with their own camera files (the module's docstring),
    # by either estimate, and each estimate alone; a camera file 20% long is 1/1.2 of them
    for factor, disagree in ((1.0, False), (1.2, True)):
        camera = _camera(1000.0 * factor)
        both = focal_check(camera, TagFocal(1000.0 * tags, std, 30), (1000.0 * sfm, 1000, 750, 30))
        alone = (
            focal_check(camera, sfm=(1000.0 * sfm, 1000, 750, 30)),
            focal_check(camera, TagFocal(1000 * tags, std, 30)),
        )
        assert [c.disagree for c in (both, *alone)] == [disagree] * 3, capture


def _sheet_photos(folder, cap):
    folder.mkdir()
    for name, img in zip(cap.names, cap.images):
        S.write_photo(folder / name, img)


def _camera_file(path, cap, factor):
    K = cap.K.copy()
    K[[0, 1], [0, 1]] *= factor
    data = {
        "K": K.tolist(),
        "dist": cap.dist.tolist(),
        "width": cap.width,
        "height": cap.height,
        "dictionary": "DICT_4X4_50",
        "heldout_rms": 0.1,
        "layout": cap.layout.to_json(),
    }
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("factor", [1.0, 1.2, 1 / 1.2])
def test_poses_compares_the_camera_files_focal_length_with_the_tags(tmp_path, capsys, factor):
    # 12 photos of a sheet of tags posed by them alone: a right camera file agrees, one whose
    # focal length is 20% off (either way) is warned of, in the report and in poses.json
    cap = S.cached_capture("sheet", 12, 5)
    _sheet_photos(tmp_path / "photos", cap)
    camera = _camera_file(tmp_path / "camera.json", cap, factor)
    out = tmp_path / "ds"
    argv = ["poses", str(tmp_path / "photos"), "--camera", str(camera), "--tag-size", "0.05", "--out", str(out)]
    assert main([*argv, "--no-dataset"]) == 0
    text = capsys.readouterr().out
    check = json.loads((out / "poses.json").read_text())["focal_check"]
    assert check["source"] == TAGS and check["photos"] >= 10
    assert check["camera_px"] == pytest.approx(cap.K[0, 0] * factor, abs=0.01)
    assert check["ratio"] == pytest.approx(1 / factor, rel=0.01)  # the photos' own: the truth
    assert check["disagree"] is (factor != 1.0)
    lines = [line for line in text.splitlines() if "focal length: the camera file's" in line]
    assert len(lines) == 1 and lines[0].startswith("WARNING") is (factor != 1.0), text
    # the tags' own note does not warn a second time: the check says it
    assert sum(line.startswith("WARNING") for line in text.splitlines()) == (factor != 1.0)
    assert math.isfinite(check["std"]) and check["std"] < 0.01


@pytest.mark.slow  # (about 18 s each)
@pytest.mark.parametrize("method, factor", [("auto", 1.0), ("auto", 1.2), ("colmap", 1.2)])
def test_poses_compares_the_camera_files_focal_length_with_structure_from_motions(tmp_path, capsys, method, factor):
    # A textured room with one tag, posed by SfM (--method auto: in the tag's frame; colmap: SfM
    # alone). SfM finds the photos' own focal length wherever it starts, and a camera file 20% long
    # is warned of, in the report, transforms.json and sfm_report.json
    pytest.importorskip("pycolmap")
    from test_colmap import ROOM_K, TAG_SIZE, make_room

    make_room(tmp_path / "photos")
    K = ROOM_K.copy()
    K[[0, 1], [0, 1]] *= factor
    camera = tmp_path / "camera.json"
    camera.write_text(json.dumps({"K": K.tolist(), "dist": [0.0] * 5, "width": 320, "height": 240}))
    out = tmp_path / "ds"
    split = ["--val-every", "6", "--test-every", "0", "--matcher", "exhaustive", "--jobs", "1"]
    argv = ["poses", str(tmp_path / "photos"), "--camera", str(camera), "--tag-size", str(TAG_SIZE), *split]
    assert main([*argv, "--method", method, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    check = json.loads((out / "transforms.json").read_text())["nerfkit"]["focal_check"]
    by_sfm = check if method == "colmap" else check["other"]
    if method == "auto":  # the tags pin it here (a large tag): theirs first, SfM's beside it
        assert check["source"] == TAGS and check["std"] < 0.01 and by_sfm["source"] == SFM
        assert check["photos_px"] == pytest.approx(ROOM_K[0, 0], rel=0.01)
        assert check["ratio"] == pytest.approx(1 / factor, rel=0.01)
    else:  # SfM's alone
        assert check["source"] == SFM and check["other"] is None
    assert by_sfm["photos"] == 12
    assert by_sfm["photos_px"] == pytest.approx(ROOM_K[0, 0], rel=0.03)  # (12 small photos: SfM drifts 1.5%)
    assert by_sfm["ratio"] == pytest.approx(1 / factor, rel=0.03)
    assert check["disagree"] is (factor != 1.0)
    lines = [line for line in text.splitlines() if "focal length: the camera file's" in line]
    assert len(lines) == 1 and lines[0].startswith("WARNING") is (factor != 1.0), text
    assert sum(line.startswith("WARNING") for line in text.splitlines()) == (factor != 1.0)
    if (out / "sfm_report.json").is_file():  # (SfM's poses taken)
        assert json.loads((out / "sfm_report.json").read_text())["focal_check"] == check
