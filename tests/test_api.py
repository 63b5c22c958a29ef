"""The pipeline from Python (nerfkit.api): typed results, and the same results as the commands."""

from __future__ import annotations

import json

import pytest

import nerfkit
from nerfkit import api
from nerfkit.capture import synthetic as S
from nerfkit.cli import main
from nerfkit.errors import NerfkitError


def write_photos(folder, cap):
    folder.mkdir()
    for name, img in zip(cap.names, cap.images):
        S.write_photo(folder / name, img)
    return folder


@pytest.mark.slow
def test_calibrate_pose_train_render_from_python(tmp_path, capsys):
    sheet, obj = S.cached_capture("sheet", 12, 5), S.cached_capture("object", 10, 1)
    calib, photos = write_photos(tmp_path / "sheet", sheet), write_photos(tmp_path / "object", obj)

    assert nerfkit.calibrate is api.calibrate and nerfkit.pose is api.pose
    camera = nerfkit.calibrate(calib, tmp_path / "camera.json", tag_size=0.05)
    assert isinstance(camera, api.CalibrationResult) and camera.camera_path.is_file()
    assert camera.photos_used >= 8 and camera.rms_px < 1.0 and camera.model
    assert abs(json.loads(camera.camera_path.read_text())["K"][0][0] / sheet.K[0, 0] - 1) < 0.03

    posed = nerfkit.pose(
        photos, tmp_path / "dataset", tag_size=0.06, camera=camera.camera_path, method="tags", max_side=160
    )
    assert isinstance(posed, api.PoseResult) and posed.dataset_path.is_file()
    assert posed.total == len(obj.names) and 7 <= posed.posed <= posed.total

    run = api.train(
        posed.dataset_path,
        tmp_path / "run",
        steps=120,
        quiet=True,
        resolutions="16,32",
        upsample_steps="40",
        device="cpu",
    )
    assert isinstance(run, api.TrainResult) and run.steps == 120 and not run.interrupted
    assert run.preset == "capture"  # the dataset says it is a capture: its settings, unless given
    settings = json.loads((run.run_dir / "config.json").read_text())
    assert settings["model"]["resolutions"] == "16,32" and settings["model"]["rgb_loss"] == "charbonnier"
    assert run.val_psnr is not None and run.val_psnr > 14.0
    assert (run.run_dir / "model.pt").is_file()

    videos = api.render(run.run_dir, frames=3, device="cpu")
    assert [p.name for p in videos.videos] == ["orbit.mp4", "orbit.gif", "depth.mp4"]
    scores = nerfkit.evaluate(run.run_dir, device="cpu")
    assert scores.report_path.is_file() and scores.psnr == pytest.approx(run.val_psnr, abs=0.05)
    capsys.readouterr()


@pytest.mark.slow
def test_the_command_and_the_api_train_the_same_run(tmp_path, sphere_npz, capsys):
    tiny = {"n_samples": 4, "width": 8, "depth": 2, "eval_views": 1, "checkpoint_seconds": 1e9}
    flags = [x for k, v in tiny.items() for x in (f"--{k.replace('_', '-')}", str(v))]
    assert (
        main(
            [
                "train",
                "--data",
                str(sphere_npz),
                "--out",
                str(tmp_path / "cmd"),
                "--model",
                "vanilla",
                "--steps",
                "6",
                "--device",
                "cpu",
                *flags,
            ]
        )
        == 0
    )
    by_api = api.train(sphere_npz, tmp_path / "api", model="vanilla", steps=6, device="cpu", quiet=True, **tiny)
    a = json.loads((tmp_path / "cmd" / "config.json").read_text())
    b = json.loads((tmp_path / "api" / "config.json").read_text())
    a["train"].pop("out"), b["train"].pop("out")
    assert a["train"] == b["train"] and a["model"] == b["model"]
    assert json.loads((tmp_path / "cmd" / "metrics.json").read_text())["step"] == by_api.steps == 6
    assert f"val PSNR: {by_api.val_psnr:.2f} dB" in capsys.readouterr().out


def test_the_api_checks_its_arguments_as_the_command_line_does(tmp_path):
    with pytest.raises(TypeError, match="neither training nor any model has: bogus"):
        api.train("x.npz", tmp_path / "r", bogus=1)
    with pytest.raises(NerfkitError, match="--lr"):
        api.train("x.npz", tmp_path / "r", lr=500.0)
    with pytest.raises(NerfkitError, match="--fps"):
        api.render(tmp_path, fps=0)
    with pytest.raises(TypeError, match="unexpected keyword argument 'colour'"):
        api.render(tmp_path, colour="red")
    with pytest.raises(NerfkitError, match="resume.*lr cannot change"):
        api.resume(tmp_path, lr=0.1)
    with pytest.raises(NerfkitError, match="--focal-px: does nothing with --method colmap"):
        api.pose(tmp_path / "photos", tmp_path / "ds", method="colmap", focal_px=500.0)
    with pytest.raises(NerfkitError, match="--no-dataset: does not apply to --method colmap"):
        api.pose(tmp_path / "photos", tmp_path / "ds", method="colmap", build_dataset=False)
    assert not (tmp_path / "ds").exists()


