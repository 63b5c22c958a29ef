"""Never touch what is not ours (issue 12): paths stay inside the folders nerfkit is given,
inputs are never written and outputs replaced only with --force, one process per run,
SIGTERM saves like Ctrl-C, numeric flags are checked when parsed, outputs follow the umask,
and a run keeps one compact final model.

Every crafted file is made here, in tmp_path; nothing outside it is read or written.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from conftest import tiny_vanilla, tiny_vanilla_configs
from nerfkit.cli import main
from nerfkit.errors import NerfkitError

TINY = tiny_vanilla(batch_rays=64, lr="3e-3", seed=3)


def one_line(capsys, *fragments) -> str:
    """The one error line a command printed (exit code checked by the caller); progress and
    log lines of training before the error are not counted."""
    text = capsys.readouterr().err
    err = [ln.rsplit("\r", 1)[-1] for ln in text.splitlines() if "error:" in ln]
    assert len(err) == 1 and "Traceback" not in text, text
    for f in fragments:
        assert f in err[0], (f, err[0])
    return err[0]


def files_under(folder: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def sphere_arrays(n_train=3, size=8, seed=0) -> dict:
    from nerfkit.data.synthetic import sphere_scene

    s = sphere_scene(n_train=n_train, n_val=1, size=size, seed=seed)
    return {
        "images_train": s.train.images,
        "c2ws_train": s.train.c2w,
        "images_val": s.val.images,
        "c2ws_val": s.val.c2w,
        "focal": np.float32(s.train.K[0, 0, 0]),
    }


def save_png(path: Path, mode="RGB", size=(8, 8), color=(10, 20, 30, 128)) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.new(mode, size, color[: len(mode)]).save(path)
    return path


def blender_folder(folder: Path, file_paths: list[str], split="train", size=8) -> Path:
    """A Blender-style folder whose frames point at ``file_paths`` (images made for the relative ones)."""
    from nerfkit.cameras import opencv_to_opengl
    from nerfkit.data.synthetic import sphere_cameras

    c2w = sphere_cameras(len(file_paths), seed=1).astype(np.float64)
    for fp in file_paths:
        if not Path(fp).is_absolute() and ".." not in fp:
            save_png(folder / (fp + ".png"), "RGBA", (size, size))
    frames = [{"file_path": fp, "transform_matrix": opencv_to_opengl(m).tolist()} for fp, m in zip(file_paths, c2w)]
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": 0.69, "frames": frames}))
    return folder


# ============================================================================= paths: the one function


def test_path_kind_names_what_is_there_and_refuses_unusable_paths(tmp_path):
    from nerfkit.io.paths import path_kind

    save_png(tmp_path / "a.png")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    paths = (tmp_path / "a.png", tmp_path, tmp_path / "none", "/dev/null", "a\x00b", tmp_path / "loop" / "a")
    assert [path_kind(p) for p in paths] == ["file", "dir", None, "other", None, None]
    with pytest.raises(NerfkitError, match="not a usable path"):
        path_kind("x" * 5000)  # a name too long for the file system


def test_resolve_inside_refuses_what_leaves_the_root(tmp_path):
    from nerfkit.io.paths import resolve_inside, safe_output_name

    root = tmp_path / "ds"
    save_png(root / "a.png")
    (tmp_path / "outside.png").write_bytes(b"x")
    (root / "link.png").symlink_to(tmp_path / "outside.png")
    assert resolve_inside(root, "a.png") == (root / "a.png").resolve()
    assert resolve_inside(root, "./sub/../a.png") == (root / "a.png").resolve()
    for name in ("../outside.png", str(tmp_path / "outside.png"), "link.png", "/etc/hostname"):
        with pytest.raises(NerfkitError, match="outside the dataset folder.*--allow-outside-paths"):
            resolve_inside(root, name)
        target = name if Path(name).is_absolute() or name == "link.png" else root / name
        assert resolve_inside(root, name, allow_outside=True) == (root / target).resolve()  # the user's opt-in
    assert [safe_output_name(n) for n in ("../../x.png", "/abs/keep.png", "a\\b.png", "..", "", "c\nd.png")] == [
        "x.png",
        "keep.png",
        "b.png",
        "view",
        "view",
        "c_d.png",
    ]


# ============================================================================= paths: readers


OUTSIDE_COLOUR = (200, 100, 50)


def _outside_image(tmp_path: Path) -> Path:
    return save_png(tmp_path / "elsewhere" / "outside.png", color=(*OUTSIDE_COLOUR, 255))


def _transforms_reading(tmp_path: Path, file_path: str) -> Path:
    from nerfkit.data.nerfstudio import write_transforms_json
    from nerfkit.data.synthetic import sphere_scene

    folder = tmp_path / "ns"
    write_transforms_json(sphere_scene(n_train=3, n_val=1, size=8), folder)
    data = json.loads((folder / "transforms.json").read_text())
    data["frames"][0]["file_path"] = file_path
    (folder / "transforms.json").write_text(json.dumps(data))
    return folder


def _colmap_reading(tmp_path: Path, name: str) -> Path:
    pytest.importorskip("pycolmap")
    m = tmp_path / "proj" / "sparse" / "0"
    m.mkdir(parents=True)
    (m / "cameras.txt").write_text("1 PINHOLE 8 8 10 10 4 4\n")
    names = [name, "1.png", "2.png"]
    (m / "images.txt").write_text("".join(f"{i + 1} 1 0 0 0 {0.1 * i} 0 4 1 {n}\n\n" for i, n in enumerate(names)))
    pts = np.random.default_rng(0).normal(size=(30, 3)) * 0.3
    (m / "points3D.txt").write_text("".join(f"{j + 1} {x} {y} {z} 1 2 3 0.5\n" for j, (x, y, z) in enumerate(pts)))
    for n in names[1:]:
        save_png(tmp_path / "proj" / "images" / n)
    return tmp_path / "proj"


def _symlink_reading(tmp_path: Path, target: str) -> Path:
    folder = blender_folder(tmp_path / "lego", ["./train/r_0", "./train/r_1", "./train/r_2"])
    (folder / "train" / "r_0.png").unlink()
    (folder / "train" / "r_0.png").symlink_to(target)
    return folder


@pytest.mark.parametrize(
    "make",
    [
        lambda t, o: blender_folder(t / "lego", [str(o.with_suffix("")), "./train/r_1", "./train/r_2"]),  # absolute
        lambda t, o: blender_folder(t / "lego", ["../elsewhere/outside", "./train/r_1", "./train/r_2"]),
        lambda t, o: _symlink_reading(t, str(o)),
        lambda t, o: _transforms_reading(t, "../elsewhere/outside.png"),
        lambda t, o: _transforms_reading(t, str(o)),
        lambda t, o: _colmap_reading(t, "../../elsewhere/outside.png"),
    ],
    ids=["blender absolute", "blender ../", "blender symlink", "transforms ../", "transforms absolute", "colmap ../"],
)
def test_dataset_readers_refuse_images_outside_the_dataset_unless_allowed(tmp_path, capsys, make):
    from nerfkit.data.load import load_scene

    outside = _outside_image(tmp_path)
    dataset = make(tmp_path, outside)
    with pytest.raises(NerfkitError, match="outside the dataset folder"):
        load_scene(dataset)
    assert main(["convert", str(dataset), "--to", str(tmp_path / "o.npz")]) == 2
    one_line(capsys, "outside the dataset folder", "--allow-outside-paths")
    assert not (tmp_path / "o.npz").exists()
    assert main(["convert", str(dataset), "--to", str(tmp_path / "o.npz"), "--allow-outside-paths"]) == 0
    with np.load(tmp_path / "o.npz") as npz:  # the image outside was read, as the user allowed
        views = [im for k in npz.files if k.startswith("images_") for im in npz[k]]
    assert any((np.asarray(im)[..., :3] == OUTSIDE_COLOUR).all() for im in views)


def test_poses_json_entries_must_be_photos_of_its_folder(tmp_path):
    from nerfkit.capture.dataset import read_poses_json

    ds = posed_capture(tmp_path)
    data = json.loads((ds / "poses.json").read_text())
    for bad in ("../ds/poses.json", "/etc/hostname", str(tmp_path / "photos" / ".." / "ds" / "poses.json")):
        data["photos"][0]["file"] = bad
        (ds / "poses.json").write_text(json.dumps(data))
        with pytest.raises(NerfkitError, match="outside the dataset folder"):
            read_poses_json(ds)


# ============================================================================= paths: writers


def test_convert_writes_crafted_npz_names_only_inside_its_output(tmp_path):
    pytest.importorskip("pycolmap")
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    keep = tmp_path / "keep.png"
    keep.write_bytes(b"the user's file")
    np.savez(work / "crafted.npz", **sphere_arrays(), names_train=np.array(["../../outside.png", str(keep), "ok.png"]))
    before = files_under(tmp_path)
    out = work / "out"
    assert main(["convert", str(work / "crafted.npz"), "--to", str(out), "--format", "colmap"]) == 0
    after = files_under(tmp_path)
    assert keep.read_bytes() == b"the user's file"
    new = set(after) - set(before)
    assert new and all(p.is_relative_to(out) for p in new), sorted(new)
    assert {"outside.png", "keep.png", "ok.png"} <= {p.name for p in (out / "images").iterdir()}


def test_convert_writes_crafted_transforms_names_only_inside_its_output(tmp_path):
    pytest.importorskip("pycolmap")
    folder = _transforms_reading(tmp_path, "images/sphere_0_000.png")
    data = json.loads((folder / "transforms.json").read_text())
    data["frames"][0]["name"] = "../../../escaped.png"
    (folder / "transforms.json").write_text(json.dumps(data))
    out = tmp_path / "deep" / "out"
    assert main(["convert", str(folder), "--to", str(out), "--format", "colmap"]) == 0
    escaped = list(tmp_path.rglob("escaped.png"))
    assert escaped and all(p.is_relative_to(out) for p in escaped)
    assert all(p.is_relative_to(out) or p.is_relative_to(folder) for p in files_under(tmp_path))


def test_blender_absolute_file_path_never_overwrites_the_source_image(tmp_path):
    pytest.importorskip("pycolmap")
    folder = tmp_path / "lego"
    sources = [save_png(folder / "train" / f"r_{i}.png", "RGBA") for i in range(3)]
    blender_folder(folder, [str(p.with_suffix("")) for p in sources])  # absolute, but inside the folder
    before = files_under(folder)
    assert main(["convert", str(folder), "--to", str(tmp_path / "out"), "--format", "colmap"]) == 0
    assert files_under(folder) == before
    assert Image.open(sources[0]).mode == "RGBA"
    assert sorted(p.name for p in (tmp_path / "out" / "images").iterdir()) == ["r_0.png", "r_1.png", "r_2.png"]


# ============================================================================= the user's files


def posed_capture(root: Path, n=8, size=32) -> Path:
    """photos/ and ds/poses.json as `nerfkit poses --no-dataset` would leave them."""
    from nerfkit.data.synthetic import sphere_scene

    s = sphere_scene(n_train=n, n_val=1, size=size)
    photos = root / "photos"
    photos.mkdir(parents=True)
    K = s.train.K[0].astype(np.float64)
    K[:2, 2] -= 0.5  # the camera file uses OpenCV's pixel centres
    entries = []
    for i in range(n):
        Image.fromarray(s.train.images[i]).save(photos / f"p{i}.png")
        entries.append({"file": f"p{i}.png", "used": True, "size": [size, size], "c2w": s.train.c2w[i].tolist()})
    ds = root / "ds"
    ds.mkdir()
    (ds / "poses.json").write_text(
        json.dumps(
            {
                "format": "nerfkit-poses",
                "version": 1,
                "photos_dir": str(photos),
                "tag_size": 1.0,
                "photos": entries,
                "camera": {"K": K.tolist(), "dist": [0, 0, 0, 0, 0], "width": size, "height": size, "source": "test"},
            }
        )
    )
    return ds


def test_dataset_replaces_an_existing_dataset_only_with_force(tmp_path, capsys):
    ds = posed_capture(tmp_path)
    argv = ["dataset", str(ds), "--max-side", "16", "--val-every", "4", "--test-every", "0", "--jobs", "1"]
    assert main(argv) == 0
    before = files_under(ds)
    capsys.readouterr()
    assert main([*argv, "--max-side", "8"]) == 2
    one_line(capsys, "already exists", "--force")
    assert files_under(ds) == before
    (ds / "images" / "IMG_dropped_since.jpg").write_bytes(next((ds / "images").iterdir()).read_bytes())
    assert main([*argv, "--max-side", "8", "--force"]) == 2  # a file no dataset wrote: the user's, kept
    one_line(capsys, "holds files that no earlier output of nerfkit's wrote there (IMG_dropped_since.jpg)")
    assert (ds / "images" / "IMG_dropped_since.jpg").exists() and np.load(ds / "dataset.npz")["images_train"].shape[
        1:3
    ] == (16, 16)
    # as the dataset before wrote it: a photo since dropped from the photo folder
    record = json.loads((ds / "transforms.json").read_text())
    record["frames"].append({**record["frames"][0], "file_path": "images/IMG_dropped_since.jpg"})
    (ds / "transforms.json").write_text(json.dumps(record))
    assert main([*argv, "--max-side", "8", "--force"]) == 0
    assert np.load(ds / "dataset.npz")["images_train"].shape[1:3] == (8, 8)
    # the images folder is the new dataset's alone: a photo of the one before does not stay
    listed = {Path(f["file_path"]).name for f in json.loads((ds / "transforms.json").read_text())["frames"]}
    assert {p.name for p in (ds / "images").iterdir()} == listed


def test_dataset_and_poses_never_write_into_the_photo_folder(tmp_path, capsys):
    ds = posed_capture(tmp_path)
    photos = tmp_path / "photos"
    project = tmp_path / "project"
    project.mkdir()
    photos.rename(project / "images")  # the photos are the project's images/ folder
    data = json.loads((ds / "poses.json").read_text())
    (ds / "poses.json").write_text(json.dumps({**data, "photos_dir": str(project / "images")}))
    before = files_under(project)
    assert main(["dataset", str(ds), "--out", str(project), "--jobs", "1"]) == 2
    one_line(capsys, "holds the input")
    assert main(["dataset", str(ds), "--out", str(project / "images"), "--jobs", "1"]) == 2  # among the photos
    one_line(capsys, "is inside the input")
    assert (
        main(
            [
                "poses",
                str(project / "images"),
                "--out",
                str(project),
                "--tag-size",
                "0.05",
                "--focal-px",
                "40",
                "--jobs",
                "1",
                "--force",
            ]
        )
        == 2
    )
    one_line(capsys, "is an input", "never writes its inputs")
    assert files_under(project) == before


def test_outputs_never_land_in_a_dataset_folder_or_on_images_it_names_outside_it(tmp_path, capsys):
    import shutil

    from nerfkit.data.npz import save_npz
    from nerfkit.data.synthetic import sphere_scene

    ds = tmp_path / "ds"  # as poses writes it: the npz beside its images
    (ds / "images").mkdir(parents=True)
    save_npz(sphere_scene(n_train=3, n_val=1, size=8), ds / "dataset.npz")
    assert main(["view", str(ds / "dataset.npz"), "--png", str(ds / "images" / "view.png")]) == 2
    one_line(capsys, "is inside the input")
    # a transforms.json whose images live outside its folder (read with --allow-outside-paths)
    folder = _transforms_reading(tmp_path, "../shared/images/photo.png")
    (tmp_path / "shared" / "images").mkdir(parents=True)
    shutil.copy(folder / "images" / "sphere_0_000.png", tmp_path / "shared" / "images" / "photo.png")
    before = files_under(tmp_path / "shared")
    outside = ["--allow-outside-paths", "--force"]
    assert main(["convert", str(folder), "--to", str(tmp_path / "shared"), *outside]) == 2
    one_line(capsys, "holds the input")
    assert main(["view", str(folder), "--png", str(tmp_path / "shared" / "images" / "photo.png"), *outside]) == 2
    one_line(capsys, "is an input")
    assert files_under(tmp_path / "shared") == before


def test_convert_to_its_own_source_is_refused_even_with_force(tmp_path, capsys):
    folder = _transforms_reading(tmp_path, "images/sphere_0_000.png")
    before = files_under(folder)
    for src in (folder / "transforms.json", folder):
        assert main(["convert", str(src), "--to", str(folder), "--force"]) == 2
        one_line(capsys, "input")
        assert main(["convert", str(src), "--to", str(folder / "sub"), "--force"]) == 2
        one_line(capsys, "inside the input")
    assert files_under(folder) == before


def _sphere_npz(path: Path, n_train: int) -> Path:
    from nerfkit.data.npz import save_npz
    from nerfkit.data.synthetic import sphere_scene

    save_npz(sphere_scene(n_train=n_train, n_val=1, size=8), path)
    return path


@pytest.mark.parametrize("fmt", ["transforms", "colmap"])
def test_a_conversion_replaced_with_force_keeps_no_file_of_the_one_before(tmp_path, fmt):
    """A smaller scene converted over a larger one leaves none of the larger one's images,
    nor its text model beside the new binary one; the user's other files stay."""
    pytest.importorskip("nerfkit.data.nerfstudio")
    from nerfkit.data.load import load_scene

    out = tmp_path / "out"
    assert (
        main(
            [
                "convert",
                str(_sphere_npz(tmp_path / "big.npz", 5)),
                "--to",
                str(out),
                "--format",
                fmt,
                *(["--text"] if fmt == "colmap" else []),
            ]
        )
        == 0
    )
    assert len(list((out / "images").iterdir())) == 6
    (out / "notes.txt").write_text("mine")
    assert (
        main(["convert", str(_sphere_npz(tmp_path / "small.npz", 2)), "--to", str(out), "--format", fmt, "--force"])
        == 0
    )
    assert len(list((out / "images").iterdir())) == 3
    if fmt == "colmap":
        assert {p.suffix for p in (out / "sparse" / "0").iterdir()} == {".bin"}  # no .txt left
    assert sum(len(v) for v in load_scene(out).splits.values() if v.images is not None) == 3
    assert (out / "notes.txt").read_text() == "mine"
    assert not list(out.rglob("*.replaced*"))


