"""Hostile and broken inputs, one by one (issue 6): regression cases for the bugs the fuzz
found, exit codes and one-line errors of every command that takes files, what the servers
listen on, and that photo loading does not make float32 copies.

The random versions of these checks live in ``test_fuzz_loaders.py``; crash/resume,
atomic writes, crafted checkpoints and the non-finite guard in ``test_reliability.py``.
"""

from __future__ import annotations

import ast
import contextlib
import importlib
import inspect
import io
import json
import os
import re
import shutil
import signal
import struct
from pathlib import Path

import numpy as np
import pytest

from conftest import sigint_as_a_terminal_gives_it, tiny_vanilla, tiny_vanilla_configs
from nerfkit.cli import build_parser, main
from nerfkit.errors import NerfkitError
from test_safety import one_line

SRC = Path(__file__).resolve().parents[1] / "src" / "nerfkit"
LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")


def one_line_error(excinfo, *fragments) -> str:
    msg = str(excinfo.value)
    assert "\n" not in msg and "Traceback" not in msg, msg
    for f in fragments:
        assert f in msg, (f, msg)
    return msg


# ============================================================================= course npz


def course_arrays(n=3, size=6):
    rng = np.random.default_rng(0)
    c2w = np.tile(np.eye(4, dtype=np.float32), (n, 1, 1))
    c2w[:, :3, 3] = rng.normal(size=(n, 3)) * 0.3 + [0, 0, 4]
    return {
        "images_train": rng.integers(0, 255, (n, size, size, 3), dtype=np.uint8),
        "c2ws_train": c2w,
        "focal": np.float32(10.0),
    }


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda a: a.update(center=np.zeros(2)), "'center' must be 3 numbers"),
        (lambda a: a.update(center=np.array(["a", "b", "c"])), "'center' must be 3 numbers"),
        (lambda a: a.update(center=np.array([np.nan, 0, 0])), "'center' is [nan"),
        (lambda a: a.update(up=np.zeros(3)), "'up' is the zero vector"),
        (lambda a: a.update(up=np.array([np.inf, 0, 0])), "'up' is [inf"),
        (lambda a: a.update(focal=np.float64(1e300)), "'focal' has NaN or inf values"),
        (lambda a: a["c2ws_train"].__setitem__((0, 0, 3), 1e30), "'c2ws_train'[0] has NaN or inf values"),
        (lambda a: a.update(c2ws_train=np.repeat(a["c2ws_train"][:1], 3, 0)), "cannot estimate near/far"),
        (lambda a: a.update(K=np.array([[1e300, 0, 3], [0, 1e300, 3], [0, 0, 1]])), "'K' has NaN or inf values"),
    ],
)
def test_npz_values_that_used_to_crash_or_load_as_garbage(tmp_path, edit, message):
    from nerfkit.data.npz import load_npz

    a = course_arrays()
    edit(a)
    np.savez(tmp_path / "s.npz", **a)
    with pytest.raises(NerfkitError) as e:
        load_npz(tmp_path / "s.npz")
    one_line_error(e, message, "s.npz")


def test_npz_byte_string_names_are_decoded(tmp_path):
    from nerfkit.data.npz import load_npz

    np.savez(tmp_path / "s.npz", **course_arrays(), names_train=np.array([b"a.jpg", b"b.jpg", b"c.jpg"]))
    assert load_npz(tmp_path / "s.npz").train.names == ["a.jpg", "b.jpg", "c.jpg"]


# ============================================================================= images


def test_float_tiff_with_nan_loads_finite(tmp_path):
    from PIL import Image

    from nerfkit.images import load_image

    Image.fromarray(np.array([[np.nan, np.inf], [-np.inf, 0.5]], np.float32)).save(tmp_path / "f.tif")
    img = load_image(tmp_path / "f.tif")
    assert np.isfinite(img).all() and img.min() >= 0 and img.max() <= 1


@pytest.mark.parametrize("name", ["a\x00b.png", "x" * 5000 + ".png"])
def test_unusable_image_paths_are_one_line_errors(tmp_path, name):
    from nerfkit.data.load import load_scene
    from nerfkit.images import load_image_uint8

    for fn in (load_image_uint8, load_scene):
        with pytest.raises(NerfkitError, match="not a usable path|no such file") as e:
            fn(str(tmp_path / name))
        one_line_error(e)


def test_hidden_files_beside_photos_are_not_photos(tmp_path):
    from nerfkit.images import list_images

    for name in ("IMG_0001.JPG", "._IMG_0001.JPG", ".hidden.png", "notes.txt", "b.png"):
        (tmp_path / name).write_bytes(b"x")
    assert [p.name for p in list_images(tmp_path)] == ["IMG_0001.JPG", "b.png"]
    (tmp_path / "IMG_0001.JPG").unlink()
    (tmp_path / "b.png").unlink()
    with pytest.raises(NerfkitError, match="holds no images"):
        list_images(tmp_path)  # the macOS "._" files alone are no photos
    (tmp_path / "IMG_0002.MOV").write_bytes(b"x")
    with pytest.raises(NerfkitError, match=r"holds no images, but a video \(IMG_0002.MOV\)\. Pass the video itself"):
        list_images(tmp_path)


def test_uint8_loading_of_a_photo_makes_no_float_copy(tmp_path):
    """A 12-MP photo as float32 is ~150 MB; load_image_uint8 must not build one (nor three)."""
    import tracemalloc

    from PIL import Image

    from nerfkit.images import load_image_uint8

    w, h = 1600, 1200
    yy, xx = np.mgrid[0:h, 0:w]
    Image.fromarray(np.stack([xx % 256, yy % 256, (xx + yy) % 256], -1).astype(np.uint8)).save(tmp_path / "p.jpg")
    tracemalloc.start()
    img = load_image_uint8(tmp_path / "p.jpg")
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert img.shape == (h, w, 3) and img.dtype == np.uint8
    assert peak < 2.5 * img.nbytes, f"peak {peak / 1e6:.1f} MB for a {img.nbytes / 1e6:.1f} MB image"


# ============================================================================= Blender folders


def make_blender(folder: Path, angle=0.69, n=3):
    from PIL import Image

    from nerfkit.cameras import opencv_to_opengl
    from nerfkit.data.synthetic import sphere_cameras

    c2w = sphere_cameras(n, seed=1).astype(np.float64)
    (folder / "train").mkdir(parents=True)
    for i in range(n):
        Image.new("RGBA", (8, 6), (10, 20, 30, 255)).save(folder / "train" / f"r_{i}.png")
    frames = [{"file_path": f"./train/r_{i}", "transform_matrix": opencv_to_opengl(c2w[i]).tolist()} for i in range(n)]
    (folder / "transforms_train.json").write_text(json.dumps({"camera_angle_x": angle, "frames": frames}))


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda d: d.update(camera_angle_x=True), "'camera_angle_x' is True"),
        (lambda d: d.update(camera_angle_x=1e-300), "'camera_angle_x' has NaN or inf values"),
        (lambda d: d["frames"][0]["transform_matrix"][0].__setitem__(3, 1e300), "has NaN or inf values"),
        (lambda d: d["frames"][0].update(file_path="a\x00b"), "is not a usable path"),
        (lambda d: d["frames"][0].update(file_path="x" * 5000), "is not a usable path"),
        (lambda d: d["frames"][0].update(file_path="line\nbreak"), "not found"),
    ],
)
def test_blender_values_that_used_to_crash_or_load_as_garbage(tmp_path, edit, message):
    from nerfkit.data.load import load_scene

    make_blender(tmp_path)
    p = tmp_path / "transforms_train.json"
    d = json.loads(p.read_text())
    edit(d)
    p.write_text(json.dumps(d))
    with pytest.raises(NerfkitError) as e:
        load_scene(tmp_path)
    one_line_error(e, message)


# ============================================================================= COLMAP models


