"""`nerfkit capture`: the whole flow on a synthetic capture, kept and redone."""

from __future__ import annotations

import json
import re

import imageio.v3 as iio
import numpy as np
import pytest

from nerfkit.capture import synthetic as S
from nerfkit.cli import main


def write_photos(folder, cap):
    folder.mkdir()
    for name, img in zip(cap.names, cap.images):
        S.write_photo(folder / name, img)
    return folder


@pytest.mark.slow
def test_capture_runs_every_step_keeps_them_resumes_and_force_redoes(tmp_path, capsys, monkeypatch):
    from nerfkit.train import trainer

    sheet, obj = S.cached_capture("sheet", 12, 5), S.cached_capture("object", 10, 1)
    calib, photos = write_photos(tmp_path / "sheet", sheet), write_photos(tmp_path / "object", obj)
    out = tmp_path / "my_object"
    argv = [
        "capture",
        str(photos),
        "--calib",
        str(calib),
        "--sheet-tag-size",
        "0.05",
        "--tag-size",
        "0.06",
        "--out",
        str(out),
        "--method",
        "tags",
        "--model",
        "fast",
        "--max-side",
        "160",
        "--steps",
        "160",
        "--frames",
        "3",
    ]
    full_run = trainer.Trainer.run
    monkeypatch.setattr(trainer.Trainer, "run", lambda self, stop_after=None: full_run(self, stop_after=40))
    assert main(argv) == 0, capsys.readouterr().err  # training cut short at step 40 of 160
    text = capsys.readouterr().out
    monkeypatch.setattr(trainer.Trainer, "run", full_run)
    camera = json.loads((out / "camera.json").read_text())
    assert abs(camera["K"][0][0] / sheet.K[0, 0] - 1) < 0.03  # the camera, from the sheet's photos
    photos_json = json.loads((out / "dataset" / "poses.json").read_text())["photos"]
    found = [p for p in photos_json if p.get("tags")]
    assert len(found) >= 7 and all(p["used"] for p in found)
    for p in found:  # posed at the object tag's size: metres, as the truth
        k = obj.names.index(p["file"])
        assert np.linalg.norm(np.array(p["c2w"])[:3, 3] - obj.c2w[k][:3, 3]) < 0.005
    run = out / "run"
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["step"] == 40 and metrics["finished"] is False
    scores = json.loads((run / "eval_val.json").read_text())
    assert len(iio.imread(run / "videos" / "orbit.mp4")) == 3
    assert (run / "eval_val.png").exists() and (run / "plots" / "psnr.png").exists()
    # the summary says what came out, with the eval's own figures
    assert "capture done" in text and f"{scores['psnr']:.2f} dB" in text and str(run / "videos") in text
    assert "training photos. A NeRF from this few" in text.split("capture done")[1]  # 6 of them: said again
    # where the photos look from: said after posing and again in the summary, beside its chart
    assert text.count("coverage: the photos look from") == 2 and (out / "dataset" / "coverage.png").exists()
    assert f"(chart: {out / 'dataset' / 'coverage.png'})" in text.split("capture done")[1]
    # the synthetic sphere's texture gives SfM no points (it starts from the whole region): said
    # twice, and without the object's box how well the photos agree on the table is not measured
    assert text.count("note: the sparse points show no object near the middle of the photos") == 2
    assert text.count("the photos agree on the table is not measured") == 2
    assert "agreement: the training photos show the table" not in text
    took = re.search(r"\n  time      (.*); (.*) in all\n", text)  # each step run now, in the order it ran
    assert [part.rsplit(" ", 2)[0] for part in took[1].split(", ")] == [
        "calibrate",
        "poses",
        "train",
        "eval",
        "render",
        "object",
        "export",
    ]
    # a NeRF too faint to mesh (as at 40 steps here) is still a capture: the summary says so
    assert (run / "mesh.ply").exists() == ("mesh      none" not in text)

    # a copy whose checkpoints are gone: its NeRF is kept as it is, never trained over from step 0
    import shutil

    cut = shutil.copytree(out, tmp_path / "cut")
    shutil.rmtree(cut / "run" / "checkpoints")
    assert main([*argv[: argv.index("--out") + 1], str(cut), *argv[argv.index("--out") + 2 :]]) == 0
    assert "it was cut short and has no checkpoint to go on from: --force" in capsys.readouterr().out
    assert json.loads((cut / "run" / "metrics.json").read_text())["step"] == 40

    # again: the run cut short goes on to its 160 steps; the camera and dataset are kept
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert f"train --resume {run}" in text and text.count("is there from an earlier run, kept") == 2
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["step"] == 160 and metrics["finished"] is True
    assert [p.name for p in (run / "checkpoints").iterdir()] == ["step_00000160.pt"]  # one resume checkpoint
    assert (run / "mesh.ply").exists() and f"mesh      {run / 'mesh.ply'}" in text
    assert len(iio.imread(run / "videos" / "object.mp4")) == 3  # the object alone, too
    assert "the object alone: object.mp4, object.gif, object_depth.mp4" in text
    obj = json.loads((run / "eval_val.json").read_text())["object"]  # the object's own pixels, scored
    assert f"the object's own pixels: {obj['psnr']:.2f} dB as rendered, {obj['psnr_fitted']:.2f} fitted" in text

    # again: every step kept, the run not trained again, its eval, videos and mesh not made again
    assert main([*argv[:-2]]) == 0  # (--frames asks for the videos again)
    text = capsys.readouterr().out
    assert text.count("is there from an earlier run, kept") == 7 and "its budget is" not in text
    assert "  time  " not in text  # nothing run now
    assert main([*argv[:-4], "--steps", "100"]) == 0  # a smaller budget: said, not trained again
    assert "its budget is 160 steps, not the 100 steps asked for now: --force" in capsys.readouterr().out
    assert json.loads((run / "metrics.json").read_text())["step"] == 160
    assert main([*argv[:-4], "--minutes", "9"]) == 0  # minutes for a run by steps: the same
    assert "its budget is 160 steps, not the 9 minutes asked for now: --force" in capsys.readouterr().out
    bare = shutil.copytree(out, tmp_path / "bare")  # finished, its checkpoint gone: nothing to go on from
    shutil.rmtree(bare / "run" / "checkpoints")
    assert (
        main([*argv[: argv.index("--out") + 1], str(bare), *argv[argv.index("--out") + 2 : -4], "--steps", "180"]) == 0
    )
    assert "(and no checkpoint is left to go on from): --force" in capsys.readouterr().out
    assert json.loads((bare / "run" / "metrics.json").read_text())["step"] == 160
    assert main([*argv[:-4], "--steps", "180"]) == 0  # a larger one: trained on, and shown again
    text, err = capsys.readouterr()
    assert "its budget was 160 steps: training goes on to the 180 steps asked for now" in text
    assert f"train --resume {run} --steps 180" in text and "resumed from step_00000160.pt" in err
    assert json.loads((run / "metrics.json").read_text())["step"] == 180
    assert json.loads((run / "config.json").read_text())["train"]["steps"] == 180
    assert text.count("is there from an earlier run, kept") == 3  # camera, dataset, NeRF: the rest is new

    # other inputs are refused, not mixed with the earlier results
    other = [*argv]
    other[other.index("--tag-size") + 1] = "0.07"
    assert main(other) == 2
    assert "tag_size: 0.06 then, 0.07 now" in capsys.readouterr().err

    # --force: calibrated, posed and trained again, in place
    assert main([*argv[:-4], "--steps", "20", "--frames", "2", "--force", "--no-mesh"]) == 0
    assert "mesh      not made (--no-mesh)" in capsys.readouterr().out
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["step"] == 20 and metrics["finished"] is True
    assert not (out / "run-2").exists()

    # the summary repeats the calibration's warnings
    from nerfkit.commands.capture import summary

    camera["sanity"]["warnings"] = ["focal length is uncertain (+/-240.9 px); add photos from more varied angles"]
    (tmp_path / "camera.json").write_text(json.dumps(camera))
    assert metrics["notes"] == []  # the sphere lies within its box
    metrics["notes"] = ["the object reaches the x- face of the model's box at the end of training"]
    (run / "metrics.json").write_text(json.dumps(metrics))
    text = summary(out, tmp_path / "camera.json", out / "dataset", run, None)
    assert "WARNING: focal length is uncertain (+/-240.9 px)" in text and "mesh      none (see above)" in text
    assert "\n            note: the object reaches the x- face" in text.split("  NeRF  ")[1]  # the trainer's notes
    # the phone's exposure: named when the held-out photos' colour alone gains 0.75 dB or more
    scores = json.loads((run / "eval_val.json").read_text())
    for gain, said in ((0.7, False), (0.8, True)):
        scores["colour_only"]["psnr"] = scores["psnr"] + gain
        (run / "eval_val.json").write_text(json.dumps(scores))
        text = summary(out, tmp_path / "camera.json", out / "dataset", run, None)
        assert ("each photo's overall colour changed (the phone's exposure or white balance" in text) == said
        assert "(the agreement above says how much)" not in text  # the dataset did not measure it
    # with an agreement measured (a dataset whose object has its box), the summary says it and
    # points to it
    tj = json.loads((out / "dataset" / "transforms.json").read_text())
    tj["nerfkit"]["agreement"] = {"psnr": 19.0, "psnr_exposure_evened": 21.5, "points": 900, "photos_per_point": 6.0}
    (out / "dataset" / "transforms.json").write_text(json.dumps(tj))
    text = summary(out, tmp_path / "camera.json", out / "dataset", run, None)
    assert "agreement: the training photos show the table around the object in the same colours to 19.0 dB" in text
    assert "(the agreement above says how much)" in text