def test_a_failed_replacement_puts_the_earlier_conversion_back(tmp_path, monkeypatch, capsys):
    pytest.importorskip("nerfkit.data.nerfstudio")
    import nerfkit.data.nerfstudio as ns
    from nerfkit.errors import fail

    out = tmp_path / "out"
    assert main(["convert", str(_sphere_npz(tmp_path / "big.npz", 5)), "--to", str(out)]) == 0
    before = files_under(out)
    calls = []

    def disk_full_on_the_third(path, image, quality):
        calls.append(path)
        if len(calls) == 3:
            raise fail(path, "could not be written: the disk is full")
        save(path, image, quality)

    save = ns._save_image
    monkeypatch.setattr(ns, "_save_image", disk_full_on_the_third)
    assert main(["convert", str(_sphere_npz(tmp_path / "small.npz", 2)), "--to", str(out), "--force"]) == 2
    one_line(capsys, "the disk is full")
    assert len(calls) == 3
    assert files_under(out) == before
    fresh = tmp_path / "fresh"  # a first conversion that fails leaves no half-written images
    calls.clear()
    assert main(["convert", str(tmp_path / "small.npz"), "--to", str(fresh)]) == 2
    assert not (fresh / "images").exists()


def test_replacing_a_symlinked_output_folder_never_touches_its_target(tmp_path):
    from nerfkit.io.atomic import replacing_folder

    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "photo.png").write_bytes(b"theirs")
    out = tmp_path / "out"
    out.mkdir()
    (out / "images").symlink_to(theirs)
    with replacing_folder(out / "images") as images:
        images.mkdir()
        (images / "new.png").write_bytes(b"ours")
    assert not (out / "images").is_symlink()
    assert files_under(out) == {out / "images" / "new.png": b"ours"}
    assert files_under(theirs) == {theirs / "photo.png": b"theirs"}