def colmap_project(folder: Path, cams="1 PINHOLE 16 12 20 20 8 6\n", pose="1 0 0 0 {x} 0 4", n=4) -> Path:
    from PIL import Image

    m = folder / "sparse" / "0"
    m.mkdir(parents=True)
    (m / "cameras.txt").write_text(cams)
    (m / "images.txt").write_text("".join(f"{i + 1} {pose.format(x=0.1 * i)} 1 {i}.png\n\n" for i in range(n)))
    pts = np.random.default_rng(0).normal(size=(30, 3)) * 0.3
    (m / "points3D.txt").write_text("".join(f"{j + 1} {x} {y} {z} 1 2 3 0.5\n" for j, (x, y, z) in enumerate(pts)))
    (folder / "images").mkdir()
    for i in range(n):
        Image.new("RGB", (16, 12)).save(folder / "images" / f"{i}.png")
    return folder


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"cams": "1 PINHOLE 16 12 0 0 8 6\n"}, "zero or negative focal"),
        ({"cams": "1 PINHOLE 16 12 -20 -20 8 6\n"}, "zero or negative focal"),
        ({"cams": "1 PINHOLE 0 12 20 20 8 6\n"}, "has image size 0x12"),
        ({"pose": "1 0 0 0 1e300 0 4"}, "has NaN or inf values"),
        ({"pose": "0 0 0 0 {x} 0 4"}, "which is zero: no rotation at all"),  # (one of norm 0.5 is normalised)
        ({"cams": "1 PINHOLE 16 12 nan 20 8 6\n"}, "cannot read the COLMAP model"),
    ],
)
def test_colmap_values_that_used_to_load_as_garbage(tmp_path, kw, message):
    pytest.importorskip("pycolmap")
    from nerfkit.data.load import load_scene

    with pytest.raises(NerfkitError) as e:
        load_scene(colmap_project(tmp_path, **kw))
    one_line_error(e, message)


def _binary_model(folder: Path) -> Path:
    from nerfkit.data.colmap import write_colmap_model
    from nerfkit.data.synthetic import sphere_scene

    return write_colmap_model(sphere_scene(n_train=3, n_val=1, size=8), folder)


def test_colmap_binary_header_declaring_a_huge_count_is_refused_at_once(tmp_path):
    """8 bytes claiming 10^15 points made pycolmap allocate until the machine ran out of memory."""
    pytest.importorskip("pycolmap")
    from nerfkit.data.colmap import read_model

    m = _binary_model(tmp_path / "m")
    (m / "points3D.bin").write_bytes(struct.pack("<Q", 10**15))
    with pytest.raises(NerfkitError) as e:
        read_model(m)
    one_line_error(e, "declares 1000000000000000 records but holds 8 bytes")


def test_colmap_binary_nested_count_is_read_in_a_memory_capped_child(tmp_path):
    """A huge per-image point count inside images.bin: pycolmap tries to allocate it."""
    pytest.importorskip("pycolmap")
    from nerfkit.data.colmap import read_model

    m = _binary_model(tmp_path / "m")
    b = bytearray((m / "images.bin").read_bytes())
    off = b.index(b"\x00", 8 + 4 + 32 + 24 + 4) + 1  # after the first image's name
    b[off : off + 8] = struct.pack("<Q", 10**15)
    (m / "images.bin").write_bytes(bytes(b))
    with pytest.raises(NerfkitError) as e:
        read_model(m)
    one_line_error(e, "cannot read the COLMAP model")


# ============================================================================= run config.json and checkpoints


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    from nerfkit.data.npz import save_npz
    from nerfkit.data.synthetic import sphere_scene
    from nerfkit.train.trainer import train

    root = tmp_path_factory.mktemp("hostile")
    scene = sphere_scene(n_train=4, n_val=1, size=8)
    save_npz(scene, root / "data.npz")
    train(scene, *tiny_vanilla_configs(root / "run", 3, data=str(root / "data.npz")), quiet=True)
    return root / "run"


def edited_run(tiny_run, tmp_path, edit_config=None, edit_checkpoint=None) -> Path:
    import torch

    run = shutil.copytree(tiny_run, tmp_path / "run")
    if edit_config:
        cfg = json.loads((run / "config.json").read_text())
        cfg = edit_config(cfg) or cfg
        (run / "config.json").write_text(json.dumps(cfg))
    if edit_checkpoint:  # the newest checkpoint and the final model.pt hold the same model
        for path in (sorted((run / "checkpoints").glob("*.pt"))[-1], run / "model.pt"):
            ckpt = torch.load(path, weights_only=True)
            edit_checkpoint(ckpt)
            torch.save(ckpt, path)
    return run


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda c: [c], "expected a JSON object, got list"),
        (lambda c: c.update(train=[]), "'train' is missing or not an object"),
        (lambda c: c.update(model=["width"]), "'model' is missing or not an object"),
        (lambda c: c["train"].update(model="nope"), "unknown model 'nope'"),
        (lambda c: c["train"].update(lr=float("nan")), "'lr' (--lr): 'nan' is not a finite number"),
        (
            lambda c: c["train"].update(lr_final_factor=5.0),
            "'lr_final_factor' (--lr-final-factor): 5.0 is above the maximum 1",
        ),
        (lambda c: c["train"].update(steps=0, minutes=0.0), "invalid TrainConfig settings (train: no stopping rule"),
        (lambda c: c["bounds"].update(near=float("nan")), "near/far must be finite"),
        (lambda c: c["bounds"].update(near=7.0), "need 0 <= near < far"),
        (lambda c: c["bounds"].update(center=[1.0]), "'bounds.center' must be 3 numbers"),
        (lambda c: c["bounds"].update(up=[0, 0, 0]), "'bounds.up' is the zero vector"),
        (lambda c: c["bounds"].update(radius=-1), "'bounds.radius' is -1"),
        (lambda c: c["bounds"].update(radius=1e14), "'bounds' reach 1e+14 units"),  # a grid over it divides by 0
        (lambda c: c["model"].update(width=-1), "'width' (--width): -1 is below the minimum 1"),
    ],
)
def test_run_config_values_that_used_to_crash_or_load_as_garbage(tiny_run, tmp_path, edit, message):
    from nerfkit.train.checkpoint import load_run

    with pytest.raises(NerfkitError) as e:
        load_run(edited_run(tiny_run, tmp_path, edit_config=edit))
    one_line_error(e, message, "config.json")


def first_weight(ckpt: dict) -> str:
    """The name of the first weight matrix in a checkpoint's model state."""
    return next(name for name in ckpt["model"] if name.endswith(".weight"))


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda k: k.update(model_extra=5), "'model' or 'model_extra' has the wrong type"),
        (lambda k: k.update(model=[1, 2]), "'model' or 'model_extra' has the wrong type"),
        (lambda k: k.update(model_packing=5), "'model_packing' is not a name"),
        (lambda k: k.update(model_packing="zip-bomb-9"), "unknown model packing 'zip-bomb-9'"),
        (lambda k: k.update(step="x"), "checkpoint step is 'x'"),
        (lambda k: k.update(step=-5), "checkpoint step is -5"),
        (
            lambda k: k["model"].update({first_weight(k): k["model"][first_weight(k)] * float("nan")}),
            "weights hold NaN or inf",
        ),
        (
            lambda k: k["model"].update({first_weight(k): k["model"][first_weight(k)] * float("inf")}),
            "weights hold NaN or inf",
        ),
        (
            lambda k: k["model"].update({"estimator.cell_sigma": k["model"]["estimator.cell_sigma"] * float("nan")}),
            "state holds NaN",
        ),
        (lambda k: k["model"].update({first_weight(k): np.float32(0) + __import__("torch").zeros(1)}), "size mismatch"),
    ],
)
def test_checkpoint_values_that_used_to_crash_or_load_as_garbage(tiny_run, tmp_path, capsys, edit, message):
    from nerfkit.train.checkpoint import load_run

    with pytest.raises(NerfkitError) as e:
        load_run(edited_run(tiny_run, tmp_path, edit_checkpoint=edit))
    one_line_error(e, message, "no checkpoint could be loaded")
    assert capsys.readouterr().err == ""  # the reason is in the error, not repeated as a warning


def _npz_at(path: Path) -> None:
    with open(path, "wb") as f:
        np.savez(f, x=np.zeros(3))


@pytest.mark.parametrize("write", [lambda p: p.write_text("hello"), _npz_at], ids=["text", "npz"])
def test_a_checkpoint_replaced_by_another_kind_of_file_says_so(tiny_run, tmp_path, write):
    """A text file or an npz where the run's checkpoints were: the error says what is wrong and
    what to do, not the unpickler's KeyError or the zip reader's internals."""
    from nerfkit.train.checkpoint import load_run

    run = edited_run(tiny_run, tmp_path)
    for path in [run / "model.pt", *(run / "checkpoints").glob("*.pt")]:
        write(path)
    with pytest.raises(NerfkitError) as e:
        load_run(run)
    one_line_error(e, "the file is not a PyTorch checkpoint", "no checkpoint could be loaded")
    assert "KeyError" not in str(e.value) and "inline_container" not in str(e.value)


# ============================================================================= files owned by the capture work