def test_a_run_trains_and_resumes_from_a_thread_other_than_the_main_one(tmp_path, sphere_npz):
    # signal handlers can be set on the main thread only: a GUI's or a server's worker trains too
    import threading

    tiny = {"n_samples": 4, "width": 8, "depth": 2, "eval_views": 1, "device": "cpu", "quiet": True}
    results, errors = [], []

    def work():
        try:
            results.append(api.train(sphere_npz, tmp_path / "run", model="vanilla", steps=2, **tiny))
            results.append(api.resume(tmp_path / "run", steps=4, quiet=True))
        except Exception as e:  # reported below, on the main thread
            errors.append(e)

    worker = threading.Thread(target=work)
    worker.start()
    worker.join()
    assert not errors, errors
    assert [r.steps for r in results] == [2, 4]


def test_the_api_says_what_is_wrong_with_a_path_before_any_work(tmp_path, sphere_npz):
    tiny = {"n_samples": 4, "width": 8, "depth": 2, "eval_views": 1, "device": "cpu", "quiet": True}
    run = api.train(sphere_npz, tmp_path / "run", model="vanilla", steps=1, **tiny).run_dir
    with pytest.raises(NerfkitError, match=r"^run: is empty"):
        api.render("")
    with pytest.raises(NerfkitError, match=r"^photos: is empty"):
        api.calibrate("", tmp_path / "c.json", tag_size=0.05)
    with pytest.raises(NerfkitError, match=r"^--data: is empty"):
        api.resume(run, steps=2, data="")
    for out in (sphere_npz, sphere_npz / "videos"):  # a file where the folder goes, or in its path
        with pytest.raises(NerfkitError, match=f"{sphere_npz} is a file, not a folder"):
            api.render(run, out=out, quiet=True)
    assert not (run / "videos").exists()  # refused before rendering anything
    # the system's refusal of a file is one clear error too (a folder where the mesh file goes)
    (tmp_path / "m.ply").mkdir()
    with pytest.raises(NerfkitError, match="m.ply.*(folder|directory)"):
        api.export(run, points=tmp_path / "m.ply", force=True)
    # a setting of another model
    with pytest.raises(NerfkitError, match="--sh-degree: is a setting of the fast and splat models, not of vanilla"):
        api.train(sphere_npz, tmp_path / "o", model="vanilla", steps=1, sh_degree=2)


def test_an_option_of_an_output_not_asked_for_is_said_to_do_nothing(tmp_path, sphere_npz, capsys):
    tiny = {"n_samples": 4, "width": 8, "depth": 2, "eval_views": 1, "device": "cpu", "quiet": True}
    run = api.train(sphere_npz, tmp_path / "run", model="vanilla", steps=1, **tiny).run_dir
    capsys.readouterr()
    api.export(
        run, points=tmp_path / "p.ply", resolution=128, color_views=3, stride=2, background_dome=False, quiet=True
    )
    err = capsys.readouterr().err
    assert "note: --resolution, --color-views act only with --mesh" in err and "--stride" not in err
    assert "note: --no-background-dome acts only with --splat" in err
    assert (tmp_path / "p.ply").is_file()
    # the dataset gives the mesh's colours and the points, not the Gaussians (the note comes first)
    with pytest.raises(NerfkitError, match="--splat exports runs of --model splat"):
        api.export(run, splat=tmp_path / "s.ply", data=sphere_npz, quiet=True)
    assert "note: --data acts only with --mesh or --points" in capsys.readouterr().err


def test_numpy_scalars_are_taken_as_pythons(tmp_path, sphere_npz):
    import numpy as np

    tiny = {"n_samples": np.int64(4), "width": 8, "depth": 2, "eval_views": 1, "device": "cpu", "quiet": np.True_}
    result = api.train(sphere_npz, tmp_path / "run", model="vanilla", steps=np.int32(2), lr=np.float32(1e-3), **tiny)
    config = json.loads((result.run_dir / "config.json").read_text())
    assert result.steps == 2 and config["model"]["n_samples"] == 4 and config["train"]["lr"] == pytest.approx(1e-3)


def test_eval_writes_nothing_among_a_datasets_files(tmp_path, sphere_npz):
    # a run moved into its dataset's folder: eval refuses to write there, as render does
    import shutil

    api.convert(sphere_npz, tmp_path / "ds", quiet=True)
    tiny = {"n_samples": 4, "width": 8, "depth": 2, "eval_views": 1, "device": "cpu", "quiet": True}
    run = api.train(tmp_path / "ds", tmp_path / "run", model="vanilla", steps=1, **tiny).run_dir
    (run / "eval_val.json").unlink(missing_ok=True)
    shutil.move(run, tmp_path / "ds" / "run")
    with pytest.raises(NerfkitError, match="is inside the input"):
        api.evaluate(tmp_path / "ds" / "run", device="cpu", quiet=True)
    assert not (tmp_path / "ds" / "run" / "eval_val.json").exists()