def test_train_refuses_a_folder_of_other_files(tmp_path, capsys, sphere_npz):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "metrics.csv").write_text("my own numbers\n")
    assert main(["train", "--data", str(sphere_npz), "--out", str(out), "--steps", "2", *TINY]) == 2
    one_line(capsys, "holds files that are not a nerfkit run")
    assert (out / "metrics.csv").read_text() == "my own numbers\n" and sorted(os.listdir(out)) == ["metrics.csv"]


# ============================================================================= runs


@pytest.fixture(scope="module")
def trained(tmp_path_factory, sphere):
    """A tiny run trained through the CLI on data.npz in its own folder (relative --data)."""
    from nerfkit.data.npz import save_npz

    root = tmp_path_factory.mktemp("safety")
    (root / "a").mkdir()
    save_npz(sphere, root / "a" / "data.npz")
    cwd = os.getcwd()
    os.chdir(root / "a")
    try:
        assert main(["train", "--data", "data.npz", "--out", str(root / "run"), "--steps", "6", *TINY]) == 0
    finally:
        os.chdir(cwd)
    return root


def copy_run(trained: Path, tmp_path: Path) -> Path:
    return shutil.copytree(trained / "run", tmp_path / "run")


def placed(argv: list[str], trained: Path, run: Path) -> list[str]:
    """``argv`` with RUN as ``run`` and D as the trained run's dataset."""
    return [str(run) if a == "RUN" else str(trained / "a" / "data.npz") if a == "D" else a for a in argv]


