"""The pipeline's stages called from Python with typed arguments (nerfkit.api): the results
are the files written and the figures the commands print, the commands are the same calls,
and arguments are checked as the command line checks them."""

from __future__ import annotations

import argparse
import inspect
import json
from pathlib import Path

import numpy as np
import pytest

from nerfkit import api
from nerfkit.capture import synthetic as S
from nerfkit.cli import main
from nerfkit.commands.options import CalibrateOptions, PosesOptions, RunDeviceOptions
from nerfkit.errors import NerfkitError

TAG = 0.06


@pytest.fixture(scope="module")
def obj():
    return S.cached_capture("object", 10, 1)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory, sphere_npz):
    """A vanilla run of 6 steps on the sphere: enough to render and score."""
    out = tmp_path_factory.mktemp("api_stages") / "run"
    tiny = {"n_samples": 4, "width": 8, "depth": 2, "eval_views": 1, "checkpoint_seconds": 1e9}
    return api.train(sphere_npz, out, model="vanilla", steps=6, device="cpu", quiet=True, **tiny)


def photo_folder(folder, cap):
    folder.mkdir()
    for name, img in zip(cap.names, cap.images):
        S.write_photo(folder / name, img)
    return folder


def camera_file(path, cap):
    keys = {"K": cap.K.tolist(), "dist": cap.dist.tolist(), "width": cap.width, "height": cap.height}
    path.write_text(json.dumps({**keys, "dictionary": "DICT_4X4_50"}))
    return path


def test_pose_a_tag_capture_from_python(tmp_path, obj, capsys):
    """Each posed photo's camera within 3 mm of the truth; the dataset holds every posed photo
    at the asked size; quiet prints nothing; the same call again is refused without force."""
    from nerfkit.capture.dataset import DatasetConfig
    from nerfkit.data.npz import load_npz

    photos, cam = photo_folder(tmp_path / "object", obj), camera_file(tmp_path / "camera.json", obj)
    result = api.pose(
        photos,
        tmp_path / "ds",
        tag_size=TAG,
        camera=cam,
        method="tags",
        max_side=160,
        dataset_settings=DatasetConfig(points=False, val_every=4),
        quiet=True,
    )
    assert capsys.readouterr().out == ""
    assert result.out == tmp_path / "ds" and result.dataset_path == tmp_path / "ds" / "dataset.npz"
    poses = json.loads((tmp_path / "ds" / "poses.json").read_text())
    used = [p for p in poses["photos"] if p["used"]]
    assert result.total == len(obj.names) and result.posed == len(used) == poses["photos_posed"] >= 6
    truth = dict(zip(obj.names, obj.c2w))
    for p in used:
        assert np.linalg.norm(np.array(p["c2w"])[:3, 3] - truth[p["file"]][:3, 3]) < 0.003, p["file"]
    scene = load_npz(result.dataset_path)
    assert sum(len(v) for v in scene.splits.values()) == result.posed and len(scene.val) >= 1
    assert max(scene.train.width, scene.train.height) == 160
    with pytest.raises(NerfkitError, match="--force"):
        api.pose(photos, tmp_path / "ds", tag_size=TAG, camera=cam, method="tags", quiet=True)


def test_pose_without_a_dataset_reports_the_poses_and_prints_what_the_command_prints(tmp_path, obj, capsys):
    photos, cam = photo_folder(tmp_path / "object", obj), camera_file(tmp_path / "camera.json", obj)
    result = api.pose(photos, tmp_path / "a", tag_size=TAG, camera=cam, build_dataset=False)
    by_api = capsys.readouterr().out
    assert result.dataset_path is None and not (tmp_path / "a" / "dataset.npz").exists()
    assert result.posed == json.loads((tmp_path / "a" / "poses.json").read_text())["photos_posed"]
    argv = ["poses", str(photos), "--camera", str(cam), "--tag-size", str(TAG), "--out", str(tmp_path / "b")]
    assert main([*argv, "--no-dataset"]) == 0
    by_command = capsys.readouterr().out
    assert by_api.replace(str(tmp_path / "a"), "OUT") == by_command.replace(str(tmp_path / "b"), "OUT")
    assert f"wrote {tmp_path / 'a' / 'poses.json'}" in by_api