@pytest.mark.parametrize(
    "text",
    [
        '{"K": [[1000, 0, 640], [0, 1000, 480], [0, 0, 1]], "dist": [0, 0, 0, 0, 0], "width": Infinity, "height": 960}',
        "DIRECTORY",
    ],
)
def test_camera_file_crashes(tmp_path, text):
    from nerfkit.capture.camera import load_camera

    path = tmp_path / "camera.json"
    if text == "DIRECTORY":
        path.mkdir()
    else:
        path.write_text(text)
    with pytest.raises(NerfkitError) as e:
        load_camera(path)
    one_line_error(e)
    if text == "DIRECTORY":
        (path / "camera.json").write_text("{}")
        with pytest.raises(
            NerfkitError, match=r"is a folder, not a JSON file\. Name the JSON file itself \(.* holds camera\.json\)"
        ):
            load_camera(path)


GRID = {"board": "grid", "markers_y": 2, "marker_length": 0.04, "marker_separation": 0.01}


@pytest.mark.parametrize(
    "spec, message",
    [
        ({"tags": {"0": {"center": "ab", "size": 0.05}}}, r"'tags\.0\.center' must hold numbers, got 'ab'"),
        ({"tags": {"0": {"center": [0, 0], "size": "big"}}}, r"'tags\.0\.size' is 'big', expected a positive length"),
        (
            {"tags": {"0": {"center": [0, 0], "size": 0.05, "rotation_deg": "x"}}},
            r"'tags\.0\.rotation_deg' is 'x', expected a finite number",
        ),
        ({"tags": {"0": [[0, 0, 0], [1, 0]]}}, r"'tags\.0' is not an array of numbers \(ragged or mixed lists\?\)"),
        ({"tags": {"0": {"center": [0, 0], "size": float("inf")}}}, r"'tags\.0\.size' is inf, expected a positive"),
        ({"tag_size": "x", "tags": {"0": {"center": [0, 0]}}}, r"'tag_size' is 'x', expected a positive length"),
        ({**GRID, "markers_x": -2}, r"'markers_x' is -2, expected a whole number from 1 to 100"),
        ({**GRID, "markers_x": 10**6, "markers_y": 10**6}, r"'markers_x' is 1000000, expected a whole number from 1"),
        ({**GRID, "markers_x": float("inf")}, r"'markers_x' is inf, expected a whole number from 1 to 100"),
        ({**GRID, "dictionary": ["x"], "markers_x": 2}, r"unknown ArUco dictionary \['x'\]\. Use one of DICT_4X4_50"),
        (
            {"board": "charuco", "squares_x": 5, "squares_y": 5, "square_length": 0.01, "marker_length": 0.04},
            r"'marker_length' is 0\.04, expected a positive length in metres, smaller than square_length 0\.01",
        ),
    ],
)
def test_layout_file_crashes(tmp_path, spec, message):
    from nerfkit.capture.aruco import load_layout

    path = tmp_path / "layout.json"
    path.write_text(json.dumps(spec))
    with pytest.raises(NerfkitError, match=message) as e:
        load_layout(path, "DICT_4X4_50")
    one_line_error(e, str(path), "Fix the layout file")


@pytest.mark.parametrize(
    "edit",
    [
        lambda d: d.update(w=0),
        lambda d: (d.pop("fl_x"), d.pop("fl_y"), d.update(camera_angle_x=0)),
        lambda d: d.update(nerfkit={"center": [1, 2]}),
        lambda d: d.update(nerfkit={"near": "a", "far": 2}),
        lambda d: d.update(nerfkit={"poses_only": [1, 2]}),
        lambda d: d.update(nerfkit={"poses_only": {"test": "abc"}}),
    ],
)
def test_transforms_json_crashes(tmp_path, edit):
    from PIL import Image

    from nerfkit.data.load import load_scene

    (tmp_path / "images").mkdir()
    frames = []
    for i in range(3):
        Image.new("RGB", (16, 12)).save(tmp_path / "images" / f"{i}.png")
        m = np.eye(4)
        m[:3, 3] = [0.3 * i, 0, 4]
        frames.append({"file_path": f"images/{i}.png", "transform_matrix": m.tolist()})
    d = {"fl_x": 20, "fl_y": 20, "cx": 8, "cy": 6, "w": 16, "h": 12, "frames": frames}
    edit(d)
    (tmp_path / "transforms.json").write_text(json.dumps(d))
    with pytest.raises(NerfkitError) as e:
        load_scene(tmp_path)
    one_line_error(e)


# ============================================================================= fast model grid sizes


def test_fast_grid_resolution_is_bounded_in_config_and_checkpoint():
    """A config or a crafted checkpoint must not make the fast model allocate a huge grid."""
    from nerfkit.models.base import SceneBounds
    from nerfkit.models.fast import FastConfig, FastNeRF

    with pytest.raises(NerfkitError) as e:
        FastConfig(resolutions="16,100000", upsample_steps="10").stages()
    one_line_error(e, "--resolutions", "'resolutions'", "Use smaller sizes")
    with pytest.raises(NerfkitError) as e:
        FastConfig(resolutions="32,16", upsample_steps="10").stages()  # a stage that shrinks the grid
    one_line_error(e, "--resolutions", "'32,16': a stage's grid must not be smaller than the one before")

    bounds = SceneBounds(2.0, 6.0, np.zeros(3, np.float32), 1.0, np.array([0, 0, 1], np.float32))
    model = FastNeRF(FastConfig(resolutions="8", upsample_steps="", kernels="torch"), bounds)
    shape = tuple(model.field.grid.shape)
    for res in ([4096, 4096, 4096], [100000, 2, 2], [8, 8, True], "8,8,8", [8, 8]):
        state = {**model.extra_state(), "res": res}
        with pytest.raises(NerfkitError) as e:
            model.load_extra_state(state)
        one_line_error(e, "'res'", "model_extra")
        assert tuple(model.field.grid.shape) == shape  # refused before anything was replaced


# ============================================================================= named pipes, devices, sockets


@contextlib.contextmanager
def within(seconds: int):
    """Fail, instead of hanging, when the block takes longer than ``seconds``: opening a named
    pipe nobody writes to blocks, and SIGALRM interrupts it."""

    def stop(signum, frame):  # not an OSError, which readers turn into their own errors
        pytest.fail(f"still blocked after {seconds} s")

    previous = signal.signal(signal.SIGALRM, stop)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _fifo(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(path)
    return path


def _piped(reader: str, name: str):
    """Read a named pipe ``name`` with ``reader`` ("module:function")."""

    def read(t: Path):
        module, function = reader.split(":")
        return getattr(importlib.import_module(module), function)(_fifo(t / name))

    return read


def _npz_beside_a_piped_transforms_json(t: Path):
    from nerfkit.commands.view import dataset_tag_size

    np.savez(t / "scene.npz", **course_arrays())
    _fifo(t / "transforms.json")
    return dataset_tag_size(t / "scene.npz")


def _colmap_with_piped_points(t: Path):
    pytest.importorskip("pycolmap")
    from nerfkit.data.load import load_scene

    colmap_project(t)
    (t / "sparse" / "0" / "points3D.txt").unlink()
    _fifo(t / "sparse" / "0" / "points3D.txt")
    return load_scene(t)


def _blender_with_a_piped_image(t: Path):
    from nerfkit.data.load import load_scene

    make_blender(t)
    (t / "train" / "r_1.png").unlink()
    _fifo(t / "train" / "r_1.png")
    return load_scene(t)


def _llff_with_piped_poses(t: Path):
    from nerfkit.data.load import load_scene

    _fifo(t / "scene" / "poses_bounds.npy")
    return load_scene(t / "scene")


def _nerfstudio_with_a_piped_point_cloud(t: Path):
    from nerfkit.data.load import load_scene

    (t / "images").mkdir()
    from PIL import Image

    Image.fromarray(np.zeros((4, 6, 3), np.uint8)).save(t / "images" / "a.png")
    frame = {"file_path": "images/a.png", "transform_matrix": np.eye(4).tolist()}
    (t / "transforms.json").write_text(
        json.dumps(
            {
                "fl_x": 5,
                "fl_y": 5,
                "cx": 3,
                "cy": 2,
                "w": 6,
                "h": 4,
                "ply_file_path": "points.ply",
                "frames": [frame],
                "nerfkit": {"near": 0.1, "far": 2.0},
            }
        )
    )
    _fifo(t / "points.ply")
    return load_scene(t)


@pytest.mark.parametrize(
    "read, piped",
    [
        (_piped("nerfkit.data.load:load_scene", "scene.npz"), "scene.npz"),
        (_piped("nerfkit.data.npz:load_npz", "scene.npz"), "scene.npz"),
        (_piped("nerfkit.images:load_image", "photo.jpg"), "photo.jpg"),
        (_piped("nerfkit.config:load_json", "camera.json"), "camera.json"),
        (_blender_with_a_piped_image, "r_1.png"),
        (_colmap_with_piped_points, "points3D.txt"),
        (_npz_beside_a_piped_transforms_json, "transforms.json"),
        (_llff_with_piped_poses, "poses_bounds.npy"),
        (_nerfstudio_with_a_piped_point_cloud, "points.ply"),
    ],
    ids=[
        "dataset",
        "npz",
        "image",
        "json",
        "image in a dataset",
        "colmap model file",
        "file beside a dataset",
        "llff poses",
        "nerfstudio point cloud",
    ],
)
def test_a_named_pipe_is_refused_without_opening_it(tmp_path, read, piped):
    # opening a pipe nobody writes to blocked forever: `nerfkit train --data pipe.npz` never returned
    with within(10), pytest.raises(NerfkitError) as e:
        read(tmp_path)
    one_line_error(e, piped, "is a named pipe, not a regular file", "nerfkit reads only regular files")


def test_devices_and_sockets_are_refused_by_what_they_are(tmp_path):
    import socket

    from nerfkit.io.paths import refuse_special_file

    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(tmp_path / "s.npz"))
    (tmp_path / "zero.npz").symlink_to("/dev/zero")  # reading it never ends
    try:
        for path, what in ((tmp_path / "s.npz", "a socket"), (tmp_path / "zero.npz", "a character device")):
            with pytest.raises(NerfkitError) as e:
                refuse_special_file(path)
            one_line_error(e, f"{path}: is {what}, not a regular file")
    finally:
        sock.close()
    (tmp_path / "a.npz").write_bytes(b"x")
    for path in (tmp_path / "a.npz", tmp_path, tmp_path / "none"):
        assert refuse_special_file(path) == path  # a folder or nothing: the reader says what it expected