def test_capture_refuses_a_missing_folder_a_file_as_out_and_an_out_among_the_photos(tmp_path, capsys):
    photos = tmp_path / "object"
    photos.mkdir()
    assert main(["capture", str(tmp_path / "nowhere"), "--tag-size", "0.06", "--out", str(tmp_path / "o")]) == 2
    assert "nowhere: no such file or folder" in capsys.readouterr().err
    (tmp_path / "a_file").write_text("x")  # a file that is no video
    assert main(["capture", str(tmp_path / "a_file"), "--tag-size", "0.06", "--out", str(tmp_path / "o")]) == 2
    assert "a_file: is a file, not a folder of photos or a video" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    assert main(["capture", str(photos), "--tag-size", "0.06", "--out", str(tmp_path / "file")]) == 2
    assert "is not a folder" in capsys.readouterr().err
    assert (
        main(
            [
                "capture",
                str(photos),
                "--tag-size",
                "0.06",
                "--out",
                str(tmp_path / "o"),
                "--calib",
                str(tmp_path / "nowhere"),
            ]
        )
        == 2
    )
    assert "--calib" in capsys.readouterr().err
    # nothing is written among the photos; the photos may sit in the capture's folder
    assert main(["capture", str(photos), "--tag-size", "0.06", "--out", str(photos / "out")]) == 2
    assert "inside the input" in capsys.readouterr().err and not (photos / "out").exists()
    nested = tmp_path / "mine" / "photos"
    nested.mkdir(parents=True)
    assert main(["capture", str(nested), "--tag-size", "0.06", "--out", str(tmp_path / "mine")]) == 2
    assert "holds no images" in capsys.readouterr().err  # it got as far as reading the (empty) folder
    # a step's error, with its traceback under --verbose
    iio.imwrite(nested / "blank.png", np.full((48, 64, 3), 128, np.uint8))  # a photo without a tag
    (nested / "IMG_0001.MOV").write_bytes(b"a clip beside the photos: not read, said so")
    assert main(["--verbose", "capture", str(nested), "--tag-size", "0.06", "--out", str(tmp_path / "mine")]) == 2
    out, err = capsys.readouterr()
    assert err.count("Traceback") == 3  # the step's own, and the capture's with its cause chained
    assert f"note: {nested} also holds 1 video (IMG_0001.MOV), not read" in out


