"""Poses of synthetic object photos (known cameras) from the tag beside the object."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from nerfkit.capture import aruco as A
from nerfkit.capture import synthetic as S
from nerfkit.capture.camera import Camera, camera_from_focal, exif_fx
from nerfkit.capture.poses import solve_pose
from nerfkit.cli import main
from nerfkit.errors import NerfkitError

TAG = 0.06


@pytest.fixture(scope="module")
def obj():
    return S.cached_capture("object", 10, 1)


def pose_error(c2w, truth):
    """(position error in metres, rotation error in degrees)."""
    dR = truth[:3, :3].T @ c2w[:3, :3]
    ang = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(c2w[:3, 3] - truth[:3, 3])), float(ang)


def write_camera(path, cap):
    path.write_text(
        json.dumps(
            {
                "K": cap.K.tolist(),
                "dist": cap.dist.tolist(),
                "width": cap.width,
                "height": cap.height,
                "dictionary": "DICT_4X4_50",
            }
        )
    )
    return path


def test_single_tag_poses_within_millimetres_and_a_fraction_of_a_degree(obj):
    cam = Camera(obj.K, obj.dist, obj.width, obj.height)
    det = A.make_detector("DICT_4X4_50")
    layout = A.Layout.single(0, TAG)
    errs = []
    for img, truth in zip(obj.images, obj.c2w):
        c2w, err, reason, info = solve_pose(A.detect(img, det), cam, layout)
        if c2w is None:
            assert reason == "no tags found"  # the sphere hides the tag in a few views
            continue
        assert err < 1.0 and info["tags_used"] == [0]
        errs.append(pose_error(c2w, truth))
    errs = np.array(errs)
    assert len(errs) >= 6
    assert errs[:, 0].max() < 0.003 and errs[:, 1].max() < 0.5


def test_layout_poses_use_all_tags_jointly():
    sheet = S.cached_capture("sheet", 12, 5)
    cam = Camera(sheet.K, sheet.dist, sheet.width, sheet.height)
    det = A.make_detector("DICT_4X4_50")
    n_joint = 0
    for img, truth in zip(sheet.images[:6], sheet.c2w[:6]):
        c2w, err, reason, info = solve_pose(A.detect(img, det), cam, sheet.layout)
        assert c2w is not None, reason
        n_joint += len(info["tags_used"]) > 1
        pos, ang = pose_error(c2w, truth)
        assert pos < 0.002 and ang < 0.3
    assert n_joint >= 4


@pytest.mark.slow
def test_poses_command_with_exif_rotated_photos_and_photos_without_tags(tmp_path, obj, capsys):
    folder = tmp_path / "object"
    folder.mkdir()
    for k, (name, img) in enumerate(zip(obj.names, obj.images)):
        # Store most photos rotated with an EXIF orientation flag, as phones do.
        S.write_photo(folder / name, img, orientation=(1, 6, 8, 3)[k % 4])
    S.write_photo(folder / "zz_table.jpg", np.full((480, 640, 3), 140, np.uint8))
    S.write_photo(folder / "zz_blurred.jpg", cv2.GaussianBlur(obj.images[5], (0, 0), 8))
    S.write_photo(folder / "zz_portrait.jpg", np.ascontiguousarray(np.rot90(obj.images[5])))
    (folder / "zz_broken.jpg").write_bytes(b"garbage")
    cam_file = write_camera(tmp_path / "camera.json", obj)
    out = tmp_path / "ds"
    assert (
        main(
            ["poses", str(folder), "--camera", str(cam_file), "--tag-size", str(TAG), "--out", str(out), "--no-dataset"]
        )
        == 0
    )
    poses = json.loads((out / "poses.json").read_text())
    photos = {p["file"]: p for p in poses["photos"]}
    n_posed = 0
    for name, truth in zip(obj.names, obj.c2w):
        p = photos[name]
        if p["used"]:
            n_posed += 1
            pos, ang = pose_error(np.array(p["c2w"]), truth)
            assert pos < 0.003 and ang < 0.5, name
            assert p["size"] == [640, 480]  # upright, whatever the stored orientation
        else:
            assert p["reason"].startswith("no tags found")
    assert n_posed >= 6
    assert photos["zz_table.jpg"]["reason"].startswith("no tags found")
    assert photos["zz_blurred.jpg"]["reason"].startswith("no tags found (looks blurred")
    assert "portrait 480x640" in photos["zz_portrait.jpg"]["reason"]
    assert photos["zz_broken.jpg"]["reason"].startswith("unreadable")
    assert poses["photos_posed"] == n_posed
    text = capsys.readouterr().out
    assert "zz_broken.jpg" in text and "skipped" in text


def _held_the_other_way(img, orientation):
    """What a phone held the other way writes: the sensor's pixels (``img``) with EXIF 6 or 8
    (upright: portrait). Returns the upright image for :func:`S.write_photo`."""
    return np.ascontiguousarray(np.rot90(img, -1 if orientation == 6 else 1))


@pytest.mark.slow
def test_object_photos_held_the_other_way_are_turned_into_the_cameras_frame(tmp_path, obj):
    """Photos from a phone held the other way (EXIF 6 or 8) are turned back, posed as the
    truth, and enter the dataset as the sensor saw them; `nerfkit dataset` rebuilds the same.
    A photo turned in an editor (no EXIF) cannot be turned back and says why."""
    from nerfkit.data.load import load_scene

    plain, mixed = tmp_path / "plain", tmp_path / "mixed"
    plain.mkdir()
    mixed.mkdir()
    held = {obj.names[2]: 6, obj.names[5]: 8, obj.names[7]: 6}  # (the sphere hides the tag in 0 and 1)
    for name, img in zip(obj.names, obj.images):
        S.write_photo(plain / name, img)
        if name in held:
            S.write_photo(mixed / name, _held_the_other_way(img, held[name]), orientation=held[name])
        else:
            S.write_photo(mixed / name, img)
    S.write_photo(mixed / "zz_edited.jpg", _held_the_other_way(obj.images[3], 6))  # no flag
    cam = write_camera(tmp_path / "camera.json", obj)  # no sensor_turns: the photos' own frame
    for folder in (plain, mixed):
        assert (
            main(
                [
                    "poses",
                    str(folder),
                    "--camera",
                    str(cam),
                    "--tag-size",
                    str(TAG),
                    "--out",
                    str(tmp_path / f"ds_{folder.name}"),
                    "--method",
                    "tags",
                    "--max-side",
                    "320",
                ]
            )
            == 0
        )
    photos = {p["file"]: p for p in json.loads((tmp_path / "ds_mixed" / "poses.json").read_text())["photos"]}
    for name, truth in zip(obj.names, obj.c2w):
        if name in held:
            assert photos[name]["turned_deg"] == {6: 270, 8: 90}[held[name]] and photos[name]["size"] == [640, 480]
            pos, ang = pose_error(np.array(photos[name]["c2w"]), truth)
            assert pos < 0.003 and ang < 0.5, name
    assert "no EXIF orientation says which way" in photos["zz_edited.jpg"]["reason"]

    def views(folder):  # name -> (image, c2w) over every split
        scene = load_scene(folder)
        return {
            n: (im.astype(float), c)
            for v in scene.splits.values()
            if v is not None
            for n, im, c in zip(v.names, v.images, v.c2w)
        }

    a, b = views(tmp_path / "ds_plain"), views(tmp_path / "ds_mixed")
    assert sorted(a) == sorted(b) and set(held) <= set(b)
    for name in a:
        np.testing.assert_allclose(b[name][1], a[name][1], atol=1e-4)
    for name in held:
        diff = np.abs(b[name][0] - a[name][0]).mean()
        assert diff < 2.0, (name, diff)  # the same picture (JPEG aside); half a turn off would differ by ~40
    assert main(["dataset", str(tmp_path / "ds_mixed"), "--max-side", "320", "--out", str(tmp_path / "again")]) == 0
    again = views(tmp_path / "again")
    for name in held:
        np.testing.assert_array_equal(again[name][0], b[name][0])


@pytest.mark.slow
def test_a_capture_held_the_other_way_from_the_calibration_follows_the_camera_file(tmp_path, obj, capsys):
    """Calibrated holding the phone one way, every object photo taken the other way: the
    camera file's sensor_turns turns them all back. A camera file without it says what to do."""
    folder = tmp_path / "object"
    folder.mkdir()
    for name, img in zip(obj.names, obj.images):
        S.write_photo(folder / name, _held_the_other_way(img, 6), orientation=6)
    data = json.loads(write_camera(tmp_path / "old.json", obj).read_text())
    (tmp_path / "camera.json").write_text(json.dumps({**data, "sensor_turns": 0}))
    assert (
        main(
            [
                "poses",
                str(folder),
                "--camera",
                str(tmp_path / "camera.json"),
                "--tag-size",
                str(TAG),
                "--out",
                str(tmp_path / "ds"),
                "--no-dataset",
            ]
        )
        == 0
    )
    photos = json.loads((tmp_path / "ds" / "poses.json").read_text())["photos"]
    posed = [p for p in photos if p["used"]]
    assert len(posed) >= 6 and all(p["turned_deg"] == 270 for p in posed)
    assert f"{len(posed)} photos held the other way turned back by their EXIF orientation" in capsys.readouterr().out
    for p in posed:
        pos, ang = pose_error(np.array(p["c2w"]), obj.c2w[obj.names.index(p["file"])])
        assert pos < 0.003 and ang < 0.5
    assert (
        main(
            [
                "poses",
                str(folder),
                "--camera",
                str(tmp_path / "old.json"),
                "--tag-size",
                str(TAG),
                "--out",
                str(tmp_path / "ds_old"),
                "--no-dataset",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "no photo could be posed" in err and "Calibrate with photos of this size, shape and lens" in err
    photos = json.loads((tmp_path / "ds_old" / "poses.json").read_text())["photos"]
    assert all("re-run nerfkit calibrate" in p["reason"] for p in photos if not p["reason"].startswith("no tags"))
    # the failed try's poses.json does not stand in the way of the next (here with the right camera)
    argv = ["poses", str(folder), "--camera", str(tmp_path / "camera.json"), "--tag-size", str(TAG)]
    assert main([*argv, "--out", str(tmp_path / "ds_old"), "--no-dataset"]) == 0
    assert json.loads((tmp_path / "ds_old" / "poses.json").read_text())["photos_posed"] == len(posed)
    assert main([*argv, "--out", str(tmp_path / "ds_old"), "--no-dataset"]) == 2  # a good one does, without --force
    assert "already exists" in capsys.readouterr().err


def test_poses_start_from_the_exif_focal_length_without_a_camera_file(tmp_path):
    K = np.array([[540.0, 0, 319.5], [0, 540.0, 239.5], [0, 0, 1]])
    cap = S.make_object_capture(n=4, K=K, dist=np.zeros(5), seed=3, object_center=(0.14, 0.05, 0.045))
    f35 = round(540.0 * 43.2666 / np.hypot(640, 480))
    folder = tmp_path / "object"
    cap.write(folder, f35=f35)
    out = tmp_path / "ds"
    assert main(["poses", str(folder), "--tag-size", str(TAG), "--out", str(out), "--no-dataset"]) == 0
    poses = json.loads((out / "poses.json").read_text())
    assert poses["camera"]["source"].startswith("EXIF")
    assert poses["camera"]["K"][0][0] == pytest.approx(exif_fx(f35, 640, 480))
    assert any("EXIF focal length" in n for n in poses["notes"])
    posed = [p for p in poses["photos"] if p["used"]]
    assert len(posed) >= 3
    for p in posed:
        pos, ang = pose_error(np.array(p["c2w"]), cap.c2w[cap.names.index(p["file"])])
        assert pos < 0.01 and ang < 1.0  # the EXIF focal length is ~1% off


@pytest.mark.slow
def test_no_camera_and_no_exif_is_a_clear_error(tmp_path, obj):
    folder = tmp_path / "object"
    obj.write(folder)
    with pytest.raises(NerfkitError, match="no --camera given and the photos have no EXIF"):
        main_raise(["poses", str(folder), "--tag-size", str(TAG), "--out", str(tmp_path / "ds")])


def main_raise(argv):
    from nerfkit.cli import build_parser

    args = build_parser().parse_args(argv)
    return args.func(args)


def test_no_tags_of_the_dictionary_suggests_the_one_that_finds_them(tmp_path):
    import cv2

    folder = tmp_path / "photos"
    folder.mkdir()
    img = np.full((480, 640, 3), 235, np.uint8)
    marker = cv2.aruco.generateImageMarker(A.get_dictionary("DICT_5X5_100"), 77, 140)
    img[170:310, 250:390] = marker[..., None]
    for k in range(3):
        S.write_photo(folder / f"p{k}.png", img)
    with pytest.raises(NerfkitError) as e:
        main_raise(["calibrate", str(folder), "--tag-size", "0.05", "--out", str(tmp_path / "c.json")])
    msg = str(e.value)
    assert "no DICT_4X4_50 tags in any of the 3 photos" in msg and "--dict DICT_5X5_100" in msg and "\n" not in msg
    blank = tmp_path / "blank"
    blank.mkdir()
    S.write_photo(blank / "a.png", np.full((100, 100, 3), 200, np.uint8))
    with pytest.raises(NerfkitError, match="no DICT_4X4_50 tags found in any of 1 photos \\(also tried"):
        main_raise(["poses", str(blank), "--focal-px", "100", "--tag-size", "0.05", "--out", str(tmp_path / "d")])


def test_camera_scaling_to_a_resized_photo_keeps_rays():
    cam = camera_from_focal(1000.0, 4000, 3000, "test")
    small = cam.scaled_to(1000, 750)
    # The image centre stays the image centre; the focal length scales with the width.
    assert small.K[0, 0] == pytest.approx(250.0)
    assert small.K[0, 2] == pytest.approx((1000 - 1) / 2)
    assert cam.compatible(2000, 1500) is None
    assert "portrait" in cam.compatible(3000, 4000)
    assert "aspect ratio" in cam.compatible(3000, 3000)


@pytest.mark.slow
def test_poses_builds_the_dataset_by_default_and_heic_photos_keep_their_name(tmp_path, obj):
    from PIL import Image

    from nerfkit.data.load import load_scene

    pillow_heif = pytest.importorskip("pillow_heif")
    pillow_heif.register_heif_opener()
    folder = tmp_path / "object"
    folder.mkdir()
    for k, (name, img) in enumerate(zip(obj.names, obj.images)):
        if k == 5:
            Image.fromarray(img).save(folder / "phone_shot.HEIC", quality=95)
        elif k == 7:  # an iPhone held the other way: the sensor's pixels, EXIF 6 (pillow-heif decodes it upright)
            exif = Image.Exif()
            exif[0x0112] = 6
            Image.fromarray(img).save(folder / "held.HEIC", quality=95, exif=exif.tobytes())
        else:
            S.write_photo(folder / name, img)
    out = tmp_path / "ds"
    assert (
        main(
            [
                "poses",
                str(folder),
                "--camera",
                str(write_camera(tmp_path / "camera.json", obj)),
                "--tag-size",
                str(TAG),
                "--out",
                str(out),
                "--max-side",
                "320",
            ]
        )
        == 0
    )
    scene = load_scene(out)  # the dataset folder holds one npz: dataset.npz
    names = [n for v in scene.splits.values() for n in (v.names or [])]
    assert "phone_shot.HEIC" in names and "held.HEIC" in names
    held = next(p for p in json.loads((out / "poses.json").read_text())["photos"] if p["file"] == "held.HEIC")
    assert held["turned_deg"] == 270 and pose_error(np.array(held["c2w"]), obj.c2w[7])[1] < 0.5
    assert (out / "images" / "phone_shot.HEIC.png").exists()
    tj = json.loads((out / "transforms.json").read_text())
    assert "images/phone_shot.HEIC.png" in [f["file_path"] for f in tj["frames"]]
    assert max(scene.train.width, scene.train.height) == 320 and scene.near < scene.far


# ---------------------------------------------------------------- issue 11: every photo where the tag is found


def test_error_limit_follows_the_calibration_and_the_tag_size():
    from nerfkit.capture.poses import PoseConfig, error_limit

    cam = camera_from_focal(500.0, 640, 480, "test")
    cam.heldout_rms = 0.5
    assert error_limit(cam, 20.0, PoseConfig())[0] == pytest.approx(1.5)  # 3 x held-out
    assert error_limit(cam, 200.0, PoseConfig())[0] == pytest.approx(4.0)  # 2% of a 200 px tag
    cam.heldout_rms = 0.1
    assert error_limit(cam, 20.0, PoseConfig())[0] == pytest.approx(1.0)  # the floor
    assert error_limit(cam.scaled_to(1280, 960), 20.0, PoseConfig())[1].startswith("floor")
    assert cam.scaled_to(1280, 960).heldout_rms == pytest.approx(0.2)  # held-out error scales with the photo
    assert error_limit(cam, 20.0, PoseConfig(max_error=2.5)) == (2.5, "--max-error")


@pytest.mark.slow
def test_a_photo_from_another_lens_is_skipped_with_the_reason(tmp_path, obj):
    """A phone's 2x lens (EXIF 52 mm where the calibration's photos say 26 mm) has another
    focal length and distortion: posing it with the calibrated camera would be wrong, so
    it is skipped, saying why; a camera file from a 52 mm calibration takes it."""
    folder = tmp_path / "object"
    folder.mkdir()
    for k, (name, img) in enumerate(zip(obj.names, obj.images)):
        S.write_photo(folder / name, img, f35=52 if k == 5 else 26)
    data = json.loads(write_camera(tmp_path / "plain.json", obj).read_text())
    for f35 in (26, 52, 27):
        (tmp_path / f"cam{f35}.json").write_text(json.dumps({**data, "sanity": {"exif_focal_35mm": f35}}))
        assert (
            main(
                [
                    "poses",
                    str(folder),
                    "--camera",
                    str(tmp_path / f"cam{f35}.json"),
                    "--tag-size",
                    str(TAG),
                    "--out",
                    str(tmp_path / f"ds{f35}"),
                    "--no-dataset",
                ]
            )
            == 0
        )
    photos = {
        f35: {p["file"]: p for p in json.loads((tmp_path / f"ds{f35}" / "poses.json").read_text())["photos"]}
        for f35 in (26, 52, 27)
    }
    assert not photos[26][obj.names[5]]["used"] and "another lens or zoom" in photos[26][obj.names[5]]["reason"]
    assert photos[26][obj.names[6]]["used"] and photos[27][obj.names[6]]["used"]  # 4% apart: the same lens
    assert photos[52][obj.names[5]]["used"] and not photos[52][obj.names[6]]["used"]
    # no focal length in the camera file: most photos' lens is the camera's
    assert (
        main(
            [
                "poses",
                str(folder),
                "--camera",
                str(tmp_path / "plain.json"),
                "--tag-size",
                str(TAG),
                "--out",
                str(tmp_path / "ds"),
                "--no-dataset",
            ]
        )
        == 0
    )
    plain = {p["file"]: p for p in json.loads((tmp_path / "ds" / "poses.json").read_text())["photos"]}
    assert "another lens" in plain[obj.names[5]]["reason"] and plain[obj.names[6]]["used"]


@pytest.mark.slow
def test_a_camera_calibrated_at_another_size_is_scaled_and_said(tmp_path, obj):
    """One camera, scaled, fits photos resized alike (the note says it was scaled); a photo
    cropped to another shape is skipped with the reason, not posed with a camera that does not fit it."""
    folder = tmp_path / "object"
    folder.mkdir()
    for k, (name, img) in enumerate(zip(obj.names, obj.images)):
        if k == 3:  # a copy cropped to another shape
            img = np.ascontiguousarray(img[: img.shape[0] * 3 // 4])
        S.write_photo(folder / name, img)
    twice = {
        "K": (obj.K * [[2], [2], [1]]).tolist(),
        "dist": obj.dist.tolist(),
        "width": obj.width * 2,
        "height": obj.height * 2,
        "dictionary": "DICT_4X4_50",
    }  # calibrated on photos twice as large
    twice["K"][0][2], twice["K"][1][2] = obj.K[0, 2] * 2 + 0.5, obj.K[1, 2] * 2 + 0.5  # (pixel centres)
    (tmp_path / "camera.json").write_text(json.dumps(twice))
    for camera, scaled in ((tmp_path / "camera.json", True), (write_camera(tmp_path / "same.json", obj), False)):
        out = tmp_path / f"ds_{camera.stem}"
        assert (
            main(
                [
                    "poses",
                    str(folder),
                    "--camera",
                    str(camera),
                    "--tag-size",
                    str(TAG),
                    "--out",
                    str(out),
                    "--no-dataset",
                ]
            )
            == 0
        )
        poses = json.loads((out / "poses.json").read_text())
        photos = {p["file"]: p for p in poses["photos"]}
        assert not photos[obj.names[3]]["used"] and "aspect ratio" in photos[obj.names[3]]["reason"]
        note = f"the camera ({obj.width * 2}x{obj.height * 2}) is scaled to the photos' {obj.width}x{obj.height}"
        assert (note in poses["notes"]) == scaled and sum("is scaled" in n for n in poses["notes"]) == scaled
        assert sum(p["used"] for p in photos.values()) >= 7
        for name, p in photos.items():
            if p["used"]:
                pos, ang = pose_error(np.array(p["c2w"]), obj.c2w[obj.names.index(name)])
                assert pos < 0.003 and ang < 0.5


def test_a_tag_disagreeing_with_the_others_is_dropped_and_the_pose_kept():
    from nerfkit.capture.poses import solve_pose_robust

    sheet = S.cached_capture("sheet", 12, 5)
    cam = Camera(sheet.K, sheet.dist, sheet.width, sheet.height)
    det = A.detect(sheet.images[0], A.make_detector("DICT_4X4_50"))
    assert len(det.ids) >= 4
    bad = int(det.ids[1])
    moved = A.Detection(det.width, det.height, det.ids, det.corners.copy())
    moved.corners[1] += 6.0  # e.g. the object hides part of this tag, or the paper lifts
    c2w, err, reason, info = solve_pose_robust(moved, cam, sheet.layout, limit=1.0)
    assert c2w is not None and err < 0.5, reason
    assert list(info["tags_dropped"]) == [str(bad)] and bad not in info["tags_used"]
    pos, ang = pose_error(c2w, sheet.c2w[0])
    assert pos < 0.002 and ang < 0.3


def test_poses_use_the_camera_files_layout_when_photos_show_several_tags(tmp_path):
    sheet = S.cached_capture("sheet", 12, 5)
    folder = tmp_path / "object"
    folder.mkdir()
    for name, img in zip(sheet.names[:4], sheet.images[:4]):
        S.write_photo(folder / name, img)
    cam = json.loads(write_camera(tmp_path / "camera.json", sheet).read_text())
    cam["layout"] = sheet.layout.to_json()
    cam["heldout_rms"] = 0.1
    (tmp_path / "camera.json").write_text(json.dumps(cam))
    out = tmp_path / "ds"
    argv = ["poses", str(folder), "--camera", str(tmp_path / "camera.json"), "--tag-size", "0.05", "--out", str(out)]
    assert main([*argv, "--no-dataset"]) == 0
    poses = json.loads((out / "poses.json").read_text())
    assert any("camera file's layout" in n for n in poses["notes"])
    assert sorted(p["file"] for p in poses["photos"]) == sorted(sheet.names[:4])  # the loop below sees all
    for p in poses["photos"]:
        assert p["used"] and len(p["tags_used"]) > 1, p
        pos, ang = pose_error(np.array(p["c2w"]), sheet.c2w[sheet.names.index(p["file"])])
        assert pos < 0.002 and ang < 0.3
    assert main([*argv, "--no-dataset", "--single-tag", "--force"]) == 0
    single = [p for p in json.loads((out / "poses.json").read_text())["photos"] if p["used"]]
    assert len(single) == 4 and all(len(p["tags_used"]) == 1 for p in single)
    # calibrated with a --tag-size 10% short: the layout takes the --tag-size the poses are given
    # (the photos show no other tag), so the cameras stand where they are, and it is said
    cam["layout"] = sheet.layout.scaled(0.9).to_json()
    (tmp_path / "short.json").write_text(json.dumps(cam))
    argv[3] = str(tmp_path / "short.json")
    assert main([*argv, "--no-dataset", "--force"]) == 0
    poses = json.loads((out / "poses.json").read_text())
    assert any("layout has tags of 45.0 mm" in n and "scaled to --tag-size" in n for n in poses["notes"])
    for p in poses["photos"]:
        pos, ang = pose_error(np.array(p["c2w"]), sheet.c2w[sheet.names.index(p["file"])])
        assert p["used"] and pos < 0.002 and ang < 0.3


@pytest.mark.slow
def test_a_waved_sheet_under_the_object_is_posed_on_its_heights():
    # The camera file keeps the printed, flat sheet; the paper under the object lies in waves
    # of its own (up to 1.5 mm here). `poses` measures their heights from the photos first.
    from nerfkit.capture.photos import PhotoRecord
    from nerfkit.capture.poses import PoseConfig, sheet_heights

    cap = S.make_calibration_capture(n=10, seed=6, height=S.cockle(0.0015, 0.2, seed=6))
    cam = Camera(cap.K, cap.dist, cap.width, cap.height)
    det = A.make_detector("DICT_4X4_50")
    records = [PhotoRecord(n, None, A.detect(im, det)) for n, im in zip(cap.names, cap.images)]
    layout, note = sheet_heights(records, cam, cap.layout, PoseConfig())
    assert "off its plane in these photos" in note and not layout.is_planar()
    ids = sorted(layout.tags)
    xy = np.concatenate([layout.tags[t][:, :2] for t in ids])
    assert np.array_equal(xy, np.concatenate([cap.layout.tags[t][:, :2] for t in ids]))  # printed places kept
    truth = cap.scene.height(xy[:, 0], xy[:, 1])
    est = np.concatenate([layout.tags[t][:, 2] for t in ids])
    A_ = np.column_stack([xy, np.ones(len(xy))])
    truth = truth - A_ @ np.linalg.lstsq(A_, truth, rcond=None)[0]  # both less their best-fit plane
    assert np.abs(truth).max() > 0.001 and np.abs(est - truth).max() < 0.0004

    def fit_errors(on):
        return [solve_pose(r.detection, cam, on)[1] for r in records]

    flat, waved = np.median(fit_errors(cap.layout)), np.median(fit_errors(layout))
    assert waved < 0.7 * flat, (waved, flat)
    # one tag, or a layout with heights already: as it is
    single = A.Layout.single(0, 0.05)
    lay, note = sheet_heights(records, cam, single, PoseConfig())
    assert lay is single and note == ""
    assert sheet_heights(records, cam, layout, PoseConfig())[0] is layout


def test_poses_estimate_the_layout_from_photos_showing_several_tags_when_none_is_known(tmp_path):
    """No layout given nor in the camera file, and most photos show several tags (an object
    standing on the sheet): the layout is estimated from the photos, to a fraction of a
    millimetre in the most-seen tag's frame, and each photo is posed on every tag it shows.
    --single-tag poses from one tag."""
    sheet = S.cached_capture("sheet", 12, 5)
    folder = tmp_path / "object"
    folder.mkdir()
    for name, img in zip(sheet.names[:8], sheet.images[:8]):
        S.write_photo(folder / name, img)
    write_camera(tmp_path / "camera.json", sheet)  # no layout in it
    out = tmp_path / "ds"
    argv = [
        "poses",
        str(folder),
        "--camera",
        str(tmp_path / "camera.json"),
        "--tag-size",
        "0.05",
        "--out",
        str(out),
        "--no-dataset",
    ]
    assert main(argv) == 0
    poses = json.loads((out / "poses.json").read_text())
    assert any(n.startswith("estimated the layout of") for n in poses["notes"]), poses["notes"]
    estimated = {int(k): np.array(v) for k, v in poses["layout"]["tags"].items()}
    ref = min(estimated, key=lambda t: np.abs(estimated[t]).sum())  # the tag at the origin: the world
    np.testing.assert_allclose(estimated[ref], A.square_corners(0.05), atol=1e-9)
    to_ref = np.linalg.inv(A.tag_pose_in_layout(sheet.layout.tags[ref]))  # the sheet's frame -> the world
    assert set(estimated) == set(sheet.layout.tags)
    for tag, corners in estimated.items():
        truth = sheet.layout.tags[tag] @ to_ref[:3, :3].T + to_ref[:3, 3]
        assert np.abs(corners - truth).max() < 5e-4, tag  # half a millimetre
    assert sorted(p["file"] for p in poses["photos"]) == sorted(sheet.names[:8])  # the loop below sees all
    for p in poses["photos"]:
        assert p["used"] and len(p["tags_used"]) > 1, p
        pos, ang = pose_error(np.array(p["c2w"]), to_ref @ sheet.c2w[sheet.names.index(p["file"])])
        assert pos < 0.002 and ang < 0.3
    assert main([*argv, "--single-tag", "--force"]) == 0
    poses = json.loads((out / "poses.json").read_text())
    assert not any(n.startswith("estimated the layout") for n in poses["notes"])
    single = [p for p in poses["photos"] if p["used"]]
    assert len(single) == 8 and all(len(p["tags_used"]) == 1 for p in single)


def test_an_estimated_layout_leaves_out_a_tag_of_another_size():
    """Four tags on a plane, one of them printed 30% larger than --tag-size says: the
    layout estimated from exact projections places the other three to a hundredth of a
    millimetre and leaves the odd one out, saying so."""
    from nerfkit.capture.photos import PhotoRecord
    from nerfkit.capture.poses import PoseConfig, layout_from_photos

    size = 0.05
    centres = {0: (0.0, 0.0), 1: (0.09, 0.0), 2: (0.0, 0.09), 3: (0.09, 0.09)}
    truth = {t: A.square_corners(size * (1.3 if t == 3 else 1.0)) + [x, y, 0.0] for t, (x, y) in centres.items()}
    cam = camera_from_focal(800.0, 1024, 768, "test")
    rng = np.random.default_rng(0)
    records = []
    for k in range(10):
        eye = np.array([0.045, 0.045, 0.0]) + [rng.uniform(-0.15, 0.15), rng.uniform(-0.15, 0.15), 0.35]
        z = np.array([0.045, 0.045, 0.0]) - eye
        z /= np.linalg.norm(z)
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])  # world -> camera rows
        rvec, tvec = cv2.Rodrigues(R)[0], -R @ eye
        corners = np.stack([cv2.projectPoints(truth[t], rvec, tvec, cam.K, cam.dist)[0].reshape(4, 2) for t in truth])
        det = A.Detection(1024, 768, np.array(list(truth)), corners)
        records.append(PhotoRecord(f"p{k}.jpg", None, det))
    layout, note = layout_from_photos(records, cam, size, PoseConfig())
    assert sorted(layout.tags) == [0, 1, 2] and "tags [3] fit the photos worse" in note, note
    ref = min(layout.tags, key=lambda t: np.abs(layout.tags[t]).sum())
    for t in layout.tags:
        np.testing.assert_allclose(layout.tags[t] - layout.tags[ref], truth[t] - truth[ref], atol=1e-5)


def test_skip_reasons_are_counted_by_kind_with_their_own_numbers():
    from nerfkit.capture.report import reason_counts

    reasons = [
        "bad fit: reprojection error 3.1 px > 2 px",
        "no tags found",
        "bad fit: reprojection error 9 px > 2 px",
        "taken at 52 mm (the camera's photos at 26 mm)",
        "size 1024x768 has a different aspect ratio",
        "size 800x500 has a different aspect ratio",
    ]
    assert reason_counts(reasons) == (
        "2 x bad fit; 2 x size 1024x768 has a different aspect ratio (or similar); "
        "1 x no tags found; 1 x taken at 52 mm"
    )


def test_the_reasons_table_wraps_a_long_reason_whole():
    from nerfkit.capture.report import table

    reason = (
        "unreadable: cannot decode image (image file is truncated (12 bytes not processed)). The file may be "
        "truncated or corrupt"
    )
    text = table(
        [["a.jpg", "skipped", "-", "", reason], ["bb.jpg", "used", "0", "0.5", "ok"]],
        ["photo", "status", "tags", "err px", "reason"],
        max_width=60,
    )
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 60 and len(lines) > 4
    start = lines[0].index("reason")
    rows = lines[2:-1]  # a.jpg's lines: the reason column, word for word
    assert " ".join(line[start:].strip() for line in rows) == reason
    assert all(line[:start].strip() == "" for line in rows[1:])  # continued under its column
    assert lines[-1].split() == ["bb.jpg", "used", "0", "0.5", "ok"]


def test_the_focal_length_is_refined_on_the_photos_tags_when_they_pin_it():
    # A phone focused near has a longer focal length than when it photographed the sheet: a
    # camera 4% short is fitted back to the photos' own, and the poses follow it.
    from nerfkit.capture.photos import PhotoRecord
    from nerfkit.capture.poses import PoseConfig, refine_focal

    cap = S.cached_capture("sheet", 12, 5)
    det = A.make_detector("DICT_4X4_50")
    records = [PhotoRecord(n, None, A.detect(im, det)) for n, im in zip(cap.names, cap.images)]

    def scaled_focal(factor):
        K = cap.K.copy()
        K[[0, 1], [0, 1]] *= factor
        return Camera(K, cap.dist, cap.width, cap.height, "calibrated")

    true, short = scaled_focal(1.0), scaled_focal(0.96)
    cam, note = refine_focal(records, short, cap.layout, PoseConfig())
    assert cam.K[0, 0] == pytest.approx(cap.K[0, 0], rel=0.004) and cam.K[1, 1] == pytest.approx(cap.K[1, 1], rel=0.004)
    np.testing.assert_array_equal(cam.K[:2, 2], short.K[:2, 2])  # the principal point and distortion kept
    np.testing.assert_array_equal(cam.dist, short.dist)
    assert "want a focal length +4." in note and "posed with it" in note and "refined" in cam.source

    def position_errors(camera):
        return [
            pose_error(solve_pose(r.detection, camera, cap.layout)[0], truth)[0] for r, truth in zip(records, cap.c2w)
        ]

    assert np.median(position_errors(cam)) < 0.3 * np.median(position_errors(short))
    # the right focal length already: kept, and nothing said
    cam, note = refine_focal(records, true, cap.layout, PoseConfig())
    assert cam is true and note == ""
    # 15% off is not the focus: kept, and said
    far_off = scaled_focal(0.85)
    cam, note = refine_focal(records, far_off, cap.layout, PoseConfig())
    assert cam is far_off and "the camera's is kept" in note and note.startswith("WARNING")
    # another phone's camera (35% long): said too, however loosely the tags pin the focal length
    cam, note = refine_focal(records, scaled_focal(1.35), cap.layout, PoseConfig())
    assert "want a focal length -2" in note and "Another phone, lens or zoom" in note
    # too few photos pin nothing
    cam, note = refine_focal(records[:5], short, cap.layout, PoseConfig())
    assert cam is short and note == ""
    # ... nor do photos of another lens count: with 5 of the 12 taken at 2x, 7 are left
    from dataclasses import replace

    lenses = [replace(r, exif_f35=52.0 if i < 5 else 26.0) for i, r in enumerate(records)]
    cam, note = refine_focal(lenses, replace(short, exif_f35=26.0), cap.layout, PoseConfig())
    assert cam.K[0, 0] == short.K[0, 0] and note == ""
    lenses = [replace(r, exif_f35=52.0 if i < 3 else 26.0) for i, r in enumerate(records)]  # 9 left: enough
    assert refine_focal(lenses, replace(short, exif_f35=26.0), cap.layout, PoseConfig())[0].K[0, 0] != short.K[0, 0]


def test_photos_held_the_other_way_count_in_the_focal_length_fitted_before_posing():
    # every photo taken portrait with a landscape calibration: turned into its frame first, the
    # tags refine the focal length as those of the same photos stored landscape do
    from dataclasses import replace

    from nerfkit.capture.photos import PhotoRecord
    from nerfkit.capture.poses import PoseConfig
    from nerfkit.commands.stages.pose import tag_frame

    cap = S.cached_capture("sheet", 12, 5)
    det = A.make_detector("DICT_4X4_50")
    K = cap.K.copy()
    K[[0, 1], [0, 1]] *= 0.96
    short = Camera(K, cap.dist, cap.width, cap.height, "calibrated", sensor_turns=0)

    def frame(records):
        opts = dict(camera_file=None, dictionary="DICT_4X4_50", focal_px=None, tag_id=None, tag_size=None)
        return tag_frame(records, short, cap.layout, **opts, single_tag=False, cfg=PoseConfig())

    stored = [PhotoRecord(n, None, A.detect(im, det)) for n, im in zip(cap.names, cap.images)]
    held = [replace(r, detection=r.detection.turned(1), orientation=6) for r in stored]  # upright: portrait
    assert (held[0].detection.width, held[0].detection.height) == (cap.height, cap.width)
    (cam_a, *_, notes_a), (cam_b, *_, notes_b) = frame(stored), frame(held)
    assert any("want a focal length +4." in n for n in notes_a)
    assert any("want a focal length +4." in n for n in notes_b)
    assert cam_b.K[0, 0] == pytest.approx(cam_a.K[0, 0], rel=1e-6)


def test_photos_of_another_sheet_with_the_same_ids_do_not_use_the_camera_files_layout(tmp_path):
    # The camera file's sheet has its 6 tags in 2 columns; the object photos show a sheet of the
    # same ids in 3 columns. Posed on the file's layout each photo would keep one tag of its
    # choice (frames that disagree by centimetres); the layout is found not to fit, and the
    # sheet's own is estimated from the photos instead.
    sheet = S.cached_capture("sheet", 12, 5)
    other = S.make_calibration_capture(n=8, seed=5, cols=3, gap=0.04, prefix="other")
    folder = tmp_path / "object"
    other.write(folder)
    cam = json.loads(write_camera(tmp_path / "camera.json", sheet).read_text())
    cam["layout"], cam["heldout_rms"] = sheet.layout.to_json(), 0.1
    (tmp_path / "camera.json").write_text(json.dumps(cam))
    argv = ["poses", str(folder), "--camera", str(tmp_path / "camera.json"), "--tag-size", "0.05"]
    assert main([*argv, "--out", str(tmp_path / "ds"), "--no-dataset"]) == 0
    poses = json.loads((tmp_path / "ds" / "poses.json").read_text())
    assert any("the camera file's layout does not fit these photos' tags" in n for n in poses["notes"])
    assert not any("using the camera file's layout" in n for n in poses["notes"])
    used = [p for p in poses["photos"] if p["used"]]
    assert len(used) >= 6 and all(len(p["tags_used"]) >= 3 for p in used)  # the whole sheet, not one tag each
    centres = np.array([np.array(p["c2w"])[:3, 3] for p in used])
    truth = np.array([other.c2w[other.names.index(p["file"])][:3, 3] for p in used])
    apart = np.linalg.norm(centres[:, None] - centres[None], axis=-1)  # (in any frame)
    assert np.abs(apart - np.linalg.norm(truth[:, None] - truth[None], axis=-1)).max() < 0.003