def test_the_run_records_its_dataset_absolutely_and_eval_uses_it_from_anywhere(trained, tmp_path, monkeypatch, capsys):
    from nerfkit.data.npz import save_npz
    from nerfkit.data.synthetic import sphere_scene

    run = copy_run(trained, tmp_path)
    assert json.loads((run / "config.json").read_text())["train"]["data"] == str(trained / "a" / "data.npz")
    elsewhere = tmp_path / "b"
    elsewhere.mkdir()
    save_npz(sphere_scene(n_train=4, n_val=2, size=16, seed=9), elsewhere / "data.npz")  # another data.npz
    monkeypatch.chdir(elsewhere)
    capsys.readouterr()
    assert main(["eval", str(run), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["data"] == str(trained / "a" / "data.npz")


def run_on_a_copy_of_its_data(trained, tmp_path):
    """(a copy of the trained run, the copy of its dataset it now records)."""
    data = tmp_path / "a" / "data.npz"
    shutil.copytree(trained / "a", data.parent)
    run = copy_run(trained, tmp_path)
    cfg = json.loads((run / "config.json").read_text())
    cfg["train"]["data"] = str(data)
    (run / "config.json").write_text(json.dumps(cfg))
    return run, data


def test_a_dataset_changed_in_place_is_refused_on_resume_and_eval(trained, tmp_path, capsys):
    from nerfkit.data.npz import load_npz, save_npz

    run, data = run_on_a_copy_of_its_data(trained, tmp_path)
    scene = load_npz(data)
    scene.train.c2w[0, :3, 3] += 0.01  # one camera moved a centimetre: a different dataset
    save_npz(scene, data)
    assert main(["eval", str(run)]) == 2
    one_line(capsys, "is not the dataset run", "poses differ")
    assert main(["train", "--resume", str(run), "--steps", "8"]) == 2
    one_line(capsys, "is not the dataset run")
    assert not (run / "eval_val.json").exists()


def test_changed_intrinsics_or_held_out_images_are_refused_but_an_older_fingerprint_is_not(trained, tmp_path, capsys):
    from nerfkit.data.npz import load_npz, save_npz

    run, data = run_on_a_copy_of_its_data(trained, tmp_path)
    original = load_npz(data)
    scene = load_npz(data)
    for views in scene.splits.values():
        views.K[:, :2, :2] *= 1.2  # focal lengths x1.2 (the npz holds one K), poses and images as they were
    save_npz(scene, data)
    assert main(["train", "--resume", str(run), "--steps", "8"]) == 2
    one_line(capsys, "is not the dataset run", "intrinsics differ")
    scene = load_npz(data)
    scene.val.images = 255 - scene.val.images
    for name, views in scene.splits.items():
        views.K = original.splits[name].K
    save_npz(scene, data)
    assert main(["eval", str(run)]) == 2
    one_line(capsys, "is not the dataset run", "held_out_images differ")
    # a run from before these parts were recorded is checked on what it recorded
    cfg = json.loads((run / "config.json").read_text())
    for key in ("intrinsics_sha256", "held_out_images_sha256"):
        del cfg["scene"]["fingerprint"][key]
    (run / "config.json").write_text(json.dumps(cfg))
    save_npz(original, data)
    assert main(["train", "--resume", str(run), "--steps", "7"]) == 0


def test_a_moved_dataset_is_named_with_its_run_and_the_flag_to_give(trained, tmp_path, capsys):
    run = copy_run(trained, tmp_path)
    cfg = json.loads((run / "config.json").read_text())
    cfg["train"]["data"] = str(tmp_path / "gone" / "data.npz")
    (run / "config.json").write_text(json.dumps(cfg))
    for argv in (["train", "--resume", str(run), "--steps", "8"], ["eval", str(run)], ["render", str(run)]):
        assert main(argv) == 2
        one_line(
            capsys, f"{run}: its dataset {tmp_path / 'gone' / 'data.npz'} is not there any more", "--data NEW_PATH"
        )


def test_resume_with_data_of_a_moved_dataset_records_where_it_is_now(trained, tmp_path, capsys):
    run = copy_run(trained, tmp_path)
    moved = tmp_path / "moved" / "data.npz"
    moved.parent.mkdir()
    shutil.copy(trained / "a" / "data.npz", moved)
    cfg = json.loads((run / "config.json").read_text())
    cfg["train"]["data"] = str(tmp_path / "gone" / "data.npz")
    (run / "config.json").write_text(json.dumps(cfg))
    assert main(["train", "--resume", str(run), "--steps", "5", "--data", str(moved)]) == 0  # past it: trains nothing
    after = json.loads((run / "config.json").read_text())
    assert after["train"]["data"] == str(moved.resolve())
    assert {k: v for k, v in after["train"].items() if k != "data"} == {
        k: v for k, v in cfg["train"].items() if k != "data"
    }  # the data path alone
    assert main(["eval", str(run)]) == 0  # finds it without --data
    assert main(["train", "--resume", str(run), "--steps", "7"]) == 0
    # a resume refused for its --steps records no new path (a run stopped before its end: no model.pt)
    (run / "model.pt").rename(tmp_path / "model.pt")
    assert main(["train", "--resume", str(run), "--steps", "3", "--data", str(trained / "a" / "data.npz")]) == 2
    assert json.loads((run / "config.json").read_text())["train"]["data"] == str(moved.resolve())
    (tmp_path / "model.pt").rename(run / "model.pt")
    # a dataset moved into the run's own folder is refused, as train refuses a run among its data
    shutil.copy(moved, run / "data.npz")
    capsys.readouterr()
    assert main(["train", "--resume", str(run), "--steps", "8", "--data", str(run / "data.npz")]) == 2
    assert "--data: " in capsys.readouterr().err.splitlines()[-1]  # before anything is trained
    assert json.loads((run / "config.json").read_text())["train"]["data"] == str(moved.resolve())


def test_a_timed_run_past_its_budget_says_how_long_it_trained(trained, tmp_path, capsys):
    run = copy_run(trained, tmp_path)
    metrics = json.loads((run / "metrics.json").read_text())
    minutes = metrics["train_seconds"] / 60
    assert main(["train", "--resume", str(run), "--steps", "0", "--minutes", f"{minutes / 2:.3g}"]) == 0
    said = re.search(r"already past --minutes \S+ \((\S+) trained\)", capsys.readouterr().err)
    assert said and float(said.group(1)) == pytest.approx(minutes, rel=0.01)


def test_resume_applies_what_it_can_and_refuses_the_rest(trained, tmp_path, capsys):
    run = copy_run(trained, tmp_path)
    for flags in (["--lr", "1"], ["--model", "fast"], ["--width", "64"], ["--out", str(tmp_path / "x")]):
        assert main(["train", "--resume", str(run), *flags]) == 2
        one_line(capsys, f"{flags[0]} cannot change when a run continues")
    assert main(["train", "--resume", str(run), "--steps", "8", "--eval-views", "2"]) == 0
    err = capsys.readouterr().err
    assert "resuming with --steps 8 (was 6)" in err and "resuming with --eval-views 2 (was 1)" in err
    cfg = json.loads((run / "config.json").read_text())["train"]
    assert json.loads((run / "metrics.json").read_text())["step"] == 8 and cfg["steps"] == 8  # what it went on with
    before = {p: p.read_bytes() for p in (run / "config.json", run / "metrics.json", run / "model.pt")}
    assert main(["train", "--resume", str(run), "--steps", "5"]) == 0  # past it already: says so, changes nothing
    err = capsys.readouterr().err
    assert "at step 8 the run is already past --steps 5: nothing more to train" in err
    assert "--steps 0 --minutes M to go on by time" in err  # (a larger --minutes alone would not)
    assert all(p.read_bytes() == b for p, b in before.items())


def test_a_trained_run_without_its_checkpoints_is_not_trained_over(trained, tmp_path, capsys):
    run = copy_run(trained, tmp_path)
    shutil.rmtree(run / "checkpoints")
    before = (run / "model.pt").read_bytes()
    assert main(["train", "--resume", str(run), "--steps", "8"]) == 2
    one_line(capsys, "holds a trained model (model.pt) but no checkpoint to continue it from", "another --out")
    assert (run / "model.pt").read_bytes() == before


def test_one_process_per_run_folder(trained, tmp_path, capsys, sphere_npz):
    from nerfkit.io.lock import folder_lock

    run = copy_run(trained, tmp_path)
    new = tmp_path / "new"
    with folder_lock(run), folder_lock(new):  # as a training process holds them
        assert main(["train", "--resume", str(run), "--steps", "8"]) == 2
        one_line(capsys, "in use by another nerfkit process", f"pid {os.getpid()}")
        assert main(["train", "--data", str(sphere_npz), "--out", str(new), "--steps", "2", *TINY]) == 2
        one_line(capsys, f"pid {os.getpid()}")
        assert (run / ".nerfkit.lock").read_text().strip() == str(os.getpid())
    assert main(["train", "--resume", str(run), "--steps", "7"]) == 0  # released


def test_a_lock_file_that_is_a_link_is_refused_and_what_it_points_to_kept(tmp_path):
    from nerfkit.errors import NerfkitError
    from nerfkit.io.lock import LOCK_FILE, folder_lock

    mine = tmp_path / "notes.txt"
    mine.write_text("the user's notes")
    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK_FILE).symlink_to(mine)
    with pytest.raises(NerfkitError, match=r"\.nerfkit\.lock: is a link or cannot be opened"), folder_lock(out):
        pass
    assert mine.read_text() == "the user's notes"  # not emptied
    (out / LOCK_FILE).unlink()
    os.mkfifo(out / LOCK_FILE)
    with pytest.raises(NerfkitError, match="is not a regular file"), folder_lock(out):
        pass


def test_an_empty_data_or_background_is_refused_not_taken_for_the_default(trained, capsys):
    run = str(trained / "run")
    for argv in (["eval", run, "--data", ""], ["render", run, "--data", " "], ["render", run, "--background", ""]):
        assert main(argv) == 2
        one_line(capsys, ": is empty", "leave --")


def test_no_write_goes_through_a_linked_subfolder(trained, tmp_path, capsys, sphere_npz):
    run = copy_run(trained, tmp_path)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "loss.png").write_bytes(b"the user's")
    shutil.rmtree(run / "plots", ignore_errors=True)
    (run / "plots").symlink_to(mine)
    assert main(["train", "--resume", str(run), "--steps", "8"]) == 2  # its plots would land in mine/
    one_line(capsys, "plots: is a link", "Remove the link")
    (run / "plots").unlink()
    (run / "videos").symlink_to(mine)
    assert main(["render", str(run), "--frames", "2"]) == 2
    one_line(capsys, "videos: is a link")
    out = tmp_path / "conv"
    out.mkdir()
    (out / "sparse").symlink_to(mine)
    if importlib.util.find_spec("pycolmap") is not None:
        assert main(["convert", str(sphere_npz), "--to", str(out), "--format", "colmap", "--force"]) == 2
        one_line(capsys, "sparse: is a link")
    from nerfkit.images import write_image

    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "L3").symlink_to(mine)
    image = tmp_path / "img.png"
    write_image(image, np.zeros((8, 8, 3), np.uint8))
    assert main(["fit-image", str(image), "--out", str(sweep), "--sweep", "L=3,4", "--steps", "2"]) == 2
    one_line(capsys, "L3: is a link")
    assert files_under(mine) == {mine / "loss.png": b"the user's"}