def test_capture_refuses_before_any_step_what_a_later_step_would_trip_on(tmp_path, capsys):
    photos = tmp_path / "object"
    photos.mkdir()
    iio.imwrite(photos / "a.png", np.full((48, 64, 3), 128, np.uint8))
    out = tmp_path / "o"
    base = ["capture", str(photos), "--tag-size", "0.06", "--out", str(out)]
    assert main([*base, "--calib", str(photos)]) == 2  # the same folder for the sheet and the object
    assert "is both the calibration folder and the object's" in capsys.readouterr().err
    # a camera file in --out that no capture recorded is not taken for the capture's own
    out.mkdir()
    (out / "camera.json").write_text("{}")
    sheet = tmp_path / "sheet"
    sheet.mkdir()
    assert main([*base, "--calib", str(sheet)]) == 2
    assert "holds camera.json that no `nerfkit capture` recorded in capture.json" in capsys.readouterr().err
    assert (out / "camera.json").read_text() == "{}" and not (out / "capture.json").exists()
    # a video's frames posed by the tag alone: they have no focal length to start from
    clip = tmp_path / "clip.mp4"
    clip.write_bytes(b"not looked at: refused before")
    assert main(["capture", str(clip), "--tag-size", "0.06", "--method", "tags", "--out", str(tmp_path / "v")]) == 2
    assert "a video's frames carry no focal length" in capsys.readouterr().err
    assert not (tmp_path / "v").exists()