@pytest.mark.slow
def test_train_on_a_named_pipe_is_one_line_and_writes_nothing(tmp_path):
    import subprocess
    import sys

    pipe = _fifo(tmp_path / "x.npz")
    try:
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "nerfkit",
                "train",
                "--data",
                str(pipe),
                "--out",
                str(tmp_path / "r"),
                "--steps",
                "1",
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
    except subprocess.TimeoutExpired:
        pytest.fail("nerfkit train --data PIPE blocked")
    assert proc.returncode == 2
    assert proc.stderr == (
        f"nerfkit train: error: {pipe}: is a named pipe, not a regular file. nerfkit reads only "
        "regular files (a pipe or device could block or never end); save the data to a file and "
        "pass that\n"
    )
    assert not (tmp_path / "r").exists()


# ============================================================================= exit codes through the CLI


def _broken_inputs(root: Path, run: Path) -> dict[str, Path]:
    """A few broken files and folders, made once."""
    from PIL import Image

    b = {}
    root.mkdir(parents=True, exist_ok=True)
    (root / "truncated.npz").write_bytes(b"PK\x03\x04 truncated")
    b["truncated_npz"] = root / "truncated.npz"
    bad = course_arrays()
    bad["c2ws_train"][0, :3, :3] *= 2.0
    np.savez(root / "nonrigid.npz", **bad)
    b["nonrigid_npz"] = root / "nonrigid.npz"
    buf = io.BytesIO()
    Image.new("RGB", (64, 48), (200, 10, 10)).save(buf, "JPEG")
    (root / "photos").mkdir(exist_ok=True)
    (root / "photos" / "IMG_0001.jpg").write_bytes(buf.getvalue()[:100])
    (root / "photos" / "IMG_0002.jpg").write_text("not a photo")
    b["photos"] = root / "photos"
    b["truncated_jpg"] = root / "photos" / "IMG_0001.jpg"
    (root / "camera.json").write_text('{"K": [[0, 0, 1], [0, 0, 1], [0, 0, 1]], "dist": [], "width": 8, "height": 6}')
    b["camera"] = root / "camera.json"
    (root / "layout.json").write_text('{"tags": {"0": [[0, 0, 0]]}}')
    b["layout"] = root / "layout.json"
    broken_run = shutil.copytree(run, root / "broken_run")
    (broken_run / "config.json").write_text('{"train": {"model": "vanilla"')
    b["broken_run"] = broken_run
    nan_run = shutil.copytree(run, root / "nan_run")
    import torch

    for p in nan_run.rglob("*.pt"):  # the checkpoints and the final model.pt
        ckpt = torch.load(p, weights_only=True)
        for k, v in ckpt["model"].items():
            if v.is_floating_point():
                ckpt["model"][k] = v * float("nan")
        torch.save(ckpt, p)
    b["nan_run"] = nan_run
    b["run"] = run
    (root / "poses").mkdir(exist_ok=True)
    (root / "poses" / "poses.json").write_text('{"format": "nerfkit-poses", "camera": 5}')
    b["poses_json"] = root / "poses"
    outside = root / "outside"  # a transforms.json whose frame reaches out of its folder
    outside.mkdir(exist_ok=True)
    frame = {"file_path": "/etc/hostname", "transform_matrix": np.eye(4).tolist()}
    (outside / "transforms.json").write_text(json.dumps({"fl_x": 10, "w": 8, "h": 8, "frames": [frame]}))
    b["outside_paths"] = outside
    return b


CASES = [
    (
        "train --data truncated",
        lambda b, t: [
            "train",
            "--data",
            str(b["truncated_npz"]),
            "--out",
            str(t / "r"),
            "--steps",
            "1",
            "--model",
            "vanilla",
        ],
    ),
    (
        "train --data non-rigid",
        lambda b, t: [
            "train",
            "--data",
            str(b["nonrigid_npz"]),
            "--out",
            str(t / "r"),
            "--steps",
            "1",
            "--model",
            "vanilla",
        ],
    ),
    (
        "train --data missing",
        lambda b, t: ["train", "--data", str(t / "nope.npz"), "--out", str(t / "r"), "--steps", "1"],
    ),
    ("train --resume broken", lambda b, t: ["train", "--resume", str(b["broken_run"])]),
    ("eval broken run", lambda b, t: ["eval", str(b["broken_run"])]),
    ("eval --data broken", lambda b, t: ["eval", str(b["run"]), "--data", str(b["nonrigid_npz"])]),
    ("eval nan checkpoint", lambda b, t: ["eval", str(b["nan_run"])]),
    ("render broken run", lambda b, t: ["render", str(b["broken_run"])]),
    ("render missing run", lambda b, t: ["render", str(t / "no_run")]),
    ("convert truncated", lambda b, t: ["convert", str(b["truncated_npz"]), "--to", str(t / "o.npz")]),
    ("convert non-rigid", lambda b, t: ["convert", str(b["nonrigid_npz"]), "--to", str(t / "o")]),
    ("export broken run", lambda b, t: ["export", str(b["broken_run"]), "--mesh", str(t / "m.ply")]),
    (
        "fit-image truncated",
        lambda b, t: ["fit-image", str(b["truncated_jpg"]), "--out", str(t / "f"), "--steps", "1", "--quiet"],
    ),
    ("fit-image missing", lambda b, t: ["fit-image", str(t / "none.jpg"), "--out", str(t / "f"), "--quiet"]),
    (
        "calibrate unreadable photos",
        lambda b, t: [
            "calibrate",
            str(b["photos"]),
            "--tag-size",
            "0.05",
            "--out",
            str(t / "cam.json"),
            "--no-cache",
            "--jobs",
            "1",
        ],
    ),
    (
        "calibrate bad layout",
        lambda b, t: ["calibrate", str(b["photos"]), "--layout", str(b["layout"]), "--out", str(t / "cam.json")],
    ),
    (
        "poses bad camera",
        lambda b, t: [
            "poses",
            str(b["photos"]),
            "--camera",
            str(b["camera"]),
            "--tag-size",
            "0.05",
            "--out",
            str(t / "ds"),
        ],
    ),
    (
        "poses unreadable photos",
        lambda b, t: [
            "poses",
            str(b["photos"]),
            "--tag-size",
            "0.05",
            "--focal-px",
            "50",
            "--out",
            str(t / "ds"),
            "--no-cache",
            "--jobs",
            "1",
        ],
    ),
    ("dataset broken poses.json", lambda b, t: ["dataset", str(b["poses_json"]), "--out", str(t / "ds")]),
    ("view --png truncated", lambda b, t: ["view", str(b["truncated_npz"]), "--png", str(t / "v.png")]),
    ("view --png non-rigid", lambda b, t: ["view", str(b["nonrigid_npz"]), "--png", str(t / "v.png")]),
    # issue 12: paths outside the dataset, outputs onto inputs, numbers checked when parsed
    (
        "train --data outside paths",
        lambda b, t: ["train", "--data", str(b["outside_paths"]), "--out", str(t / "r"), "--steps", "1"],
    ),
    ("convert outside paths", lambda b, t: ["convert", str(b["outside_paths"]), "--to", str(t / "o.npz")]),
    (
        "convert onto its source",
        lambda b, t: [
            "convert",
            str(b["outside_paths"] / "transforms.json"),
            "--to",
            str(b["outside_paths"]),
            "--force",
        ],
    ),
    (
        "train --minutes nan",
        lambda b, t: ["train", "--data", str(b["nonrigid_npz"]), "--out", str(t / "r"), "--minutes", "nan"],
    ),
    ("train --lr inf", lambda b, t: ["train", "--data", str(b["nonrigid_npz"]), "--out", str(t / "r"), "--lr", "inf"]),
    ("train --resume --lr", lambda b, t: ["train", "--resume", str(b["run"]), "--lr", "1"]),
    ("render --fps 0", lambda b, t: ["render", str(b["run"]), "--fps", "0", "--out", str(t / "v")]),
    ("render --chunk -1", lambda b, t: ["render", str(b["run"]), "--chunk", "-1"]),
    ("eval --chunk -1", lambda b, t: ["eval", str(b["run"]), "--chunk", "-1"]),
    ("export --resolution 0", lambda b, t: ["export", str(b["run"]), "--mesh", str(t / "m.ply"), "--resolution", "0"]),
]