def test_stale_temporaries_of_a_killed_run_are_removed_on_the_next_start(trained, tmp_path):
    run = copy_run(trained, tmp_path)
    stale = [
        run / "checkpoints" / ".step_00000009.pt.tmp.k3j2x_0q.pt",
        run / ".metrics.json.tmp.abcd1234.json",
        run / "plots" / ".psnr.png.tmp.zz9zz9zz.png",
    ]
    for p in stale:
        p.write_bytes(b"half written")
    mine = run / ".notes.tmp.txt"  # a user's file whose name only looks like one
    mine.write_text("mine")
    assert main(["train", "--resume", str(run), "--steps", "7"]) == 0
    assert not any(p.exists() for p in stale)
    assert list(run.rglob("*.tmp.*")) == [mine] and mine.read_text() == "mine"


def test_a_folder_holding_a_users_file_named_like_a_temporary_is_not_empty(tmp_path, capsys, sphere_npz):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / ".notes.tmp.txt").write_text("mine")
    assert main(["train", "--data", str(sphere_npz), "--out", str(tmp_path / "out"), "--steps", "2", *TINY]) == 2
    one_line(capsys, "holds files that are not a nerfkit run")
    assert (tmp_path / "out" / ".notes.tmp.txt").read_text() == "mine"