def test_a_rerun_keeps_results_only_while_what_they_were_made_from_holds(tmp_path):
    import argparse

    from nerfkit.commands.capture import _inputs, _same_inputs
    from nerfkit.errors import NerfkitError

    def inputs(photos, calib, **kw):
        return _inputs(
            argparse.Namespace(
                **{
                    "photos": str(photos),
                    "calib": calib and str(calib),
                    "camera": None,
                    "tag_size": 0.06,
                    "sheet_tag_size": None,
                    "dict": None,
                    "method": "auto",
                    "max_side": None,
                    **kw,
                }
            )
        )

    photos, sheet, out = (tmp_path / n for n in ("object", "sheet", "out"))
    for folder in (photos, sheet, out):
        folder.mkdir()
    for i in range(3):
        (photos / f"IMG_{i}.JPG").write_bytes(b"x" * (i + 1))
        (sheet / f"S_{i}.JPG").write_bytes(b"y")
    (photos / "._IMG_0.JPG").write_bytes(b"meta")  # hidden: not a photo
    camera, made = out / "camera.json", [out / "dataset.npz", out / "config.json"]
    first = inputs(photos, sheet)
    assert first["photo_files"].startswith("3 photos (")
    (out / "capture.json").write_text(json.dumps({"inputs": first}))

    def check(now):
        _same_inputs(out, now, camera, made, [camera, *made, out / "capture.json"])

    (photos / "IMG_3.JPG").write_bytes(b"z")  # a photo added
    added = inputs(photos, sheet)
    assert added["photo_files"].startswith("4 photos (")
    check(added)  # nothing made yet: any input may change
    camera.write_text("{}")
    check(added)  # the camera is made from the sheet alone: the object's photos may change
    with pytest.raises(NerfkitError, match="calib_tag_size: 0.06 then, 0.07 now"):
        check(inputs(photos, sheet, tag_size=0.07))  # the sheet's tags measured again: the camera would not hold
    made[0].write_text("npz")
    with pytest.raises(NerfkitError, match="photo_files: 3 photos .* then, 4 photos .* now"):
        check(added)  # the dataset would not hold the photo added
    (photos / "IMG_3.JPG").unlink()
    (photos / "IMG_2.JPG").write_bytes(b"longer")  # a photo replaced by another of the same name
    with pytest.raises(NerfkitError, match="photo_files"):
        check(inputs(photos, sheet))
    (photos / "IMG_2.JPG").write_bytes(b"x" * 3)
    check(inputs(photos, sheet))  # as it was: kept
    older = {k: v for k, v in first.items() if k not in ("photo_files", "calib_files", "calib_tag_size", "camera_file")}
    (out / "capture.json").write_text(json.dumps({"inputs": older}))
    check(added)  # what an older nerfkit did not record is not taken as changed,
    with pytest.raises(NerfkitError, match="calib_tag_size: 0.06 then, 0.07 now"):
        check(inputs(photos, sheet, tag_size=0.07))  # but the sheet's tag size is worked out from what it did
    for broken in ("{", "[]", '{"inputs": {}}'):  # a record that is no record keeps nothing
        (out / "capture.json").write_text(broken)
        with pytest.raises(NerfkitError, match="no `nerfkit capture` recorded"):
            check(first)
    # a camera file given with --camera, calibrated again in place: the dataset posed with it would not hold
    given = tmp_path / "phone.json"
    given.write_text('{"K": 1}')
    mine = inputs(photos, None, camera=str(given))
    (out / "capture.json").write_text(json.dumps({"inputs": mine}))
    check(mine)
    given.write_text('{"K": 2}')
    with pytest.raises(NerfkitError, match="camera_file"):
        check(inputs(photos, None, camera=str(given)))