def test_dataset_refuses_a_photo_replaced_since_it_was_posed(tmp_path, obj, capsys):
    """A photo swapped for another after ``poses --no-dataset``: ``dataset`` would give the new
    image the old photo's pose; it names the photo and says to pose again."""
    photos, cam = photo_folder(tmp_path / "object", obj), camera_file(tmp_path / "camera.json", obj)
    api.pose(photos, tmp_path / "ds", tag_size=TAG, camera=cam, build_dataset=False, quiet=True)
    names = sorted(p.name for p in photos.iterdir())
    (photos / names[3]).write_bytes((photos / names[0]).read_bytes() + b"\0")  # another photo, another size
    assert main(["dataset", str(tmp_path / "ds"), "--out", str(tmp_path / "again")]) == 2
    err = capsys.readouterr().err
    assert f"{photos / names[3]}: changed since nerfkit poses posed it (another size)" in err and "--force" in err
    assert not (tmp_path / "again").exists()


def test_render_a_tiny_run_from_python(tmp_path, tiny_run, capsys):
    import imageio.v3 as iio

    videos = api.render(tiny_run.run_dir, out=tmp_path / "v", path="orbit", frames=3, fps=5, device="cpu", quiet=True)
    assert capsys.readouterr().out == ""
    assert [p.name for p in videos.videos] == ["orbit.mp4", "orbit.gif", "depth.mp4"]
    assert all(p.parent == tmp_path / "v" for p in videos.videos)
    assert videos.frames == 3 and videos.step == tiny_run.steps == 6
    assert len(iio.imread(videos.videos[0])) == 3 and len(iio.imread(videos.videos[2])) == 3
    with pytest.raises(NerfkitError, match="exists"):  # a folder of its own is not replaced unasked
        api.render(tiny_run.run_dir, out=tmp_path / "v", path="orbit", frames=3, device="cpu", quiet=True)