def test_a_users_lock_file_in_an_empty_out_is_theirs_refused_and_never_truncated(tmp_path, capsys, sphere_npz):
    # the run lock was RUN/.lock: a user's .lock there was taken for it, and truncated
    out = tmp_path / "out"
    out.mkdir()
    (out / ".lock").write_text("my notes")
    assert main(["train", "--data", str(sphere_npz), "--out", str(out), "--steps", "2", *TINY]) == 2
    one_line(capsys, f"{out}: holds files that are not a nerfkit run")
    assert sorted(p.name for p in out.iterdir()) == [".lock"] and (out / ".lock").read_text() == "my notes"


@pytest.mark.slow
def test_a_run_of_an_earlier_version_with_its_dot_lock_still_resumes_evaluates_and_renders(trained, tmp_path, capsys):
    run = copy_run(trained, tmp_path)
    for lock in run.glob(".*lock"):
        lock.unlink()
    (run / ".lock").write_text("4242\n")  # as an earlier version left it (never read again)
    assert main(["train", "--resume", str(run), "--steps", "7"]) == 0
    assert main(["eval", str(run)]) == 0
    assert main(["render", str(run), "--path", "orbit", "--frames", "2", "--out", str(tmp_path / "v")]) == 0
    assert (run / ".lock").read_text() == "4242\n"
    assert (run / ".nerfkit.lock").read_text() == ""  # the lock resume held, released
    assert main(["train", "--data", str(trained / "a" / "data.npz"), "--out", str(run), "--steps", "2", *TINY]) == 2
    one_line(capsys, "already holds a run")


@pytest.mark.slow
def test_sigterm_saves_like_ctrl_c_and_the_run_is_locked_meanwhile(tmp_path, sphere_npz, capsys):
    run = tmp_path / "run"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "nerfkit.cli",
            "train",
            "--data",
            str(sphere_npz),
            "--out",
            str(run),
            "--steps",
            "100000",
            "--checkpoint-seconds",
            "100000",
            *TINY,
            "--eval-every",
            "20",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        for _ in range(2400):  # up to 2 minutes on a loaded machine
            if (run / "progress").exists() and len(list((run / "progress").glob("*.png"))) >= 2:
                break
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.05)
        assert main(["train", "--resume", str(run), "--steps", "1"]) == 2  # (--steps: never trains for long)
        one_line(capsys, "in use by another nerfkit process", f"pid {proc.pid}")
        assert main(["train", "--data", str(sphere_npz), "--out", str(run), "--steps", "2", *TINY]) == 2
        one_line(capsys, "already holds a run")
        assert not list((run / "checkpoints").glob("*.pt"))  # no periodic checkpoint: all is in memory
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "--resume" in err and "Traceback" not in err
    ckpt = torch.load(sorted((run / "checkpoints").glob("*.pt"))[-1], weights_only=True)
    assert ckpt["step"] >= 20 and (run / "model.pt").exists()
    assert (run / ".nerfkit.lock").read_text() == ""  # released


# ============================================================================= arguments and messages


TRAIN = ["train", "--data", "D", "--out", "O", "--steps", "1"]  # --steps: ends at once where nan is accepted


@pytest.mark.parametrize(
    "argv, fragment",
    [
        ([*TRAIN, "--minutes", "nan"], "--minutes: 'nan' is not a finite number"),
        ([*TRAIN, "--minutes", "-1"], "--minutes: -1 is below the minimum 0"),
        ([*TRAIN, "--lr", "nan"], "--lr: 'nan' is not a finite number"),
        ([*TRAIN, "--lr", "inf"], "--lr: 'inf' is not a finite number"),
        ([*TRAIN, "--batch-rays", "100000000"], "--batch-rays: 100000000 is above"),
        ([*TRAIN, "--checkpoint-seconds", "0"], "--checkpoint-seconds: 0 must be greater"),
        ([*TRAIN, "--step-ratio", "-1"], "--step-ratio: -1 is below the minimum 0.01"),
        ([*TRAIN, "--sh-degree", "4"], "--sh-degree: 4 is above the maximum 3"),  # fast 2, splat 3
        ([*TRAIN, "--model", "vanilla", "--depth", "1"], "--depth: 1 is below the minimum 2"),
        (["calibrate", "D", "--folds", "1"], "--folds: 1 is below the minimum 2"),
        (["dataset", "D", "--jpeg-quality", "101"], "--jpeg-quality: 101 is above the maximum 100"),
        ([*TRAIN, "--seed", "18446744073709551616"], "--seed: 18446744073709551616 is above the maximum 4294967295"),
        ([*TRAIN, "--lr", "1e300"], "--lr: 1e300 is above the maximum 100"),
        (
            ["export", "RUN", "--points", "p.ply", "--stride", "9" * 20],
            "--stride: " + "9" * 20 + " is above the maximum 4096",
        ),
        (["render", "RUN", "--fps", "0"], "--fps: 0 is below the minimum 1"),
        (["render", "RUN", "--fps", "-5"], "--fps: -5 is below the minimum 1"),
        (["render", "RUN", "--chunk", "-1"], "--chunk: -1 is below the minimum 0"),
        (["eval", "RUN", "--chunk", "-1"], "--chunk: -1 is below the minimum 0"),
        (["export", "RUN", "--mesh", "m.ply", "--resolution", "nan"], "--resolution: 'nan' is not a whole number"),
        (["convert", "D", "--to", "o.npz", "--downscale", "0"], "--downscale: 0 is below the minimum 1"),
        (["view", "D", "--port", "70000"], "--port: 70000 is above the maximum 65535"),
        (["view", "D", "--downscale", "1e-300"], "--downscale: 1e-300 is below the minimum 1"),
        (["fit-image", "--lr", "inf"], "--lr: 'inf' is not a finite number"),
    ],
)
def test_numeric_options_are_checked_when_parsed(trained, tmp_path, monkeypatch, capsys, argv, fragment):
    monkeypatch.chdir(tmp_path)
    run = copy_run(trained, tmp_path)
    argv = placed(argv, trained, run)
    before = files_under(tmp_path)
    assert main(argv) == 2
    one_line(capsys, f"nerfkit {argv[0]}: error: argument {fragment}")
    assert files_under(tmp_path) == before  # nothing written: no run folder, no stub orbit.mp4


