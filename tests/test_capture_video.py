"""`nerfkit capture` from a video, without tags: frames chosen from a clip rendered here, posed by
structure-from-motion with the table found, a splat trained and exported (and the object's alone)."""

from __future__ import annotations

import argparse
import json
import re

import numpy as np
import pytest

from nerfkit.cli import main
from nerfkit.errors import NerfkitError

cv2 = pytest.importorskip("cv2")
imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")

from conftest import write_mp4 as write_mp4_file  # noqa: E402

W, H, FOCAL = 240, 180, 220.0
OBJECT = np.array([0.0, 0.0, 0.05])  # a sphere of radius 0.05 resting on the table z = 0
TARGET = np.array([0.0, 0.0, 0.04])


def placemat(n: int = 400, seed: int = 0) -> np.ndarray:
    """(n, n, 3) uint8: colour noise with discs, a patterned cloth SfM finds points on."""
    rng = np.random.default_rng(seed)
    img = cv2.resize(rng.random((n // 8, n // 8, 3)), (n, n), interpolation=cv2.INTER_CUBIC)
    img = (np.clip(img, 0, 1) * 255).astype(np.uint8)
    for _ in range(300):
        colour = tuple(int(c) for c in rng.integers(0, 255, 3))
        cv2.circle(img, (int(rng.integers(0, n)), int(rng.integers(0, n))), int(rng.integers(3, 14)), colour, -1)
    return img


def orbit_clip(n: int, blur: set[int]) -> tuple[list[np.ndarray], np.ndarray]:
    """n frames (H, W, 3) of one turn around a textured sphere on a patterned cloth on a
    table, the camera bobbing between 30 and 40 degrees up; frames in ``blur`` shaken
    (gaussian blur). Returns the frames and their true camera-to-world poses (n, 4, 4),
    OpenCV axes, the table z = 0."""
    from nerfkit.cameras import look_at
    from nerfkit.capture.synthetic import Decal, Sphere, SynthScene, camera_rays, render, table_texture

    K = np.array([[FOCAL, 0, W / 2], [0, FOCAL, H / 2], [0, 0, 1]])
    scene = SynthScene([Decal(placemat(), -0.2, 0.2, 0.001)], [Sphere(OBJECT, 0.05)], table=table_texture(0))
    rays = camera_rays(K, np.zeros(5), W, H, 2)
    frames, poses = [], []
    rng = np.random.default_rng(0)
    for i in range(n):
        az = 2 * np.pi * i / n
        el = np.deg2rad(35 + 5 * np.sin(2 * az))
        eye = TARGET + 0.35 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        c2w = look_at(eye, TARGET, np.array([0.0, 0.0, 1.0]))
        frames.append(render(scene, rays, c2w, 2, blur=4.0 if i in blur else 0.0, noise=1.0, rng=rng))
        poses.append(c2w)
    return frames, np.stack(poses)


def write_mp4(path, frames, fps: int = 10) -> None:
    write_mp4_file(path, frames, fps=fps, macro_block_size=4)


def headings(text: str) -> list[tuple[int, int, str]]:
    """The capture's stage headings ``[k/N] stage`` in ``text`` (not their parts, ``stage: part``)."""
    found = re.findall(r"^\[(\d+)/(\d+)\] ([^:\n]+)$", text, re.M)
    return [(int(k), int(n), name) for k, n, name in found]


N_FRAMES, KEEP = 48, 24
BLURRED = {3, 10, 17, 24, 31, 38, 45}


@pytest.mark.slow
def test_a_clip_without_tags_is_framed_posed_on_its_table_and_exported_as_a_splat(tmp_path, capsys):
    from nerfkit.capture.dome import DOME_GAUSSIANS, on_dome
    from nerfkit.capture.splats import in_box, object_box
    from nerfkit.sfm.dataset import load_sfm_result
    from nerfkit.sfm.frame import compare_poses, reconstruction_c2w
    from nerfkit.splat_files import read_splat_ply
    from nerfkit.train.checkpoint import read_run

    frames, truth = orbit_clip(N_FRAMES, BLURRED)
    clip = tmp_path / "orbit.mp4"
    write_mp4(clip, frames)
    out = tmp_path / "my_object"
    argv = ["capture", str(clip), "--out", str(out), "--model", "splat", "--steps", "30", "--clip-frames", str(KEEP)]
    assert main([*argv, "--frames", "2"]) == 0, capsys.readouterr().err
    text = capsys.readouterr().out

    # each stage headed [k/N] in order, N counted from this route; structure-from-motion's steps under poses
    plan = ["frames", "poses", "training the splat", "evaluation of the splat", "rendering the splat's videos"]
    assert headings(text) == [(k + 1, 6, name) for k, name in enumerate([*plan, "export of the splat files"])]
    parts = re.findall(r"^\[2/6\] poses: (\w+)$", text, re.M)
    assert parts == ["features", "matching", "mapping"]
    assert text.index("[2/6] poses\n") < text.index("[2/6] poses: features") < text.index("[3/6] training")

    # frames: the shaken ones are never kept, the rest spread along the whole turn
    report = json.loads((out / "frames" / "frames.json").read_text())
    kept = [f["frame"] for f in report["frames"]]
    assert report["read"] == N_FRAMES and len(kept) == KEEP and not set(kept) & BLURRED
    assert report["dropped"]["blurred"] == len(BLURRED)
    assert max(np.diff(kept)) <= 4 and kept[0] <= 2 and kept[-1] >= N_FRAMES - 3  # one per window of 2

    # poses: every kept frame registered, as the truth up to a similarity; the table found, z = 0 on it
    sfm = json.loads((out / "dataset" / "sfm_report.json").read_text())
    assert sfm["n_registered"] >= 0.9 * KEEP and sfm["ground"] is not None and sfm["ground"]["tilt_deg"] < 2
    result = load_sfm_result(out / "dataset")
    names, c2w = reconstruction_c2w(result.reconstruction)
    ref = truth[[kept[int(n[len("frame_") : -len(".jpg")]) - 1] for n in names]]
    errors = compare_poses(c2w, ref)
    assert errors["rot_err_deg_max"] < 1.0 and errors["pos_err_rel_median"] < 0.01
    # heights above the table: the truth's, scaled (a plane through the sphere's top would not be)
    np.testing.assert_allclose(c2w[:, 2, 3], ref[:, 2, 3] / errors["scale"], rtol=0.03)

    # the splat: the PLY reads back as the run's Gaussians, .splat 32 bytes each, the object's a box of them
    g = read_splat_ply(out / "splat.ply")
    steps = json.loads((out / "splat_run" / "metrics.json").read_text())["step"]
    assert steps == 30 and len(g) > 100 and g.sh_rest.shape[1:] == (15, 3)
    assert (out / "splat.splat").stat().st_size == 32 * len(g)
    bounds = read_run(out / "splat_run").bounds
    lo, hi, _ = object_box(bounds)
    assert int(on_dome(g.means, bounds).sum()) == DOME_GAUSSIANS  # the learned background, behind the rest
    alone = read_splat_ply(out / "splat_object.ply")
    inside = in_box(g.means, lo, hi)
    assert 0 < len(alone) == int(inside.sum()) < len(g)
    np.testing.assert_array_equal(alone.means, g.means[inside])
    np.testing.assert_array_equal(alone.sh_rest, g.sh_rest[inside])

    # the summary: frames, poses, the scene found, the scores and the files with their viewers
    summary = text.split("capture done")[1]
    scores = json.loads((out / "splat_run" / "eval_val.json").read_text())
    assert (
        f"read {N_FRAMES}, kept {KEEP}" in summary
        and f"{sfm['n_registered']} posed by structure-from-motion" in summary
    )
    assert "an object on a table" in summary and "SuperSplat" in summary and str(out / "splat_object.ply") in summary
    assert f"{scores['psnr']:.2f} dB" in summary and "  NeRF  " not in summary  # no NeRF trained
    assert f"a far dome of {DOME_GAUSSIANS} Gaussians" in summary

    # again: every step kept
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert [name for _, _, name in headings(text)] == [*plan, "export of the splat files"]
    assert "frames: " in text and text.count("is there from an earlier run, kept") == 8
    assert "  time  " not in text


def test_object_box_is_the_dataset_box_else_the_sphere_cube_above_the_table():
    from nerfkit.capture.splats import object_box
    from nerfkit.models.base import SceneBounds

    box = (np.array([-1.0, -1, 0]), np.array([1.0, 1, 2]))
    bounds = SceneBounds(1.0, 9.0, np.array([0.0, 0, 1]), 2.0, np.array([0.0, 0, 1]), object_box=box)
    lo, hi, how = object_box(bounds)
    np.testing.assert_array_equal(lo, box[0])
    np.testing.assert_array_equal(hi, box[1])
    assert "sparse points" in how
    bounds.object_box, bounds.table = None, np.array([0.0, 0, 1, 0.5])  # the table at z = -0.5
    lo, hi, how = object_box(bounds)
    np.testing.assert_allclose(lo, [-2, -2, -0.5])
    np.testing.assert_allclose(hi, [2, 2, 3])
    assert "above the table" in how
    bounds.table = None
    lo, _, how = object_box(bounds)
    np.testing.assert_allclose(lo, [-2, -2, -1])
    assert "no table" in how


def test_the_object_splat_keeps_exactly_the_gaussians_in_the_box(tmp_path):
    from nerfkit.capture.splats import write_object_splat
    from nerfkit.splat_files import Gaussians, read_splat_ply, write_splat_ply

    rng = np.random.default_rng(0)
    n = 200
    g = Gaussians(
        rng.uniform(-2, 2, (n, 3)).astype(np.float32),
        rng.normal(-3, 0.5, (n, 3)).astype(np.float32),
        rng.normal(0, 1, (n, 4)).astype(np.float32),
        rng.normal(0, 2, n).astype(np.float32),
        rng.normal(0, 1, (n, 1, 3)).astype(np.float32),
        rng.normal(0, 0.1, (n, 15, 3)).astype(np.float32),
    )
    write_splat_ply(tmp_path / "all.ply", g)
    back = read_splat_ply(tmp_path / "all.ply")  # the INRIA layout round-trips every value
    for name in ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest"):
        np.testing.assert_array_equal(getattr(back, name), getattr(g, name))
    lo, hi = np.array([-1.0, -1, 0]), np.array([1.0, 1, 1])
    assert write_object_splat(tmp_path / "all.ply", tmp_path / "obj.ply", (lo, hi)) == (
        int(np.sum(np.all((g.means >= lo) & (g.means <= hi), axis=1))),
        n,
    )
    obj = read_splat_ply(tmp_path / "obj.ply")
    assert 0 < len(obj) < n and np.all((obj.means >= lo) & (obj.means <= hi))
    outside = ~np.all((g.means >= lo) & (g.means <= hi), axis=1)
    assert not set(map(tuple, obj.means.tolist())) & set(map(tuple, g.means[outside].tolist()))
    kept, _ = write_object_splat(tmp_path / "all.ply", tmp_path / "obj.splat", (lo, hi))
    assert (tmp_path / "obj.splat").stat().st_size == 32 * kept


def _args(**kw) -> argparse.Namespace:
    base = {"tag_size": None, "method": "auto", "calib": None, "camera": None, "sheet_tag_size": None}
    return argparse.Namespace(**{**base, **kw}, photos="x")


def test_the_route_is_sfm_without_a_tag_and_for_a_video_without_a_camera():
    from nerfkit.commands.capture import _route

    assert _route(_args(), video=False) == "colmap" and _route(_args(), video=True) == "colmap"
    assert _route(_args(tag_size=0.06), video=False) == "auto"  # today's tag route, photos with EXIF
    assert _route(_args(tag_size=0.06, method="tags"), video=False) == "tags"
    assert _route(_args(tag_size=0.06), video=True) == "colmap"  # frames have no focal: the tag fixes scale
    assert _route(_args(tag_size=0.06, camera="c.json"), video=True) == "auto"
    assert _route(_args(tag_size=0.06, method="colmap"), video=False) == "colmap"


def test_sfm_posing_too_few_frames_stops_the_capture_saying_what_to_do(tmp_path):
    from nerfkit.commands.capture import _check_posed

    (tmp_path / "sfm_report.json").write_text(json.dumps({"n_photos": 40, "n_registered": 19}))
    with pytest.raises(NerfkitError, match=r"posed only 19 of the 40 frames \(at least 20 are needed") as e:
        _check_posed(tmp_path, "frames")
    assert "moving slowly all the way around" in str(e.value) and "--clip-frames" in str(e.value)
    (tmp_path / "sfm_report.json").write_text(json.dumps({"n_photos": 40, "n_registered": 20}))
    _check_posed(tmp_path, "frames")  # half of them: enough
    (tmp_path / "sfm_report.json").write_text(json.dumps({"n_photos": 12, "n_registered": 9}))
    with pytest.raises(NerfkitError, match="at least 10"):
        _check_posed(tmp_path, "photos")


def test_capture_refuses_what_no_route_can_do(tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    out = str(tmp_path / "out")
    assert main(["capture", str(photos), "--out", out, "--method", "tags"]) == 2
    assert "need the tag's size" in capsys.readouterr().err
    assert main(["capture", str(photos), "--out", out, "--calib", str(tmp_path)]) == 2
    assert "--sheet-tag-size" in capsys.readouterr().err
    (tmp_path / "notes.txt").write_text("x")
    assert main(["capture", str(tmp_path / "notes.txt"), "--out", out]) == 2
    assert "is a file, not a folder of photos or a video" in capsys.readouterr().err
    (tmp_path / "broken.mp4").write_bytes(b"not a video")
    assert main(["capture", str(tmp_path / "broken.mp4"), "--out", out]) == 2
    assert "broken.mp4" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # refused before any step


@pytest.mark.parametrize(
    ("n", "sigma", "said", "fix"),
    [(6, 0.0, "is too short", "Film a longer clip"), (40, 12.0, "blurred", "Film slower")],
)
def test_a_clip_too_short_or_too_blurred_stops_at_the_frames_saying_what_to_do(tmp_path, capsys, n, sigma, said, fix):
    rng = np.random.default_rng(1)
    tex = placemat(320)
    frames = []
    for i in range(n):
        f = tex[i * 2 : i * 2 + 120, i * 3 : i * 3 + 160].copy()
        frames.append(cv2.GaussianBlur(f, (0, 0), sigma) if sigma else f)
    if not sigma:  # (noise on a blurred frame would give it edges again)
        frames = [np.clip(f + rng.normal(0, 1, f.shape), 0, 255).astype(np.uint8) for f in frames]
    write_mp4(tmp_path / "clip.mp4", frames)
    assert main(["capture", str(tmp_path / "clip.mp4"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "nerfkit frames: error:" in err and said in err and fix in err
    assert not (tmp_path / "out" / "dataset").exists()


def test_the_summary_names_the_scene_structure_from_motion_found():
    from nerfkit.commands.capture import scene_kind_text

    assert "an object on a table" in scene_kind_text({"frame": "normalised (no tag): ...", "ground": {"tilt_deg": 1}})
    assert "no table found" in scene_kind_text({"frame": "normalised (no tag): ...", "ground": None})
    assert "in metres" in scene_kind_text({"frame": "metric, from ArUco tag 0 (6 cm) ...", "ground": None})