@pytest.fixture(scope="module")
def broken(tiny_run, tmp_path_factory):
    return _broken_inputs(tmp_path_factory.mktemp("broken"), tiny_run)


@pytest.mark.parametrize("name, argv", CASES, ids=[c[0] for c in CASES])
def test_cli_exit_code_2_and_one_line_for_broken_inputs(broken, tmp_path, capsys, name, argv):
    args = argv(broken, tmp_path)
    code = main(args)
    out, err = capsys.readouterr()
    # A tqdm bar (leave=False) is erased on a terminal but stays in a captured stream: not counted here
    # (reported: the capture commands could pass disable=None so that pipes and logs get no bar).
    shown = [ln.rsplit("\r", 1)[-1] for ln in err.splitlines()]
    lines = [ln for ln in shown if ln.strip() and not re.search(r"\|\s*\d+/\d+ \[", ln)]
    assert code == 2, (code, err)
    assert "Traceback" not in err
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"nerfkit {args[0]}: error: "), lines


def test_a_broken_newest_checkpoint_is_one_warning_when_an_older_one_loads(broken, tmp_path, capsys):
    from nerfkit.train.checkpoint import load_run

    run = shutil.copytree(broken["run"], tmp_path / "run")
    good = sorted((run / "checkpoints").glob("*.pt"))[-1]
    shutil.copy(sorted((broken["nan_run"] / "checkpoints").glob("*.pt"))[-1], run / "checkpoints" / "step_00009999.pt")
    _, _, step = load_run(run)
    assert step == int(good.stem.split("_")[1])
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "step_00009999.pt" in lines[0] and "NaN or inf" in lines[0], lines


# ============================================================================= network exposure


def test_view_listens_on_localhost_unless_told_otherwise():
    parser = build_parser()
    assert parser.parse_args(["view", "x"]).host == "127.0.0.1"
    assert parser.parse_args(["view", "x", "--host", "0.0.0.0"]).host == "0.0.0.0"


def test_every_host_flag_of_every_command_defaults_to_localhost():
    import argparse

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    seen = 0
    for name, p in sub.choices.items():
        for action in p._actions:
            if action.dest in ("host", "bind", "address") or any("host" in o for o in action.option_strings):
                seen += 1
                assert action.default in LOCAL_HOSTS, (name, action.default)
    assert seen >= 1  # at least `view --host`


def test_every_serve_function_defaults_to_localhost():
    import importlib
    import pkgutil

    import nerfkit.commands
    import nerfkit.viz

    checked = []
    for pkg in (nerfkit.viz, nerfkit.commands):
        for mod in pkgutil.iter_modules(pkg.__path__):
            module = importlib.import_module(f"{pkg.__name__}.{mod.name}")
            for obj in vars(module).values():
                funcs = (
                    [obj]
                    if inspect.isfunction(obj)
                    else [m for m in vars(obj).values() if inspect.isfunction(m)]
                    if inspect.isclass(obj)
                    else []
                )
                for f in funcs:
                    if getattr(f, "__module__", None) != module.__name__:
                        continue
                    param = inspect.signature(f).parameters.get("host")
                    if param is not None:
                        checked.append(f"{module.__name__}.{f.__qualname__}")
                        assert param.default in LOCAL_HOSTS, (f.__qualname__, param.default)
    from nerfkit.viz.viewer import serve_dataset

    assert inspect.signature(serve_dataset).parameters["host"].default == "127.0.0.1"
    try:
        from nerfkit.commands.live import LiveViewer, serve_run
    except ImportError:
        pass
    else:
        assert inspect.signature(serve_run).parameters["host"].default == "127.0.0.1"
        assert inspect.signature(LiveViewer).parameters["host"].default == "127.0.0.1"
    assert len(checked) >= 2, checked


def test_every_viser_server_is_given_a_host_explicitly():
    """viser's own default is 0.0.0.0 (every interface): nerfkit must always pass ``host``."""
    calls = 0
    for path in SRC.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Call):
                f = node.func
                name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
                if name == "ViserServer":
                    calls += 1
                    assert any(k.arg == "host" for k in node.keywords), (
                        f"{path}:{node.lineno} relies on viser's default host 0.0.0.0"
                    )
    assert calls >= 1


def _listening(port: int) -> list[str]:
    """Local addresses listening on TCP ``port`` (from /proc/net/tcp and tcp6)."""
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            local, state = row.split()[1], row.split()[3]
            addr, p = local.split(":")
            if int(p, 16) == port and state == "0A":  # LISTEN
                found.append(addr)
    return found


def test_the_dataset_viewer_really_binds_to_localhost_only():
    pytest.importorskip("viser")
    if not Path("/proc/net/tcp").exists():
        pytest.skip("needs /proc/net/tcp")
    import socket

    from nerfkit.data.synthetic import sphere_scene
    from nerfkit.viz.viewer import serve_dataset

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server, _ = serve_dataset(sphere_scene(n_train=3, n_val=1, size=8), port=port, block=False)
    try:
        addrs = _listening(server.get_port())
        assert addrs, "the viewer is not listening"
        assert set(addrs) <= {"0100007F", "00000000000000000000000001000000"}, addrs  # 127.0.0.1, ::1
    finally:
        server.stop()


def test_view_command_passes_localhost_and_warns_for_other_hosts(tmp_path, monkeypatch, capsys):
    from nerfkit.data.npz import save_npz
    from nerfkit.data.synthetic import sphere_scene
    from nerfkit.viz import viewer

    save_npz(sphere_scene(n_train=3, n_val=1, size=8), tmp_path / "d.npz")
    calls = []

    class FakeServer:
        def get_port(self):
            return 8080

    def fake_serve(scene, host, port, **kw):
        calls.append(host)
        return FakeServer(), {}

    monkeypatch.setattr(viewer, "serve_dataset", fake_serve)
    monkeypatch.setattr(viewer, "wait_until_interrupted", lambda server: None)
    assert main(["view", str(tmp_path / "d.npz")]) == 0
    assert "warning" not in capsys.readouterr().err
    assert main(["view", str(tmp_path / "d.npz"), "--host", "0.0.0.0"]) == 0
    assert calls == ["127.0.0.1", "0.0.0.0"]
    assert "warning: listening on 0.0.0.0" in capsys.readouterr().err