@pytest.mark.parametrize("value", ["1e-300", "0.5"])
def test_train_refuses_a_downscale_below_1_in_one_short_line(trained, tmp_path, monkeypatch, capsys, value):
    # 1e-300 once asked for images of 2e302 pixels a side, printed in full, with advice about --size
    monkeypatch.chdir(tmp_path)
    assert main(placed([*TRAIN, "--downscale", value], trained, tmp_path)) == 2
    line = one_line(capsys, f"--downscale: {value} is below the minimum 1 (or 0: off)")  # when parsed
    assert len(line) < 120 and "--size" not in line
    assert files_under(tmp_path) == {}  # no run folder


def test_demo_minutes_are_checked_when_parsed():
    from nerfkit.cli import UsageError, build_parser

    for minutes in ("nan", "inf", "0", "-3"):
        with pytest.raises(UsageError, match="--minutes"):
            build_parser("demo").parse_args(["demo", "--minutes", minutes])


def test_divergence_before_any_checkpoint_does_not_advise_resuming(tmp_path, sphere):
    from nerfkit.train.trainer import Trainer

    trainer = Trainer(sphere, *tiny_vanilla_configs(tmp_path / "run", 100, batch_rays=32, eval_every=1000), quiet=True)
    original = trainer.model.render_rays

    def poisoned(rays, background, perturb):
        out = original(rays, background, perturb)
        out.rgb = out.rgb * float("nan")
        return out

    trainer.model.render_rays = poisoned
    with pytest.raises(NerfkitError, match="diverged") as e:
        trainer.run()
    assert "No checkpoint was written yet" in str(e.value) and "--resume" not in str(e.value)


def test_a_stop_signal_during_the_final_save_does_not_cut_it_short(tmp_path, sphere):
    # Ctrl-C pressed twice: the second press used to land after the handlers were restored, in
    # the middle of the save, and the run was left without its model.pt, metrics and plots.
    from nerfkit.train.trainer import Trainer

    trainer = Trainer(sphere, *tiny_vanilla_configs(tmp_path / "run", 3, batch_rays=32, eval_every=1000), quiet=True)
    original = trainer.save

    def save_interrupted():
        for sig in (signal.SIGINT, signal.SIGTERM):
            os.kill(os.getpid(), sig)
        original()

    trainer.save = save_interrupted
    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}  # (nohup ignores SIGINT)
    result = trainer.run()
    assert result.step == 3 and result.interrupted
    for name in ("model.pt", "metrics.json", "metrics.csv", "plots/psnr.png"):
        assert (tmp_path / "run" / name).exists(), name
    assert {sig: signal.getsignal(sig) for sig in before} == before  # restored afterwards


def test_running_out_of_memory_is_one_line_naming_the_option(tmp_path, capsys, sphere_npz, monkeypatch):
    from nerfkit.train import trainer as trainer_mod

    def no_memory(self):
        raise RuntimeError(
            "[enforce fail at alloc_cpu.cpp:127] err == 0. DefaultCPUAllocator: can't allocate "
            "memory: you tried to allocate 100000000000000 bytes. Error code 12"
        )

    monkeypatch.setattr(trainer_mod.Trainer, "train_step", no_memory)
    assert main(["train", "--data", str(sphere_npz), "--out", str(tmp_path / "r"), "--steps", "5", *TINY]) == 2
    one_line(capsys, "out of memory", "Lower --batch-rays")