def test_a_capture_replaces_nothing_in_out_that_no_capture_recorded_and_keeps_nothing_of_an_edited_clip(tmp_path):
    import argparse

    from nerfkit.commands.capture import _inputs, _same_inputs
    from nerfkit.errors import NerfkitError

    out, clip = tmp_path / "out", tmp_path / "clip.mp4"
    out.mkdir()
    clip.write_bytes(b"a clip" * 100)
    ours = [out / "dataset", out / "capture.json", out / "frames", out / "splat.ply"]
    made = [out / "dataset" / "dataset.npz"]
    options = {"calib": None, "camera": None, "tag_size": None, "sheet_tag_size": None, "dict": None}
    now = _inputs(argparse.Namespace(photos=str(clip), clip_frames=40, method="auto", max_side=None, **options))
    _same_inputs(out, now, None, made, ours)  # an empty --out
    (out / "splat.ply").write_text("the user's own splat")
    with pytest.raises(NerfkitError, match="holds splat.ply that no `nerfkit capture` recorded"):
        _same_inputs(out, now, None, made, ours)
    (out / "splat.ply").unlink()
    (out / "frames").mkdir()  # frames chosen by `nerfkit frames` before
    with pytest.raises(NerfkitError, match="holds frames that no"):
        _same_inputs(out, now, None, made, ours)
    (out / "frames").rmdir()
    for other in ("dataset.npz", "poses.json"):  # what `nerfkit poses --out` wrote there
        (out / other).write_text("poses' own")
    with pytest.raises(NerfkitError, match=r"not a capture's \(dataset.npz, poses.json\).*--force"):
        _same_inputs(out, now, None, made, ours)
    for other in ("dataset.npz", "poses.json"):
        (out / other).unlink()
    (out / "capture.json").write_text(json.dumps({"inputs": now}))
    (out / "dataset").mkdir()
    made[0].write_text("npz")
    _same_inputs(out, now, None, made, ours)  # recorded, the same clip: kept
    clip.write_bytes(b"b clip" * 100)  # edited in place, its size kept (a rotation fixed in its header)
    edited = _inputs(argparse.Namespace(photos=str(clip), clip_frames=40, method="auto", max_side=None, **options))
    assert edited["photo_files"] == now["photo_files"]  # (its name and size)
    with pytest.raises(NerfkitError, match="clip_content: 600 bytes, sha1 .* then, 600 bytes, sha1 .* now"):
        _same_inputs(out, edited, None, made, ours)


def test_a_run_cut_short_before_its_first_checkpoint_starts_again_with_the_budget_asked_for(tmp_path, capsys):
    from argparse import Namespace

    from nerfkit.commands.capture import _larger_budget

    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"train": {"steps": 160, "minutes": 3.0}}))
    asked = Namespace(steps=300, minutes=3.0)
    assert _larger_budget(run, asked, need_checkpoint=False)  # it trains from step 0 anyway: with the new budget
    assert "training goes on to the 300 steps" in capsys.readouterr().out
    assert not _larger_budget(run, asked, need_checkpoint=True)  # a finished run needs its checkpoint
    assert "(and no checkpoint is left to go on from): --force" in capsys.readouterr().out
    assert not _larger_budget(run, Namespace(steps=None, minutes=9.0), need_checkpoint=False)  # the other unit
    assert "its budget is 160 steps, not the 9 minutes" in capsys.readouterr().out


def test_frames_chosen_from_a_clip_are_kept_only_while_the_clip_is_unchanged(tmp_path):
    import os

    from nerfkit.capture.video import REPORT_NAME, clip_stamp
    from nerfkit.commands.stages.capture import _frames_there

    clip, frames = tmp_path / "clip.mp4", tmp_path / "out" / "frames"
    clip.write_bytes(b"a clip" * 100)
    frames.mkdir(parents=True)
    (frames / "frame_0001.jpg").write_bytes(b"jpeg")
    report = {
        "source": str(clip),
        "source_stamp": clip_stamp(clip),
        "target": 10,
        "frames": [{"file": "frame_0001.jpg"}],
    }
    (frames / REPORT_NAME).write_text(json.dumps(report))
    assert _frames_there(frames, str(clip), 10, clip_stamp(clip))
    assert not _frames_there(frames, str(clip), 12, clip_stamp(clip))  # other --clip-frames
    st = clip.stat()
    os.utime(clip, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # touched (copied again): the same clip
    assert _frames_there(frames, str(clip), 10, clip_stamp(clip))
    # another clip copied over it, or this one edited (here of the same size): its frames are chosen again
    clip.write_bytes(b"b clip" * 100)
    assert not _frames_there(frames, str(clip), 10, clip_stamp(clip))
    # a report from before the stamp was recorded: chosen again too
    del report["source_stamp"]
    (frames / REPORT_NAME).write_text(json.dumps(report))
    assert not _frames_there(frames, str(clip), 10, clip_stamp(clip))


def test_force_removes_an_earlier_run_but_never_a_folder_no_run_wrote(tmp_path):
    from nerfkit.commands.stages.capture import _replace_run
    from nerfkit.errors import NerfkitError

    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text("{}")  # the user's, not a run's settings
    (run / "thesis.txt").write_text("the user's")
    with pytest.raises(NerfkitError, match="holds files that are not a nerfkit run"):
        _replace_run(run)
    assert (run / "thesis.txt").exists()
    (run / "config.json").write_text(json.dumps({"train": {"steps": 5, "minutes": 0.0}}))
    _replace_run(run)
    assert not run.exists()