def test_a_wrong_folder_points_to_the_right_one(tmp_path, capsys):
    from nerfkit.cli import main

    capture = tmp_path / "my_object"
    (capture / "dataset").mkdir(parents=True)
    (capture / "dataset" / "dataset.npz").write_bytes(b"")
    (capture / "dataset" / "poses.json").write_text("{}")
    (capture / "run").mkdir()
    (capture / "run" / "config.json").write_text("{}")
    photos = tmp_path / "photos"
    photos.mkdir()
    (photos / "IMG_1.JPG").write_bytes(b"x")
    run = tmp_path / "runs" / "mine"  # a trained run: its plots are not photos
    (run / "plots").mkdir(parents=True)
    (run / "plots" / "psnr.png").write_bytes(b"x")
    (run / "model.pt").write_bytes(b"x")
    (run / "config.json").write_text(json.dumps({"train": {"data": "/data/lego.npz"}}))
    killed = tmp_path / "runs" / "killed"  # stopped before its first checkpoint: its config alone
    killed.mkdir()
    (killed / "config.json").write_text(json.dumps({"train": {"data": "/data/lego.npz"}}))
    cases = [
        (
            ["view", str(killed), "--png", str(tmp_path / "v.png")],
            "a run's folder whose training stopped before its first checkpoint, so it holds no model: "
            f"train it again with `nerfkit train --config {killed / 'config.json'} --out NEW_RUN`",
        ),
        (
            ["train", "--data", str(capture), "--steps", "1", "--out", str(tmp_path / "r")],
            f"its dataset is {capture / 'dataset'}",
        ),
        (
            ["train", "--data", str(capture / "dataset" / "poses.json"), "--steps", "1", "--out", str(tmp_path / "r")],
            f"not the dataset. Give {capture / 'dataset' / 'dataset.npz'}",
        ),
        (
            ["train", "--data", str(photos), "--steps", "1", "--out", str(tmp_path / "r")],
            f"`nerfkit poses {photos} --out DATASET`",
        ),
        (["render", str(capture)], f"is a capture's folder, not a run. Its NeRF is {capture / 'run'}"),
        (
            ["train", "--data", str(run), "--steps", "1", "--out", str(tmp_path / "r")],
            f"a trained run's folder trained on /data/lego.npz: pass that dataset, or continue the run with "
            f"`nerfkit train --resume {run}`",
        ),
        (["convert", str(run), "--to", str(tmp_path / "r")], "a trained run's folder"),
        (["eval", str(run / "model.pt")], f"is a file of a run, not the run. Give its folder: {run}"),
        (
            ["eval", str(capture / "dataset" / "dataset.npz")],
            "is a file, not a run folder. Give the --out folder of a `nerfkit train` run (this looks like a dataset",
        ),
    ]
    for argv, hint in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert hint in err and err.count("\n") == 1, err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("flags", [["--device", "tpu"], ["--resolutions", "8,abc"], ["--stage-rays", "0"]])
def test_a_training_refused_at_start_leaves_no_empty_run_folder(tmp_path, sphere_npz, capsys, flags):
    from nerfkit.cli import main

    out = tmp_path / "runs" / "new"
    assert main(["train", "--data", str(sphere_npz), "--out", str(out), "--steps", "2", *flags]) == 2
    assert flags[0] in capsys.readouterr().err
    assert not out.exists()
    kept = tmp_path / "mine"
    kept.mkdir()  # a folder the user made is left as it was
    assert main(["train", "--data", str(sphere_npz), "--out", str(kept), "--steps", "2", *flags]) == 2
    assert kept.is_dir()


# ============================================================================= issue 66: the last holes


def _photos_with_a_link_outside(root: Path) -> tuple[Path, Path]:
    """``photos/`` holding a photo, a symlink to it (inside) and ``photo.png``, a symlink to
    ``private/secret.png`` (outside); returns (photos, secret)."""
    from PIL import Image

    photos, private = root / "photos", root / "private"
    photos.mkdir()
    private.mkdir()
    Image.new("RGB", (64, 48), (10, 20, 30)).save(photos / "a.png")
    Image.new("RGB", (64, 48), (200, 100, 50)).save(private / "secret.png")
    (photos / "b.png").symlink_to("a.png")  # a link to a photo of the folder: inside
    (photos / "photo.png").symlink_to(private / "secret.png")
    return photos, private / "secret.png"


@pytest.mark.parametrize(
    "command",
    [
        ["poses", "PHOTOS", "--focal-px", "500", "--tag-size", "0.05", "--method", "tags", "--out", "OUT"],
        ["poses", "PHOTOS", "--method", "colmap", "--out", "OUT"],
        ["calibrate", "PHOTOS", "--tag-size", "0.05", "--out", "OUT/camera.json"],
        ["capture", "PHOTOS", "--tag-size", "0.05", "--out", "OUT"],
    ],
    ids=["poses-tags", "poses-colmap", "calibrate", "capture"],
)
def test_a_photo_symlinked_to_a_file_outside_the_folder_is_never_read(tmp_path, capsys, monkeypatch, command):
    import nerfkit.capture.photos as photos_mod

    photos, _ = _photos_with_a_link_outside(tmp_path)
    out = tmp_path / "out"
    read = []
    loader = photos_mod.load_image_uint8
    monkeypatch.setattr(photos_mod, "load_image_uint8", lambda p, *a, **k: read.append(Path(p)) or loader(p, *a, **k))
    argv = [str(photos) if a == "PHOTOS" else a.replace("OUT", str(out)) for a in command]
    assert main(argv) == 2
    one_line(capsys, "photo.png", "outside the photo folder", "copy the photo into the folder")
    assert not read and not out.exists()  # refused before any photo is read or anything written


def test_the_photo_listing_applies_the_dataset_rule_to_symlinks(tmp_path):
    from nerfkit.images import list_images
    from nerfkit.io.paths import resolve_inside

    photos, secret = _photos_with_a_link_outside(tmp_path)
    with pytest.raises(NerfkitError) as e:
        list_images(photos)
    one_line_error(e, str(photos / "photo.png"), f"a symlink to {secret.resolve()}")
    assert [p.name for p in list_images(photos, allow_outside=True)] == ["a.png", "b.png", "photo.png"]
    (photos / "photo.png").unlink()
    assert [p.name for p in list_images(photos)] == ["a.png", "b.png"]  # a link inside the folder is a photo
    with pytest.raises(NerfkitError, match="--allow-outside-paths"):  # the datasets' rule, the same function
        resolve_inside(photos, "../private/secret.png")


def _dataset_folder(root: Path) -> Path:
    """``root/ds`` as ``nerfkit poses`` leaves it: the npz beside its images/ and transforms.json."""
    from nerfkit.data.npz import save_npz
    from nerfkit.data.synthetic import sphere_scene

    ds = root / "ds"
    (ds / "images").mkdir(parents=True)
    save_npz(sphere_scene(n_train=3, n_val=1, size=8), ds / "scene.npz")
    (ds / "transforms.json").write_text("{}")
    return ds


TRAIN_TINY = ["--steps", "2", *tiny_vanilla(samples=4, width=8, batch_rays=16)]


@pytest.mark.parametrize(
    "data, out",
    [
        ("ds/scene.npz", "ds/run"),
        ("ds/scene.npz", "ds/images/run"),
        ("ds", "ds/run"),
    ],
)
def test_a_run_is_never_written_inside_its_datasets_folder(tmp_path, capsys, data, out):
    ds = _dataset_folder(tmp_path)
    before = {p: p.stat().st_mtime_ns for p in ds.rglob("*")}
    assert main(["train", "--data", str(tmp_path / data), "--out", str(tmp_path / out), *TRAIN_TINY]) == 2
    one_line(capsys, "the folder of the dataset", "Choose an --out outside")
    assert {p: p.stat().st_mtime_ns for p in ds.rglob("*")} == before  # nothing written, not even a lock


def test_which_folder_is_a_datasets_own(tmp_path):
    from nerfkit.io.paths import dataset_folder, guard_run_folder

    ds = _dataset_folder(tmp_path)
    assert dataset_folder(ds / "scene.npz") == ds and dataset_folder(ds) == ds
    assert dataset_folder(ds / "transforms.json") == ds  # its images lie beside it
    assert dataset_folder(tmp_path / "nothing.npz") is None
    work = tmp_path / "work"  # `nerfkit train --data scene.npz --out runs/mine`, as the README starts
    work.mkdir()
    shutil.copy(ds / "scene.npz", work / "scene.npz")
    assert dataset_folder(work / "scene.npz") is None
    guard_run_folder(work / "runs" / "mine", work / "scene.npz")  # an npz alone among other files: allowed
    guard_run_folder(tmp_path / "runs" / "x", ds / "scene.npz")
    with pytest.raises(NerfkitError) as e:
        guard_run_folder(ds / "sub" / "run", ds / "scene.npz")
    one_line_error(e, "is inside", "the folder of the dataset")
    with pytest.raises(NerfkitError, match="holds the input"):
        guard_run_folder(work, work / "scene.npz")  # (a run there could replace it)


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--far", "1e308"], "1e308 is larger than a dataset file holds"),
        (["--far", "1e39"], "1e39 is larger than a dataset file holds"),
        (["--near", "1e-320", "--far", "6"], "1e-320 is smaller than a dataset file holds"),
        (["--near", "1", "--far", "1.00000001"], "are one number in a dataset file"),
    ],
)
def test_convert_near_far_must_survive_the_files_float32(tmp_path, capsys, flags, message):
    from nerfkit.data.npz import save_npz
    from nerfkit.data.synthetic import sphere_scene

    src = tmp_path / "src.npz"
    save_npz(sphere_scene(n_train=3, n_val=1, size=8), src)
    out = tmp_path / "out.npz"
    assert main(["convert", str(src), "--to", str(out), *flags]) == 2
    one_line(capsys, message)
    assert not out.exists()
    assert main(["convert", str(src), "--to", str(out), "--near", "0", "--far", "3e38"]) == 0  # the largest it holds
    with np.load(out) as z:
        assert float(z["far"]) == pytest.approx(3e38, rel=1e-6) and np.isfinite(z["far"]) and float(z["near"]) == 0