def huge_png(path: Path, width: int, height: int) -> Path:
    """A PNG whose header declares width x height (its pixel data is a stub)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")

    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 2, 0, 0, 0])
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b"")
    )
    return path


def test_a_400_megapixel_image_is_refused_before_it_is_decoded(tmp_path, capsys):
    png = huge_png(tmp_path / "huge.png", 20000, 20000)
    assert main(["fit-image", str(png), "--out", str(tmp_path / "f"), "--steps", "1", "--quiet"]) == 2
    one_line(capsys, "huge.png", "20000x20000 (400 megapixels)", "Downscale it first")


# ============================================================================= eval on a file of held-out views


def test_eval_on_a_test_only_npz(trained, tmp_path, capsys):
    from nerfkit.data.synthetic import sphere_scene

    s = sphere_scene(n_train=2, n_val=1, size=32, seed=4)
    np.savez(
        tmp_path / "held_out.npz",
        images_test=s.train.images,
        c2ws_test=s.train.c2w,
        focal=np.float32(s.train.K[0, 0, 0]),
    )
    assert (
        main(["eval", str(trained / "run"), "--data", str(tmp_path / "held_out.npz"), "--split", "test", "--json"]) == 0
    )
    result = json.loads(capsys.readouterr().out)
    assert result["split"] == "test" and len(result["per_image"]) == 2
    # a split with no views (a capture of 3 photos has none to validate on) names one that has
    np.savez(
        tmp_path / "no_val.npz",
        images_train=s.train.images,
        c2ws_train=s.train.c2w,
        images_test=s.train.images,
        c2ws_test=s.train.c2w,
        focal=np.float32(s.train.K[0, 0, 0]),
    )
    assert main(["eval", str(trained / "run"), "--data", str(tmp_path / "no_val.npz")]) == 2
    assert "no_val.npz: has no val views. Choose a split that has (--split test)" in capsys.readouterr().err


def test_eval_on_a_blender_folder_with_only_test_views(trained, tmp_path, capsys):
    folder = blender_folder(tmp_path / "held_out", ["./test/r_0", "./test/r_1"], split="test", size=16)
    assert main(["eval", str(trained / "run"), "--data", str(folder), "--split", "test", "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)["per_image"]) == 2
    assert main(["eval", str(trained / "run"), "--data", str(folder), "--split", "val"]) == 2
    one_line(capsys, "has no transforms_val.json")


# ============================================================================= permissions


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_outputs_follow_the_umask(trained, tmp_path, umask, mode):
    from nerfkit.io.atomic import write_json

    old = os.umask(umask)
    try:
        write_json(tmp_path / "x.json", {})
        assert main(["convert", str(trained / "a" / "data.npz"), "--to", str(tmp_path / "o.npz")]) == 0
    finally:
        os.umask(old)
    assert (tmp_path / "x.json").stat().st_mode & 0o777 == mode
    assert (tmp_path / "o.npz").stat().st_mode & 0o777 == mode
    assert (trained / "run" / "model.pt").stat().st_mode & 0o777 == 0o666 & ~old


# ============================================================================= disk


def test_the_run_keeps_a_compact_final_model_that_eval_uses(trained, tmp_path, capsys):
    from nerfkit.train.checkpoint import load_run

    run = copy_run(trained, tmp_path)
    final = torch.load(run / "model.pt", weights_only=True)
    ckpt_path = sorted((run / "checkpoints").glob("*.pt"))[-1]
    assert "optimizer" not in final and final["step"] == 6
    assert (run / "model.pt").stat().st_size < ckpt_path.stat().st_size
    shutil.rmtree(run / "checkpoints")  # eval, render, export and view need only model.pt
    _, _, step = load_run(run)
    assert step == 6
    assert main(["eval", str(run), "--json"]) == 0 and json.loads(capsys.readouterr().out)["step"] == 6


def test_a_newer_checkpoint_wins_over_an_older_final_model(trained, tmp_path):
    from nerfkit.train.checkpoint import load_run

    run = copy_run(trained, tmp_path)
    ckpt = torch.load(sorted((run / "checkpoints").glob("*.pt"))[-1], weights_only=True)
    ckpt["step"] = 9  # resumed, checkpointed at step 9, then killed before model.pt was rewritten
    torch.save(ckpt, run / "checkpoints" / "step_00000009.pt")
    assert load_run(run)[2] == 9


@pytest.mark.parametrize(
    "argv, fragments",
    [
        (
            ["view", "D", "--png", "folder.png", "--force"],
            ["--png: folder.png is a folder", "Name a PNG file, e.g. folder.png/scene.png"],
        ),
        (["convert", "D", "--to", "afile/x.npz"], ["afile/x.npz: cannot be written", "afile is a file, not a folder"]),
        (["render", "RUN", "--out", "v" * 300], ["File name too long", "Use a shorter name"]),
    ],
)
def test_a_path_the_system_refuses_is_one_line(trained, tmp_path, monkeypatch, capsys, argv, fragments):
    """OSError from the system (a folder where a file goes, a file where a folder goes, a name too
    long; permissions and full disks alike) is one line naming the path, exit code 2."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "folder.png").mkdir()
    (tmp_path / "afile").write_text("mine")
    run = copy_run(trained, tmp_path)
    argv = placed(argv, trained, run)
    assert main(argv) == 2
    one_line(capsys, *fragments)
    assert (tmp_path / "folder.png").is_dir() and (tmp_path / "afile").read_text() == "mine"
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]  # no temporary file left behind


def test_what_a_dataset_reads_beside_its_named_file_is_an_input_too(trained, tmp_path, monkeypatch, capsys):
    """A COLMAP model's photos (the project's images/, found above the model) and the folder of
    a dataset named by its transforms.json are inputs: no output may land in them, --force or not."""
    pytest.importorskip("pycolmap")
    monkeypatch.chdir(tmp_path)
    data = str(trained / "a" / "data.npz")
    assert main(["convert", data, "--to", "P", "--format", "colmap"]) == 0
    assert main(["convert", data, "--to", "W"]) == 0  # transforms.json + images/
    before = files_under(tmp_path)
    for argv in (
        ["convert", "P/sparse/0", "--to", "P/images/inside.npz"],
        ["convert", "P/sparse/0", "--to", "P", "--size", "8", "--force"],
        ["view", "W/transforms.json", "--png", "W/images/plot.png"],
        ["view", "W/transforms.json", "--png", "W/images/" + sorted(os.listdir("W/images"))[0], "--force"],
    ):
        assert main(argv) == 2, argv
        one_line(capsys, "input")
    assert files_under(tmp_path) == before
    (tmp_path / "T").mkdir()
    (tmp_path / "T" / "sparse_pc.ply").write_text("mine")  # nerfstudio's points file is an output of convert
    assert main(["convert", data, "--to", "T"]) == 2
    one_line(capsys, "sparse_pc.ply: already exists")
    assert (tmp_path / "T" / "sparse_pc.ply").read_text() == "mine"


@pytest.mark.parametrize("device", ["meta", "mps"])
def test_a_device_nerfkit_cannot_run_on_is_one_line(trained, tmp_path, capsys, device):
    run = copy_run(trained, tmp_path)
    assert main(["eval", str(run), "--device", device]) == 2
    one_line(capsys, f"not on '{device}'", "Use auto, cpu, cuda or cuda:N")


def test_an_empty_png_name_is_refused_not_taken_for_the_viewer(trained, capsys):
    assert main(["view", str(trained / "a" / "data.npz"), "--png", ""]) == 2  # it once started the server
    one_line(capsys, "--png is empty: give the path to write")


def test_a_png_that_is_a_folder_or_another_format_is_refused(trained, tmp_path, capsys):
    data = str(trained / "a" / "data.npz")
    assert main(["view", data, "--png", str(tmp_path), "--force"]) == 2
    one_line(capsys, f"--png: {tmp_path} is a folder. Name a PNG file, e.g. {tmp_path / 'scene.png'}")
    assert main(["view", data, "--png", str(tmp_path / "out.jpg")]) == 2
    one_line(capsys, "should end in .png")
    assert list(tmp_path.iterdir()) == []


def test_a_truncated_model_file_is_named_as_cut_short(trained, tmp_path, capsys):
    run = copy_run(trained, tmp_path)
    shutil.rmtree(run / "checkpoints")
    data = (run / "model.pt").read_bytes()
    (run / "model.pt").write_bytes(data[: len(data) // 2])
    assert main(["eval", str(run)]) == 2
    one_line(capsys, "model.pt: cannot load checkpoint: the file is cut short or damaged", "train it again")


@pytest.mark.slow
def test_a_run_killed_in_its_final_save_is_finished_by_resume(trained, tmp_path):
    run = copy_run(trained, tmp_path)
    metrics = json.loads((run / "metrics.json").read_text())
    (run / "metrics.json").write_text(json.dumps({**metrics, "finished": False}))  # its reports never written
    (run / "model.pt").unlink()
    assert main(["train", "--resume", str(run)]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["finished"] is True and metrics["step"] == 6 and (run / "model.pt").is_file()