def test_evaluate_returns_the_psnr_the_command_prints(tiny_run, capsys):
    scores = api.evaluate(tiny_run.run_dir, split="val", device="cpu", quiet=True)
    assert capsys.readouterr().out == ""
    written = json.loads(scores.report_path.read_text())
    assert scores.report_path == tiny_run.run_dir / "eval_val.json" and scores.scores == written
    assert scores.psnr == written["psnr"] and scores.ssim == written["ssim"] and scores.split == "val"
    assert scores.psnr == pytest.approx(np.mean([v["psnr"] for v in written["per_image"]]), abs=1e-3)
    assert scores.sheet_path == tiny_run.run_dir / "eval_val.png" and scores.sheet_path.is_file()
    assert main(["eval", str(tiny_run.run_dir), "--device", "cpu"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first == f"val: {written['n_images']} views at step 6: PSNR {scores.psnr:.2f} dB, SSIM {scores.ssim:.3f}"
    assert main(["eval", str(tiny_run.run_dir), "--device", "cpu", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["psnr"] == scores.psnr  # the command's JSON: the result's


def test_export_writes_plys_that_read_back(tmp_path, monkeypatch, capsys):
    """The analytic unit sphere as a run: the mesh's vertices and the points lie on it."""
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("skimage")
    from types import SimpleNamespace

    import torch

    from nerfkit.commands import _common
    from nerfkit.data.npz import save_npz
    from nerfkit.data.synthetic import sphere_scene
    from nerfkit.models.base import SceneBounds
    from test_export import SphereModel

    save_npz(sphere_scene(n_train=4, n_val=1, size=16), tmp_path / "s.npz")
    bounds = SceneBounds(2.0, 6.0, np.zeros(3, np.float32), 1.3, np.array([0, 0, 1.0], np.float32))
    train = SimpleNamespace(data=str(tmp_path / "s.npz"), background="black")
    info = SimpleNamespace(bounds=bounds, run_dir=tmp_path, scene={}, train=train)
    opened = _common.OpenRun(SphereModel(bounds), info, 7, torch.device("cpu"), 8192, None)
    asked = []
    monkeypatch.setattr(_common, "open_run", lambda which: asked.append(which) or opened)
    mesh, points = tmp_path / "m.ply", tmp_path / "p.ply"
    result = api.export(
        tmp_path, mesh=mesh, points=points, resolution=32, threshold=50.0, color_views=0, stride=2, quiet=True
    )
    assert capsys.readouterr().out == ""
    assert result.files == (mesh, points) and result.step == 7
    assert asked == [_common.RunToOpen(tmp_path, "auto", 0)]
    read = trimesh.load(mesh, process=False)
    assert read.is_watertight and np.linalg.norm(read.vertices, axis=1).mean() == pytest.approx(1.0, abs=0.02)
    cloud = trimesh.load(points)
    assert len(cloud.vertices) > 20
    np.testing.assert_allclose(np.linalg.norm(cloud.vertices, axis=1), 1.0, atol=1e-4)
    with pytest.raises(NerfkitError, match="nothing to export"):
        api.export(tmp_path)
    with pytest.raises(NerfkitError, match="should end in .ply"):
        api.export(tmp_path, mesh=tmp_path / "m.obj")


def test_the_stages_check_their_arguments_as_the_command_line_does(tmp_path):
    with pytest.raises(NerfkitError, match="--method: 'sfm' is not one of auto, tags, colmap"):
        api.pose(tmp_path, tmp_path / "o", tag_size=TAG, method="sfm")  # type: ignore[arg-type]
    with pytest.raises(NerfkitError, match="--tag-size: 60.0 is not a printed tag's side in metres"):
        api.pose(tmp_path, tmp_path / "o", tag_size=60.0)
    with pytest.raises(NerfkitError, match="--tag-size"):
        api.calibrate(tmp_path, tmp_path / "c.json", tag_size=-1.0)
    with pytest.raises(NerfkitError, match="--detect-size"):
        api.calibrate(tmp_path, tmp_path / "c.json", tag_size=TAG, detect_size=10)
    with pytest.raises(NerfkitError, match="--split: 'bogus' is not one of val, test, train"):
        api.evaluate(tmp_path, split="bogus")  # type: ignore[arg-type]
    with pytest.raises(NerfkitError, match="--fit-views"):
        api.evaluate(tmp_path, fit_views=-1)
    with pytest.raises(NerfkitError, match="--resolution"):
        api.export(tmp_path, mesh=tmp_path / "m.ply", resolution=4)
    from nerfkit.capture.calibrate import CalibrateConfig
    from nerfkit.capture.dataset import DatasetConfig

    with pytest.raises(NerfkitError, match="--dist-model: 'k9' is not one of"):
        api.calibrate(tmp_path, tmp_path / "c.json", tag_size=TAG, settings=CalibrateConfig(dist_model="k9"))
    with pytest.raises(NerfkitError, match="--max-side"):
        api.pose(tmp_path, tmp_path / "o", tag_size=TAG, dataset_settings=DatasetConfig(max_side=3))
    assert not (tmp_path / "o").exists() and not (tmp_path / "c.json").exists()


@pytest.mark.parametrize(
    ("flag", "value", "problem"),
    [
        ("--sfm-max-size", 10, "10 is below the minimum 64 (allowed: 64 to 100000)"),
        ("--sfm-max-size", 200_000, "200000 is above the maximum 100000 (allowed: 64 to 100000)"),
        ("--tag-id", -1, "-1 is below the minimum 0"),
        ("--focal-px", 0.0, "0.0 must be greater than 0"),
        ("--focal-px", float("nan"), "'nan' is not a finite number"),
    ],
)
def test_poses_refuses_a_number_out_of_its_range_from_python_as_on_the_command_line(
    tmp_path, capsys, flag, value, problem
):
    """--sfm-max-size, --tag-id and --focal-px have their ranges in PosesOptions: api.pose refuses
    a value outside one with the command line's words (the flag, what is wrong, what it takes),
    before any photo is read or anything written."""
    argv = ["poses", str(tmp_path), flag, str(value), "--tag-size", str(TAG), "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert (
        capsys.readouterr().err.strip()
        == f"nerfkit poses: error: argument {flag}: {problem} (see nerfkit poses --help)"
    )
    with pytest.raises(NerfkitError) as e:
        api.pose(tmp_path, tmp_path / "o", tag_size=TAG, **{flag[2:].replace("-", "_"): value})
    assert str(e.value) == f"{flag}: {problem}"
    assert list(tmp_path.iterdir()) == []


LEGO = Path(__file__).resolve().parents[1] / "src" / "nerfkit" / "assets" / "lego_200x200.npz"


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda t: api.render(t, fps=None), "--fps: None is not a whole number"),
        (lambda t: api.export(t, points=t / "p.ply", every=None), "--every: None is not a whole number"),
        (lambda t: api.calibrate(t, None, tag_size=TAG), "--out: None is not a path"),
        (lambda t: api.pose(t, None, tag_size=TAG), "out: None is not a path"),
        (lambda t: api.resume(123), "run: 123 is not a path"),
        (lambda t: api.evaluate(t, device=None), "--device: None is not text"),
        (lambda t: api.capture(t, t / "o", steps=5, dictionary=5), "--dictionary: 5 is not text or None"),
        (lambda t: api.train([LEGO], t / "r", steps=5), r"--data: \[.*\] is not a path or None"),
        (lambda t: api.train(LEGO, 123, steps=5), "--out: 123 is not a path or None"),
        (lambda t: api.train(LEGO, t / "r", steps=5, device=None), "--device: None is not text"),
        (
            lambda t: api.train(LEGO, t / "r", model="fast", steps=5, resolutions=[32, 64]),
            "--resolutions: \\[32, 64\\] is not text for the fast model",
        ),
        (
            lambda t: api.train(LEGO, t / "r", steps=5, capture="maybe"),
            "--capture: 'maybe' is not one of auto, on, off",
        ),
        (
            lambda t: api.train(LEGO, t / "r", steps=5, allow_outside_paths="no"),
            "--allow-outside-paths: 'no' is not True or False",
        ),
        (
            lambda t: api.train(LEGO, t / "r", model="fast", steps=5, kernels="x"),
            "--kernels: 'x' is not one of auto, numba, torch",
        ),
        (
            lambda t: api.calibrate(t, t / "c.json", tag_size=TAG, settings={"a": 1}),
            "settings: .* is not a CalibrateConfig",
        ),
    ],
)
def test_a_wrong_kind_of_argument_is_named_before_anything_runs(tmp_path, call, message):
    """Python callers get the command line's checks for the kind of each value too: None where a
    number goes, a list for a path, text for yes/no, a setting outside its choices; nothing is written."""
    with pytest.raises(NerfkitError, match=message):
        call(tmp_path)
    assert list(tmp_path.iterdir()) == []


# a command's flag -> the API's argument of another name; --no-X flags are X=True by default
RENAMED = {"dict": "dictionary", "no_cache": "cache", "no_dataset": "build_dataset", "no_ground": "ground"}
NEGATED = {"no_cache", "no_dataset", "no_ground"}


@pytest.mark.parametrize(
    ("command", "function", "argv", "options"),
    [
        ("calibrate", api.calibrate, ["photos"], (CalibrateOptions,)),
        ("poses", api.pose, ["photos", "--out", "o"], (PosesOptions,)),
        ("frames", api.frames, ["clip", "--out", "o"], (api.FramesOptions,)),
        ("render", api.render, ["run"], (api.RenderOptions, RunDeviceOptions)),
        ("eval", api.evaluate, ["run"], (api.EvalOptions, RunDeviceOptions)),
        ("export", api.export, ["run"], (api.ExportOptions, RunDeviceOptions)),
    ],
)
def test_the_api_defaults_are_the_commands(command, function, argv, options):
    """Every flag of the command is an argument of the API function with the flag's default
    (a ``--no-X`` flag: ``X=True``; the settings dataclasses' flags: their ``*settings``
    argument, None; the flags of the command's ``options`` dataclasses: their defaults, which the
    command fills in for the flags not given), so that a call and a command line without
    options do the same."""
    import dataclasses

    from nerfkit.cli import build_parser
    from nerfkit.config import dataclass_from_args

    args = build_parser(command).parse_args([command, *argv])
    for kind in options:  # as the command calls the function
        filled = dataclass_from_args(kind, args)
        flagged = [f for f in dataclasses.fields(kind) if f.metadata.get("cli") is not False]
        assert all(getattr(args, f.name) is None for f in flagged)  # (a field without: the command's own flag)
        args = argparse.Namespace(**{**vars(args), **dataclasses.asdict(filled)})
    params = inspect.signature(function).parameters
    skipped = {"command", "func", "verbose", "json", "run", "photos"}
    for dest, value in vars(args).items():
        if dest in skipped:
            continue
        name = RENAMED.get(dest, dest.removeprefix("no_") if dest in NEGATED else dest)
        if name not in params:  # a field of a settings dataclass: unset flags are None
            assert value is None, dest
            assert any(p.endswith("settings") for p in params), dest
            continue
        default = params[name].default
        if default is inspect.Parameter.empty:  # given on both sides (poses --out)
            continue
        expected = (not value) if dest in NEGATED else value
        assert default == expected, (dest, default, expected)