def _run_cli(args, delay=None, sig=None, ignore_sigint=False, timeout=300):
    """``python -m nerfkit ARGS`` in a child; ``sig`` sent after ``delay`` seconds (again each
    0.3 s while it runs, when ``ignore_sigint``). Returns (exit code, stderr)."""
    import subprocess
    import sys
    import time

    def ignore():
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    proc = subprocess.Popen(
        [sys.executable, "-m", "nerfkit", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=ignore if ignore_sigint else sigint_as_a_terminal_gives_it,
    )  # noqa: PLW1509
    try:
        if sig is not None:
            time.sleep(delay)
            proc.send_signal(sig)
            while ignore_sigint and proc.poll() is None:
                time.sleep(0.3)
                proc.send_signal(sig)
        _, err = proc.communicate(timeout=timeout)
    finally:
        proc.kill()
    return proc.returncode, err


SIGNAL_AT_TORCH = """
import os, runpy, sys

SIG = int(sys.argv[1])

class SignalAtTorch:  # sends the signal to this process as torch's import begins
    def find_spec(self, name, path=None, target=None):
        if name == "torch":
            sys.meta_path.remove(self)
            os.kill(os.getpid(), SIG)

sys.meta_path.insert(0, SignalAtTorch())
sys.argv = ["nerfkit", *sys.argv[2:]]
runpy.run_module("nerfkit", run_name="__main__")  # python -m nerfkit ARGS
"""


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_signal_during_start_up_is_one_line_and_exit_130(tmp_path, sphere_npz, sig):
    # The signal comes as torch's import begins: inside start-up, every time (a KeyboardInterrupt
    # traceback and death by the signal, once). It waits for the imports to end, then either
    # stops the command there (one line) or, when start-up ran on in imports until the trainer
    # took the stop over, the run stops at step 0, saved and reported (which of the two depends
    # on how long start-up spends outside imports). Both exit 130 without a traceback.
    import subprocess
    import sys

    driver = tmp_path / "driver.py"
    driver.write_text(SIGNAL_AT_TORCH)
    run = tmp_path / "run"
    args = ["train", "--data", str(sphere_npz), "--out", str(run), "--steps", "100000", *TRAIN_TINY[2:]]
    proc = subprocess.run(
        [sys.executable, str(driver), str(int(sig)), *args],
        capture_output=True,
        text=True,
        timeout=300,
        preexec_fn=sigint_as_a_terminal_gives_it,  # noqa: PLW1509
    )
    err = proc.stderr
    assert proc.returncode == 130 and "Traceback" not in err, err
    if (run / "metrics.json").exists():  # the trainer took the stop: saved whole, and said so
        assert json.loads((run / "metrics.json").read_text())["step"] == 0
        assert (run / "model.pt").exists() and (run / "plots" / "loss.png").exists(), sorted(os.listdir(run))
        assert "interrupted: checkpoint saved at step 0" in err, err
    else:  # stopped before the trainer
        assert err.strip() == "nerfkit train: interrupted", err


@pytest.mark.slow
def test_a_sigint_ignored_by_the_parent_stays_ignored(tmp_path, sphere_npz):
    # nohup, or a script's background job: SIGINT is ignored, and training must not take it back
    run = tmp_path / "run"
    code, err = _run_cli(
        ["train", "--data", str(sphere_npz), "--out", str(run), "--steps", "30", *TRAIN_TINY[2:]],
        delay=0.3,
        sig=signal.SIGINT,
        ignore_sigint=True,
    )
    assert code == 0, err
    assert "interrupted" not in err and "Traceback" not in err
    assert json.loads((run / "metrics.json").read_text())["finished"] and (run / "model.pt").exists()


def test_an_interrupted_run_reports_no_psnr_of_an_earlier_step(tmp_path, sphere_npz, capsys, monkeypatch):
    # stopped at step 5 of 1000, the last evaluation was step 0's: it is not the saved model's
    from nerfkit.train import trainer as trainer_mod

    if signal.getsignal(signal.SIGTERM) is signal.SIG_IGN:
        pytest.skip("SIGTERM is ignored here")
    step = trainer_mod.Trainer.train_step
    calls = []

    def stopped_every_5(self):
        calls.append(1)
        if len(calls) % 5 == 0:
            os.kill(os.getpid(), signal.SIGTERM)  # as `kill` or Ctrl-C: the step finishes, then the save
        return step(self)

    monkeypatch.setattr(trainer_mod.Trainer, "train_step", stopped_every_5)
    run = tmp_path / "run"
    flags = ["--eval-every", "100000", "--checkpoint-seconds", "100000"]
    assert (
        main(["train", "--data", str(sphere_npz), "--out", str(run), *TRAIN_TINY[2:], "--steps", "1000", *flags]) == 130
    )
    out, err = capsys.readouterr()
    assert "steps: 5" in out and "val PSNR" not in out, out
    assert "was not evaluated" in err and f"nerfkit eval {run}" in err
    rows = json.loads((run / "metrics.json").read_text())["rows"]
    assert [r["step"] for r in rows if r["split"] == "val"] == [0]  # the stale figure is there, and not reported
    assert main(["train", "--resume", str(run)]) == 130  # and again on resume
    out, err = capsys.readouterr()
    assert "steps: 10" in out and "val PSNR" not in out, out


@pytest.mark.parametrize(
    "quaternion, message",
    [
        ("0 0 0 0", "which is zero: no rotation at all"),
        ("0 0 0 0.0", "which is zero"),
        ("nan 0 0 1", "which is not finite"),
        ("1e400 0 0 0", "which is not finite"),
    ],
)
def test_a_colmap_text_quaternion_without_a_direction_is_refused_with_its_line(tmp_path, quaternion, message):
    from nerfkit.data.load import load_scene

    project = colmap_project(tmp_path, n=4)
    images = project / "sparse" / "0" / "images.txt"
    lines = images.read_text().splitlines()
    lines[4] = lines[4].replace("1 0 0 0", quaternion, 1)  # image 3 (lines: image, points, image, points, ...)
    images.write_text("# a comment line first, as COLMAP writes\n" + "\n".join(lines) + "\n")
    with pytest.raises(NerfkitError) as e:
        load_scene(project)
    one_line_error(e, f"{images}:6", "image 3 has the rotation quaternion", message)


def test_a_colmap_frames_txt_quaternion_of_zero_is_refused_with_its_line(tmp_path):
    import pycolmap

    from nerfkit.data.colmap import read_model

    project = colmap_project(tmp_path, n=3)
    model = project / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(model))
    rec.write_text(str(model))  # today's COLMAP layout: rigs.txt, frames.txt beside images.txt
    frames = model / "frames.txt"
    lines = frames.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("2 "))
    f = lines[i].split()
    lines[i] = " ".join(f[:2] + ["0", "0", "0", "0"] + f[6:])
    frames.write_text("\n".join(lines) + "\n")
    with pytest.raises(NerfkitError) as e:
        read_model(model)
    one_line_error(e, f"{frames}:{i + 1}", "frame 2 has the rotation quaternion 0 0 0 0", "zero")


def test_a_colmap_quaternion_of_another_length_is_normalised_as_colmap_does(tmp_path):
    from nerfkit.data.load import load_scene

    unit = load_scene(colmap_project(tmp_path / "unit", pose="0 1 0 0 {x} 0 4"))
    half = load_scene(colmap_project(tmp_path / "half", pose="0 0.5 0 0 {x} 0 4"))  # was: "not rigid"
    for a, b in zip(unit.splits.values(), half.splits.values()):
        np.testing.assert_allclose(a.c2w, b.c2w, atol=1e-6)
    np.testing.assert_allclose(unit.train.c2w[0, :3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-6)


def test_a_float_tiff_of_0_to_255_is_refused_not_clipped_to_a_silhouette(tmp_path, capsys):
    from PIL import Image

    from nerfkit.images import load_image, load_image_uint8

    values = np.array([[0.0, 64.0], [128.0, 255.0]], np.float32)
    Image.fromarray(values).save(tmp_path / "f.tif")
    for load in (load_image, load_image_uint8):
        with pytest.raises(NerfkitError) as e:
            load(tmp_path / "f.tif")
        one_line_error(e, "f.tif", "float pixels span [0, 255], expected [0, 1]", "divide 0-255 values by 255")
    assert main(["fit-image", str(tmp_path / "f.tif"), "--out", str(tmp_path / "fit"), "--steps", "1"]) == 2
    one_line(capsys, "expected [0, 1]")
    assert not (tmp_path / "fit").exists()
    Image.fromarray(values / 255.0).save(tmp_path / "g.tif")  # the same picture in 0-1 loads as it is
    np.testing.assert_allclose(load_image(tmp_path / "g.tif")[..., 0], values / 255.0, atol=1e-7)


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--depth", "100000000"], "--depth: 100000000 is above the maximum 64"),
        (["--width", "2000000000"], "--width: 2000000000 is above the maximum 8192"),
        (["--sweep", "depth=2,1000"], "1000 is above the maximum 64"),
    ],
)
def test_fit_image_model_size_is_bounded(tmp_path, capsys, flags, message):
    assert main(["fit-image", "--out", str(tmp_path / "fit"), "--steps", "1", *flags]) == 2
    one_line(capsys, message)
    assert not (tmp_path / "fit").exists()


def test_fit_image_memory_messages_name_the_flag_that_matters(tmp_path, capsys, monkeypatch):
    import nerfkit.fields.image_field as field_mod
    import nerfkit.fit_image as fit_mod

    out = tmp_path / "fit"
    monkeypatch.setattr(fit_mod, "memory_bytes", lambda device: 1 << 30)  # a 1 GB machine
    assert fit_mod.model_bytes(10, 256, 3) == 16 * (43 * 256 + 2 * 257 * 256 + 257 * 3)
    assert main(["fit-image", "--out", str(out), "--steps", "1", "--width", "8192", "--depth", "4"]) == 2
    one_line(capsys, "--width/--depth", "more than this machine's 1.07 GB", "Lower --width or --depth")
    assert main(["fit-image", "--out", str(out), "--steps", "1", "--batch", "16000000"]) == 2
    one_line(capsys, "--batch", "Lower --batch")
    assert not out.exists()
    monkeypatch.setattr(fit_mod, "memory_bytes", lambda device: None)  # unknown: PyTorch's own failure, then

    def no_memory(self, *a, **k):
        raise RuntimeError(
            "[enforce fail at alloc_cpu.cpp:127] DefaultCPUAllocator: can't allocate memory: you "
            "tried to allocate 274877906944 bytes. Error code 12"
        )

    monkeypatch.setattr(field_mod.ImageField, "__init__", no_memory)
    assert main(["fit-image", "--out", str(out), "--steps", "1", "--width", "8192"]) == 2
    one_line(capsys, "out of memory", "--width and --depth")


def test_convert_force_never_takes_a_users_folder_for_its_leftover(tmp_path):
    from nerfkit.data.npz import save_npz
    from nerfkit.data.synthetic import sphere_scene

    src = tmp_path / "src.npz"
    save_npz(sphere_scene(n_train=3, n_val=1, size=8), src)
    out = tmp_path / "out"
    assert main(["convert", str(src), "--to", str(out)]) == 0
    mine = out / ".images.replaced"  # the name nerfkit once took for the images it replaces
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    names = sorted(os.listdir(out))
    assert main(["convert", str(src), "--to", str(out), "--force"]) == 0
    assert (mine / "notes.txt").read_text() == "mine"
    assert sorted(os.listdir(out)) == names  # and no leftover of nerfkit's own beside it


def test_a_stop_swallowed_by_an_import_during_start_up_still_stops_training(tmp_path, sphere_npz, monkeypatch, capsys):
    # the SIGTERM handler raised KeyboardInterrupt inside an import that caught it (a bare
    # except): the stop it remembered must still stop the run at its first step, saved
    from nerfkit.cli import _interrupt
    from nerfkit.train import trainer as trainer_mod

    build = trainer_mod.Trainer.__init__

    def start_up_then_swallowed_stop(self, *a, **k):
        build(self, *a, **k)
        with contextlib.suppress(KeyboardInterrupt):  # what the import did
            _interrupt(signal.SIGTERM, None)

    monkeypatch.setattr(trainer_mod.Trainer, "__init__", start_up_then_swallowed_stop)
    run = tmp_path / "run"
    argv = ["train", "--data", str(sphere_npz), "--out", str(run), "--steps", "1000", *TRAIN_TINY[2:]]
    assert main(argv) == 130
    assert "interrupted" in capsys.readouterr().err
    assert json.loads((run / "metrics.json").read_text())["step"] == 0
    monkeypatch.setattr(trainer_mod.Trainer, "__init__", build)  # a later command is not stopped by it
    assert main([*argv[:4], str(tmp_path / "run2"), *TRAIN_TINY]) == 0


EMPTY_OUTPUTS = [
    ["train", "--data", "scene.npz", "--steps", "1", "--out", ""],
    ["convert", "scene.npz", "--to", " "],
    ["calibrate", "sheet", "--tag-size", "0.05", "--out", ""],
    ["poses", "photos", "--tag-size", "0.05", "--out", ""],
    ["capture", "photos", "--tag-size", "0.05", "--out", ""],
    ["frames", "clip.mp4", "--out", ""],
    ["render", "run", "--out", ""],
    ["export", "run", "--points", ""],
    ["fit-image", "photo.jpg", "--out", ""],
    ["tags", "--out", ""],
    ["dataset", "ds", "--out", ""],
]


@pytest.mark.parametrize("argv", EMPTY_OUTPUTS, ids=[a[0] for a in EMPTY_OUTPUTS])
def test_an_empty_output_path_is_refused_before_anything_is_read_or_written(tmp_path, monkeypatch, capsys, argv):
    """``--out ""`` (an unset shell variable) would write into the current folder."""
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    flag = next(a for a in argv if a in ("--out", "--to", "--points"))
    assert capsys.readouterr().err.strip() == f"nerfkit {argv[0]}: error: {flag} is empty: give the path to write"
    assert list(tmp_path.iterdir()) == []


def test_the_api_refuses_an_empty_output_path(tmp_path, monkeypatch):
    from nerfkit import api

    monkeypatch.chdir(tmp_path)
    for call in (
        lambda: api.train("scene.npz", "", steps=1),
        lambda: api.calibrate("sheet", " ", tag_size=0.05),
        lambda: api.pose("photos", "", tag_size=0.05),
        lambda: api.render("run", out=""),
        lambda: api.export("run", mesh=""),
        lambda: api.capture("photos", ""),
    ):
        with pytest.raises(NerfkitError, match="is empty: give the path to write"):
            call()
    assert list(tmp_path.iterdir()) == []


def test_eval_on_another_dataset_says_so_and_capture_does_not_keep_those_scores(tiny_run, tmp_path, capsys):
    """``eval --data`` of another scene scores it (a user may mean to) but says it is not the
    run's dataset and records so; ``capture`` then scores the run again instead of keeping them."""
    from nerfkit import api
    from nerfkit.commands.stages.capture import _on_own_dataset
    from nerfkit.data.npz import save_npz
    from nerfkit.data.synthetic import sphere_scene

    run = edited_run(tiny_run, tmp_path)
    save_npz(sphere_scene(n_train=5, n_val=1, size=8), tmp_path / "other.npz")
    other = api.evaluate(run, data=tmp_path / "other.npz", device="cpu")
    assert (
        "is not the dataset the run was trained on (views, poses, train_images, intrinsics differ)"
        in capsys.readouterr().out
    )
    assert other.scores["runs_own_dataset"] is False and not _on_own_dataset(other.report_path)
    own = api.evaluate(run, device="cpu", quiet=True)
    assert own.scores["runs_own_dataset"] is True and _on_own_dataset(own.report_path)
    # the other dataset's scores are written beside the run's own, which they never replace
    assert other.report_path == run / "eval_val_other.json" and own.report_path == run / "eval_val.json"
    api.evaluate(run, data=tmp_path / "other.npz", device="cpu", quiet=True)
    assert json.loads(own.report_path.read_text())["runs_own_dataset"] is True
