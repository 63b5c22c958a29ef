"""Property-based fuzzing of every loader (issue 6, hostile and broken inputs).

Each test throws random malformed inputs at one loader: mutated course npz files, broken
image files, camera and layout JSON, transforms.json, Blender folders, COLMAP models (text
and binary), run config.json and checkpoints. The property is always the same: the loader
either returns something valid (finite rigid poses, positive focal lengths, near < far,
uint8 images of the declared shape, ...) or raises :class:`NerfkitError` with one line.
Any other exception is a bug.

The examples are derandomised, so the suite is repeatable. For a deeper run::

    NERFKIT_FUZZ_SCALE=20 NERFKIT_FUZZ_RANDOM=1 python -m pytest tests/test_fuzz_loaders.py

(``SCALE`` multiplies every example count; ``RANDOM`` draws new examples each run.)
Every example writes into its own temporary folder; no test reads ``../shared``.
"""

from __future__ import annotations

import copy
import io
import json
import math
import os
import shutil
import struct
import tempfile
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from conftest import tiny_vanilla_configs
from nerfkit.errors import NerfkitError

SCALE = float(os.environ.get("NERFKIT_FUZZ_SCALE", "1"))
RANDOM = os.environ.get("NERFKIT_FUZZ_RANDOM", "") not in ("", "0")


def fuzz(n: int):
    """Hypothesis settings for one loader: n examples (times NERFKIT_FUZZ_SCALE), no deadline."""
    return settings(
        max_examples=max(1, int(n * SCALE)),
        deadline=None,
        derandomize=not RANDOM,
        database=None,
        suppress_health_check=list(HealthCheck),
        print_blob=True,
    )


@contextmanager
def scratch():
    """A fresh folder per example (hypothesis runs many examples in one test call)."""
    d = tempfile.mkdtemp(prefix="nerfkit-fuzz-")
    try:
        yield Path(d)
    finally:
        shutil.rmtree(d, ignore_errors=True)


def attempt(fn, *args, **kwargs):
    """Run a loader: its result, or None after checking the NerfkitError is one clear line.

    Anything else propagates and fails the test: that is the bug the fuzz looks for.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numpy overflow warnings, "undistorted on load", ...
        try:
            return fn(*args, **kwargs)
        except NerfkitError as e:
            msg = str(e)
            assert msg.strip(), "empty error message"
            assert "\n" not in msg and "\r" not in msg, f"error spans lines: {msg!r}"
            assert "Traceback" not in msg
            return None


# ----------------------------------------------------------------------------- what "valid" means


def assert_valid_views(v, split: str) -> None:
    n = len(v)
    assert isinstance(v.width, (int, np.integer)) and isinstance(v.height, (int, np.integer))
    assert v.width > 0 and v.height > 0, f"{split}: size {v.width}x{v.height}"
    assert v.c2w.shape == (n, 4, 4) and v.c2w.dtype == np.float32
    assert v.K.shape == (n, 3, 3) and v.K.dtype == np.float32
    if n == 0:
        return
    c2w = v.c2w.astype(np.float64)
    assert np.isfinite(c2w).all(), f"{split}: non-finite pose"
    np.testing.assert_allclose(c2w[:, 3], np.tile([0, 0, 0, 1.0], (n, 1)), atol=1e-2, err_msg=split)
    R = c2w[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.tile(np.eye(3), (n, 1, 1)), atol=2e-2, err_msg=split)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=2e-2, err_msg=split)
    assert np.isfinite(v.K).all(), f"{split}: non-finite K"
    assert (v.K[:, 0, 0] > 0).all() and (v.K[:, 1, 1] > 0).all(), f"{split}: focal {v.K[:, 0, 0]}"
    if v.images is not None and v.images.size:
        assert v.images.dtype == np.uint8
        assert v.images.shape == (n, v.height, v.width, 3), (split, v.images.shape)
    if v.names is not None:
        assert len(v.names) == n and all(isinstance(s, str) for s in v.names)


def assert_valid_scene(scene) -> None:
    assert len(scene.train) > 0
    for split, v in scene.splits.items():
        assert_valid_views(v, split)
    assert math.isfinite(scene.near) and math.isfinite(scene.far), (scene.near, scene.far)
    assert 0 <= scene.near < scene.far, (scene.near, scene.far)
    center, up = np.asarray(scene.center, np.float64), np.asarray(scene.up, np.float64)
    assert center.shape == (3,) and np.isfinite(center).all(), center
    assert up.shape == (3,) and np.isfinite(up).all() and abs(np.linalg.norm(up) - 1) < 1e-3, up


# ----------------------------------------------------------------------------- shared strategies

SPECIAL_FLOATS = [
    0.0,
    -0.0,
    1.0,
    -1.0,
    0.5,
    2.0,
    255.0,
    256.0,
    -1e-30,
    1e-30,
    1e15,
    1e30,
    1e300,
    -1e300,
    float("nan"),
    float("inf"),
    float("-inf"),
    3.141592653589793,
]
special = st.sampled_from(SPECIAL_FLOATS)
small_float = st.floats(-10, 10, allow_nan=False)
any_float = st.one_of(special, st.floats(allow_nan=True, allow_infinity=True), small_float)
json_scalar = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**20), 10**20),
    st.sampled_from([0, -1, 1, 3, 4]),
    any_float,
    st.text(max_size=6),
)
json_value = st.recursive(
    json_scalar, lambda c: st.lists(c, max_size=5) | st.dictionaries(st.text(max_size=4), c, max_size=4), max_leaves=16
)


def number_matrix(rows: int, cols: int):
    """A rows x cols list of numbers, or a near miss (ragged, wrong shape, strings, specials)."""
    good = st.lists(st.lists(any_float, min_size=cols, max_size=cols), min_size=rows, max_size=rows)
    return st.one_of(good, json_value, st.lists(st.lists(any_float, max_size=cols + 1), max_size=rows + 1))


def rigid_pose(quat, t):
    """A 4x4 camera-to-world from a (not necessarily unit) quaternion and a translation."""
    q = np.asarray(quat, np.float64)
    n = np.linalg.norm(q)
    w, x, y, z = q / n if n > 1e-9 else (1.0, 0.0, 0.0, 0.0)
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = R, t
    return m


quaternions = st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4)
translations = st.lists(st.one_of(st.floats(-10, 10, allow_nan=False), special), min_size=3, max_size=3)
random_pose = st.builds(rigid_pose, quaternions, translations)


def corrupt_bytes(data: bytes, draw) -> bytes:
    """Truncate, overwrite, insert or delete bytes of a file."""
    b = bytearray(data)
    kind = draw(st.sampled_from(["truncate", "overwrite", "insert", "delete", "zero_tail"]))
    if not b:
        return bytes(b)
    i = draw(st.integers(0, len(b) - 1))
    if kind == "truncate":
        return bytes(b[:i])
    if kind == "overwrite":
        for j in range(draw(st.integers(1, 8))):
            k = (i + j * draw(st.integers(1, 97))) % len(b)
            b[k] = draw(st.integers(0, 255))
    elif kind == "insert":
        b[i:i] = draw(st.binary(min_size=1, max_size=16))
    elif kind == "delete":
        del b[i : i + draw(st.integers(1, 16))]
    else:
        b[i:] = bytes(len(b) - i)
    return bytes(b)


# ============================================================================= course npz

NPZ_KEYS = [
    "images_train",
    "c2ws_train",
    "images_val",
    "c2ws_val",
    "c2ws_test",
    "focal",
    "K",
    "near",
    "far",
    "center",
    "up",
    "names_train",
    "names_val",
    "extra",
]
DTYPES = [
    np.uint8,
    np.int16,
    np.int64,
    np.uint64,
    np.float16,
    np.float32,
    np.float64,
    np.bool_,
    np.complex64,
    np.dtype("<U3"),
    np.dtype("S2"),
]


def course_arrays(n=3, size=6):
    rng = np.random.default_rng(0)
    c2w = np.tile(np.eye(4, dtype=np.float32), (n, 1, 1))
    c2w[:, :3, 3] = rng.normal(size=(n, 3)) * 0.3 + [0, 0, 4]
    return {
        "images_train": rng.integers(0, 255, (n, size, size, 3), dtype=np.uint8),
        "c2ws_train": c2w,
        "images_val": rng.integers(0, 255, (2, size, size, 3), dtype=np.uint8),
        "c2ws_val": c2w[:2].copy(),
        "c2ws_test": c2w[:3].copy(),
        "focal": np.float32(10.0),
    }


weird_arrays = hnp.arrays(
    dtype=st.sampled_from(DTYPES), shape=hnp.array_shapes(min_dims=0, max_dims=5, min_side=0, max_side=4)
)


@st.composite
def npz_mutation(draw):
    """One change to a valid course npz."""
    kind = draw(
        st.sampled_from(
            ["drop", "replace", "poke", "scale", "poses", "near_far", "focal", "K", "vector", "float_images", "shaped"]
        )
    )
    key = draw(st.sampled_from(NPZ_KEYS))
    if kind in ("drop", "replace"):
        return kind, key, draw(weird_arrays) if kind == "replace" else None
    if kind == "poke":
        return kind, key, (draw(st.integers(0, 10**6)), draw(special))
    if kind == "scale":
        return (
            kind,
            draw(st.sampled_from(["c2ws_train", "c2ws_val", "c2ws_test"])),
            (draw(st.integers(0, 2)), draw(st.sampled_from([0.0, -1.0, 0.5, 1.01, 2.0, 1e-8]))),
        )
    if kind == "poses":  # rigid poses anywhere: does the scene estimation cope?
        n = draw(st.integers(1, 3))
        return (
            kind,
            draw(st.sampled_from(["c2ws_train", "c2ws_val", "c2ws_test"])),
            draw(st.lists(random_pose, min_size=n, max_size=n)),
        )
    if kind == "near_far":
        return kind, None, (draw(st.one_of(special, small_float)), draw(st.one_of(special, small_float)))
    if kind == "focal":
        return kind, None, draw(st.one_of(special, small_float))
    if kind == "K":
        return (
            kind,
            None,
            draw(
                hnp.arrays(
                    np.float64,
                    st.sampled_from([(3, 3), (3, 3, 3), (2, 3, 3), (1, 3, 3)]),
                    elements=st.one_of(special, small_float),
                )
            ),
        )
    if kind == "vector":
        return (
            kind,
            draw(st.sampled_from(["center", "up"])),
            draw(hnp.arrays(np.float64, st.integers(0, 4), elements=st.one_of(special, small_float))),
        )
    if kind == "float_images":
        return kind, draw(st.sampled_from(["images_train", "images_val"])), draw(st.one_of(special, small_float))
    # "shaped": right shape, random (often non-finite) contents
    target = draw(st.sampled_from(["c2ws_train", "c2ws_val", "images_train", "images_val"]))
    return kind, target, draw(st.sampled_from(DTYPES[:7])), draw(st.integers(0, 2**32 - 1))


def apply_npz_mutation(a: dict, m) -> None:
    kind, key = m[0], m[1]
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        if kind == "drop":
            a.pop(key, None)
        elif kind == "replace":
            a[key] = m[2]
        elif kind == "poke":
            if key in a and np.asarray(a[key]).size:
                arr = np.array(a[key])
                idx, value = m[2]
                try:
                    arr.reshape(-1)[idx % arr.size] = np.array(value).astype(arr.dtype)
                except (ValueError, TypeError, OverflowError):
                    return
                a[key] = arr
        elif kind == "scale":
            if key in a:
                arr = np.array(a[key], np.float64)
                i, f = m[2]
                if arr.ndim == 3 and arr.shape[0] > i:
                    arr[i, :3, :3] *= f
                    a[key] = arr
        elif kind == "poses":
            a[key] = np.stack(m[2])
        elif kind == "near_far":
            a["near"], a["far"] = np.float64(m[2][0]), np.float64(m[2][1])
        elif kind == "focal":
            a["focal"] = np.float64(m[2])
        elif kind == "K":
            a["K"] = m[2]
        elif kind == "vector":
            a[key] = m[2]
        elif kind == "float_images":
            if key in a:
                img = a[key].astype(np.float64) / 255.0
                img.reshape(-1)[0] = m[2]
                a[key] = img
        else:
            dtype, seed = m[2], m[3]
            if key in a:
                rng = np.random.default_rng(seed)
                a[key] = (rng.normal(size=a[key].shape) * rng.choice([1, 100, 1e20])).astype(dtype)


@fuzz(200)
@given(mutations=st.lists(npz_mutation(), min_size=1, max_size=3))
def test_npz_random_mutations_load_valid_or_fail_cleanly(mutations):
    from nerfkit.data.npz import load_npz

    arrays = course_arrays()
    for m in mutations:
        apply_npz_mutation(arrays, m)
    with scratch() as d:
        path = d / "scene.npz"
        np.savez(path, **arrays)
        scene = attempt(load_npz, path)
        if scene is not None:
            assert_valid_scene(scene)
            assert scene.train.images.shape[1:] == arrays["images_train"].shape[1:]


@fuzz(100)
@given(data=st.data())
def test_npz_corrupted_bytes_load_valid_or_fail_cleanly(data):
    from nerfkit.data.load import load_scene

    with scratch() as d:
        path = d / "scene.npz"
        savez = np.savez_compressed if data.draw(st.booleans()) else np.savez
        savez(path, **course_arrays())
        path.write_bytes(corrupt_bytes(path.read_bytes(), data.draw))
        scene = attempt(load_scene, path)
        if scene is not None:
            assert_valid_scene(scene)


# ============================================================================= image files

IMAGE_MODES = ["RGB", "RGBA", "L", "LA", "P", "1", "I;16", "I", "F", "CMYK"]
IMAGE_FORMATS = {"PNG": ".png", "JPEG": ".jpg", "WEBP": ".webp", "TIFF": ".tif", "BMP": ".bmp", "GIF": ".png"}


@st.composite
def image_file(draw):
    """(bytes, suffix, (h, w) or None when the bytes were corrupted)."""
    from PIL import Image

    h, w = draw(st.integers(1, 9)), draw(st.integers(1, 9))
    mode = draw(st.sampled_from(IMAGE_MODES))
    fmt = draw(st.sampled_from(sorted(IMAGE_FORMATS)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if mode == "F":
            img = Image.fromarray(rng.choice(np.array(SPECIAL_FLOATS, np.float32), size=(h, w)))
        elif mode in ("I;16", "I"):
            img = Image.fromarray(rng.integers(0, 65535, (h, w)).astype(np.uint16 if mode == "I;16" else np.int32))
        else:
            img = Image.fromarray(rng.integers(0, 256, (h, w, 4), dtype=np.uint8), "RGBA").convert(mode)
        buf = io.BytesIO()
        try:
            img.save(buf, fmt)
        except (OSError, ValueError, KeyError, TypeError):
            assume(False)
    data = buf.getvalue()
    suffix = draw(st.sampled_from([IMAGE_FORMATS[fmt], ".jpg", ".png", ".heic", ".tiff"]))
    if draw(st.booleans()):
        return corrupt_bytes(data, draw), suffix, None
    return data, suffix, (h, w)


@fuzz(200)
@given(item=image_file(), background=st.sampled_from([(0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (0.2, 0.5, 0.9)]))
def test_image_files_load_as_declared_or_fail_cleanly(item, background):
    from nerfkit.images import load_image, load_image_uint8

    data, suffix, shape = item
    with scratch() as d:
        path = d / f"photo{suffix}"
        path.write_bytes(data)
        u8 = attempt(load_image_uint8, path, background)
        f32 = attempt(load_image, path, background)
    assert (u8 is None) == (f32 is None)
    if u8 is None:
        return
    assert u8.dtype == np.uint8 and u8.ndim == 3 and u8.shape[2] == 3 and u8.shape[0] > 0 and u8.shape[1] > 0
    assert f32.dtype == np.float32 and f32.shape == u8.shape
    assert np.isfinite(f32).all() and f32.min() >= 0 and f32.max() <= 1
    if shape is not None:
        assert u8.shape == (*shape, 3)


@fuzz(60)
@given(data=st.binary(max_size=64), suffix=st.sampled_from([".jpg", ".png", ".heic", ".webp", ".tif", ".bmp"]))
def test_random_bytes_are_not_images(data, suffix):
    from nerfkit.images import load_image_uint8

    with scratch() as d:
        (d / f"x{suffix}").write_bytes(data)
        img = attempt(load_image_uint8, d / f"x{suffix}")
        assert img is None or (img.dtype == np.uint8 and img.ndim == 3)


# ============================================================================= camera files

GOOD_CAMERA = {
    "K": [[1000.0, 0, 640], [0, 1000.0, 480], [0, 0, 1]],
    "dist": [0.01, -0.02, 0, 0, 0],
    "width": 1280,
    "height": 960,
    "rms": 0.3,
}


@st.composite
def camera_json(draw):
    d = copy.deepcopy(GOOD_CAMERA)
    for _ in range(draw(st.integers(1, 3))):
        key = draw(st.sampled_from(["K", "dist", "width", "height", "rms", "dictionary"]))
        kind = draw(st.sampled_from(["drop", "value", "numbers"]))
        if kind == "drop":
            d.pop(key, None)
        elif kind == "value":
            d[key] = draw(json_value)
        elif key == "K":
            d[key] = draw(number_matrix(3, 3))
        elif key == "dist":
            d[key] = draw(st.lists(any_float, max_size=15))
        else:
            d[key] = draw(st.one_of(any_float, st.integers(-(10**30), 10**30)))
    if draw(st.integers(0, 9)) == 0:
        return draw(json_value)
    return d


def dump_json(obj) -> str:
    return json.dumps(obj, allow_nan=True)


@pytest.mark.slow
@fuzz(150)
@given(spec=camera_json())
@example(spec={**GOOD_CAMERA, "width": float("inf")})  # found by the fuzz: OverflowError
@example(spec={**GOOD_CAMERA, "K": [[1000.0, 0, 640], [0, 1000.0, 480], [5, 0, 7]]})  # loads, bottom row ignored
def test_camera_files_load_valid_or_fail_cleanly(spec):
    from nerfkit.capture.camera import load_camera

    with scratch() as d:
        path = d / "camera.json"
        path.write_text(dump_json(spec))
        cam = attempt(load_camera, path)
    if cam is None:
        return
    K = np.asarray(cam.K, np.float64)
    assert K.shape == (3, 3) and np.isfinite(K).all()
    assert K[0, 0] > 0 and K[1, 1] > 0
    np.testing.assert_allclose(K[2], [0, 0, 1])
    assert cam.dist.shape == (5,) and np.isfinite(cam.dist).all()
    assert isinstance(cam.width, int) and isinstance(cam.height, int)
    assert 0 < cam.width <= 100_000 and 0 < cam.height <= 100_000


# ============================================================================= layout files


@st.composite
def layout_json(draw):
    kind = draw(st.sampled_from(["tags", "tags", "grid", "charuco", "camera_file", "random"]))
    if kind == "random":
        return draw(json_value)
    count = st.one_of(st.sampled_from([-1, 0, 1, 2, 3, 5, 10**12]), any_float, json_scalar)
    length = st.one_of(st.sampled_from([0.04, 0.01, 0.0, -0.02]), any_float, json_scalar)
    if kind == "grid":
        spec = {
            "board": "grid",
            "markers_x": draw(count),
            "markers_y": draw(count),
            "marker_length": draw(length),
            "marker_separation": draw(length),
        }
    elif kind == "charuco":
        spec = {
            "board": "charuco",
            "squares_x": draw(count),
            "squares_y": draw(count),
            "square_length": draw(length),
            "marker_length": draw(length),
        }
    else:
        tags = {}
        for _ in range(draw(st.integers(0, 3))):
            tag_id = draw(st.one_of(st.integers(-3, 60).map(str), st.text(max_size=3)))
            if draw(st.booleans()):
                value = {
                    "center": draw(st.one_of(st.lists(any_float, max_size=4), json_value)),
                    "size": draw(st.one_of(length, st.just(0.05))),
                    "rotation_deg": draw(st.one_of(st.just(0), any_float, json_scalar)),
                }
                if draw(st.booleans()):
                    value.pop(draw(st.sampled_from(sorted(value))))
            else:
                value = draw(st.one_of(number_matrix(4, 3), st.just([[0, 0, 0], [1, 0, 0], [1, -1, 0], [0, -1, 0]])))
            tags[tag_id] = value
        spec = {"tags": tags}
        if draw(st.booleans()):
            spec["tag_size"] = draw(length)
    if kind != "tags" and draw(st.booleans()):
        spec["dictionary"] = draw(st.one_of(st.sampled_from(["DICT_4X4_50", "DICT_5X5_100", "NOPE"]), json_scalar))
    if kind == "camera_file":
        return {**GOOD_CAMERA, "layout": spec}
    return spec


@fuzz(150)
@given(spec=layout_json())
@example(spec={"tags": {"0": {"center": "ab", "size": 0.05}}})  # found by the fuzz: ValueError
def test_layout_files_load_valid_or_fail_cleanly(spec):
    from nerfkit.capture.aruco import load_layout

    with scratch() as d:
        path = d / "layout.json"
        path.write_text(dump_json(spec))
        layout = attempt(load_layout, path, "DICT_4X4_50", None)
    if layout is None:
        return
    assert layout.tags
    for tag_id, corners in layout.tags.items():
        assert isinstance(tag_id, int)
        c = np.asarray(corners, np.float64)
        assert c.shape == (4, 3) and np.isfinite(c).all(), (tag_id, c)
        sides = np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1)
        assert sides.min() > 0 and sides.max() / sides.min() < 1.1
    assert math.isfinite(layout.tag_size) and layout.tag_size > 0
    if layout.charuco is not None:
        assert np.isfinite(np.asarray(layout.charuco_corners)).all()


# ============================================================================= transforms.json

FRAME_KEYS = ["file_path", "transform_matrix", "split", "fl_x", "w", "h", "name", "camera_angle_x"]
TOP_KEYS = [
    "fl_x",
    "fl_y",
    "cx",
    "cy",
    "w",
    "h",
    "camera_angle_x",
    "k1",
    "k2",
    "k3",
    "k4",
    "p1",
    "p2",
    "camera_model",
    "frames",
    "train_filenames",
    "val_filenames",
    "nerfkit",
]
NK_KEYS = ["near", "far", "center", "up", "poses_only"]


def good_transforms(n=3):
    from nerfkit.cameras import opencv_to_opengl
    from nerfkit.data.synthetic import sphere_cameras

    c2w = sphere_cameras(n, seed=1).astype(np.float64)
    return {
        "camera_model": "OPENCV",
        "fl_x": 12.0,
        "fl_y": 12.0,
        "cx": 4.0,
        "cy": 3.0,
        "w": 8,
        "h": 6,
        "frames": [
            {
                "file_path": f"images/{i}.png",
                "transform_matrix": opencv_to_opengl(c2w[i]).tolist(),
                "split": "train" if i else "val",
            }
            for i in range(n)
        ],
        "nerfkit": {"near": 2.0, "far": 6.0, "center": [0, 0, 0], "up": [0, 0, 1]},
    }


def write_images(folder: Path, names, size=(8, 6), seed=0):
    from PIL import Image

    rng = np.random.default_rng(seed)
    for name in names:
        p = folder / name
        p.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(rng.integers(0, 256, (size[1], size[0], 4), dtype=np.uint8), "RGBA").save(p)


@st.composite
def transforms_mutation(draw):
    where = draw(st.sampled_from(["top", "top", "frame", "frame", "nerfkit", "pose", "image", "whole"]))
    if where == "whole":
        return where, None, draw(json_value)
    if where == "pose":
        return (
            where,
            draw(st.integers(0, 2)),
            draw(st.one_of(random_pose.map(lambda m: m.tolist()), number_matrix(4, 4), number_matrix(3, 4))),
        )
    if where == "image":
        return where, draw(st.integers(0, 2)), draw(st.sampled_from(["truncate", "text", "size", "delete"]))
    keys = {"top": TOP_KEYS, "frame": FRAME_KEYS, "nerfkit": NK_KEYS}[where]
    key = draw(st.sampled_from(keys))
    value = draw(
        st.one_of(
            json_value,
            any_float,
            st.just("__drop__"),
            st.lists(any_float, min_size=3, max_size=3),
            st.sampled_from(["train", "val", "test"]),
        )
    )
    return where, (key, draw(st.integers(0, 2))), value


def apply_transforms_mutation(d, folder: Path, m):
    where, key, value = m
    if where == "whole":
        return value
    if not isinstance(d, dict):
        return d
    frames = d.get("frames") if isinstance(d.get("frames"), list) else []
    if where == "pose":
        if key < len(frames) and isinstance(frames[key], dict):
            frames[key]["transform_matrix"] = value
    elif where == "image":
        p = folder / "images" / f"{key}.png"
        if p.exists():
            if value == "truncate":
                p.write_bytes(p.read_bytes()[:40])
            elif value == "text":
                p.write_text("not an image")
            elif value == "size":
                write_images(folder, [f"images/{key}.png"], size=(9, 6))
            else:
                p.unlink()
    else:
        name, i = key
        if where == "top":
            target = d
        elif where == "frame":
            target = frames[i] if i < len(frames) else None
        else:
            target = d.get("nerfkit")
        if isinstance(target, dict):
            if value == "__drop__":
                target.pop(name, None)
            else:
                target[name] = value
    return d


@fuzz(150)
@given(mutations=st.lists(transforms_mutation(), min_size=1, max_size=3))
@example(mutations=[("top", ("w", 0), 0.0)])  # found by the fuzz: ZeroDivisionError
def test_transforms_json_loads_valid_or_fails_cleanly(mutations):
    from nerfkit.data.load import load_scene

    with scratch() as folder:
        write_images(folder, [f"images/{i}.png" for i in range(3)])
        d = good_transforms()
        for m in mutations:
            d = apply_transforms_mutation(d, folder, m)
        (folder / "transforms.json").write_text(dump_json(d))
        scene = attempt(load_scene, folder)
    if scene is not None:
        assert_valid_scene(scene)


# ============================================================================= Blender folders


def make_blender(folder: Path, angle=0.69):
    from nerfkit.cameras import opencv_to_opengl
    from nerfkit.data.synthetic import sphere_cameras

    for split, n in (("train", 3), ("val", 1)):
        c2w = sphere_cameras(n, seed=len(split)).astype(np.float64)
        write_images(folder, [f"{split}/r_{i}.png" for i in range(n)], seed=n)
        frames = [
            {"file_path": f"./{split}/r_{i}", "transform_matrix": opencv_to_opengl(c2w[i]).tolist()} for i in range(n)
        ]
        (folder / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": angle, "frames": frames}))


@st.composite
def blender_mutation(draw):
    split = draw(st.sampled_from(["train", "train", "val"]))
    kind = draw(st.sampled_from(["angle", "pose", "pose", "frame_key", "frames", "image", "whole", "drop_file"]))
    if kind == "angle":
        return split, kind, draw(st.one_of(any_float, json_scalar, st.floats(0.01, 3.1)))
    if kind == "pose":
        return (
            split,
            kind,
            draw(st.one_of(random_pose.map(lambda m: m.tolist()), number_matrix(4, 4), number_matrix(3, 4))),
        )
    if kind == "frame_key":
        return (
            split,
            kind,
            (
                draw(st.sampled_from(["file_path", "transform_matrix"])),
                draw(
                    st.one_of(
                        json_value,
                        st.just("__drop__"),
                        st.sampled_from(["./train/r_9", "", "/", "a\x00b", "x" * 300, "\n"]),
                    )
                ),
            ),
        )
    if kind == "frames":
        return split, kind, draw(json_value)
    if kind == "image":
        return split, kind, draw(st.sampled_from(["truncate", "text", "size", "grey", "delete"]))
    if kind == "whole":
        return split, kind, draw(json_value)
    return split, kind, None


def apply_blender_mutation(folder: Path, m) -> None:
    from PIL import Image

    split, kind, value = m
    path = folder / f"transforms_{split}.json"
    if kind == "drop_file":
        path.unlink(missing_ok=True)
        return
    if not path.exists():
        return
    if kind == "image":
        p = folder / split / "r_0.png"
        if not p.exists():
            return
        if value == "truncate":
            p.write_bytes(p.read_bytes()[:50])
        elif value == "text":
            p.write_text("<html>")
        elif value == "size":
            write_images(folder, [f"{split}/r_0.png"], size=(7, 6))
        elif value == "grey":
            Image.fromarray(np.zeros((6, 8), np.uint16)).save(p)
        else:
            p.unlink()
        return
    try:
        d = json.loads(path.read_text())
    except ValueError:
        return
    if kind == "whole":
        d = value
    elif isinstance(d, dict):
        frames = d.get("frames") if isinstance(d.get("frames"), list) else []
        if kind == "angle":
            d["camera_angle_x"] = value
        elif kind == "frames":
            d["frames"] = value
        elif frames and isinstance(frames[0], dict):
            if kind == "pose":
                frames[0]["transform_matrix"] = value
            else:
                key, v = value
                if v == "__drop__":
                    frames[0].pop(key, None)
                else:
                    frames[0][key] = v
    path.write_text(dump_json(d))


@fuzz(150)
@given(mutations=st.lists(blender_mutation(), min_size=1, max_size=3), size=st.sampled_from([None, None, 4, 16]))
@pytest.mark.slow
def test_blender_folders_load_valid_or_fail_cleanly(mutations, size):
    from nerfkit.data.load import load_scene

    with scratch() as folder:
        make_blender(folder)
        for m in mutations:
            apply_blender_mutation(folder, m)
        scene = attempt(load_scene, folder, size=size)
    if scene is not None:
        assert_valid_scene(scene)


# ============================================================================= COLMAP models

CAMERA_MODELS = {
    "SIMPLE_PINHOLE": 3,
    "PINHOLE": 4,
    "SIMPLE_RADIAL": 4,
    "RADIAL": 5,
    "OPENCV": 8,
    "OPENCV_FISHEYE": 8,
    "FOV": 5,
    "FOO": 4,
}
colmap_number = st.one_of(
    st.sampled_from(["0", "-1", "nan", "inf", "1e300", "-20", "abc", "1e-30"]),
    st.floats(-50, 50, allow_nan=False).map(repr),
)


@st.composite
def colmap_text_model(draw):
    """cameras.txt, images.txt, points3D.txt: mostly sane, with a few hostile fields."""
    model = draw(st.sampled_from(["PINHOLE"] * 8 + sorted(CAMERA_MODELS)))
    n_params = CAMERA_MODELS[model] + draw(st.sampled_from([0] * 8 + [-1, 1]))
    base = {"SIMPLE_PINHOLE": [20, 8, 6], "PINHOLE": [20, 20, 8, 6]}.get(model, [20, 20, 8, 6, 0, 0, 0, 0, 0])
    params = [
        str(base[i]) if i < len(base) and draw(st.integers(0, 12)) else draw(colmap_number)
        for i in range(max(n_params, 0))
    ]
    width, height = (
        draw(st.sampled_from(["16"] * 12 + ["0", "-16", "99999999999", "17"])),
        draw(st.sampled_from(["12"] * 12 + ["0", "12.5"])),
    )
    cams = f"# camera\n1 {model} {width} {height} {' '.join(params)}\n"
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    lines = []
    for i in range(draw(st.sampled_from([0, 1, 2, 3, 4, 4, 4, 4]))):
        if draw(st.integers(0, 15)):
            q = rng.normal(size=4)
            q /= np.linalg.norm(q)
            q, t = [repr(float(x)) for x in q], [repr(float(x)) for x in rng.normal(size=3) * 0.3 + [0, 0, 4]]
        else:
            q = [draw(colmap_number) for _ in range(4)]
            t = [draw(colmap_number) for _ in range(3)]
        cam_id = draw(st.sampled_from(["1"] * 15 + ["2"]))
        name = draw(st.sampled_from([f"{i}.png"] * 15 + ["missing.png", "../0.png"]))
        lines.append(f"{i + 1} {' '.join(q)} {' '.join(t)} {cam_id} {name}\n\n")
    pts = "".join(
        f"{j + 1} {' '.join(repr(float(v)) for v in rng.normal(size=3) * 0.4)} 128 128 128 0.5\n"
        for j in range(draw(st.sampled_from([0, 30])))
    )
    if draw(st.integers(0, 5)) == 0:
        pts += f"999 {draw(colmap_number)} 0 0 1 2 3 0.5\n"
    return cams, "".join(lines), pts


@fuzz(120)
@given(model=colmap_text_model())
def test_colmap_text_models_load_valid_or_fail_cleanly(model):
    pytest.importorskip("pycolmap")
    from nerfkit.data.load import load_scene

    cams, imgs, pts = model
    with scratch() as d:
        m = d / "sparse" / "0"
        m.mkdir(parents=True)
        (m / "cameras.txt").write_text(cams)
        (m / "images.txt").write_text(imgs)
        (m / "points3D.txt").write_text(pts)
        write_images(d, [f"images/{i}.png" for i in range(4)], size=(16, 12))
        scene = attempt(load_scene, d)
    if scene is not None:
        assert_valid_scene(scene)


@pytest.mark.slow
@fuzz(8)
@given(data=st.data())
def test_colmap_binary_models_fail_cleanly_when_corrupted(data):
    """Binary models are read in a memory-capped child first (see colmap._precheck_binary_model)."""
    pycolmap = pytest.importorskip("pycolmap")
    from nerfkit.data.colmap import write_colmap_model
    from nerfkit.data.load import load_scene
    from nerfkit.data.synthetic import sphere_scene

    with scratch() as d:
        source = sphere_scene(n_train=3, n_val=1, size=8)
        for v in source.splits.values():
            v.names = [f"{n}.png" for n in v.names]
        write_colmap_model(source, d / "sparse" / "0")
        names = [im.name for im in pycolmap.Reconstruction(d / "sparse" / "0").images.values()]
        write_images(d, [f"images/{name}" for name in names], size=(8, 8))
        assert_valid_scene(load_scene(d))  # before the corruption, it loads
        files = sorted((d / "sparse" / "0").glob("*.bin"))
        f = data.draw(st.sampled_from(files))
        raw = f.read_bytes()
        if data.draw(st.booleans()) and len(raw) >= 8:  # a header declaring a huge count
            raw = struct.pack("<Q", data.draw(st.sampled_from([10**15, 2**63, 10**6]))) + raw[8:]
        else:
            raw = corrupt_bytes(raw, data.draw)
        f.write_bytes(raw)
        scene = attempt(load_scene, d)
    if scene is not None:  # what loads is a valid scene, never NaN rotations or a zero focal length
        assert_valid_scene(scene)


# ============================================================================= run config.json and checkpoints


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A 3-step vanilla run on a tiny sphere (config.json + one checkpoint)."""
    from nerfkit.data.synthetic import sphere_scene
    from nerfkit.train.trainer import train

    out = tmp_path_factory.mktemp("fuzz") / "run"
    train(sphere_scene(n_train=4, n_val=1, size=8), *tiny_vanilla_configs(out, 3), quiet=True)
    return out


def copy_run(run: Path, dest: Path) -> Path:
    shutil.copytree(run, dest)
    return dest


@st.composite
def config_mutation(draw):
    section = draw(st.sampled_from(["train", "model", "bounds", "top", "whole"]))
    keys = {
        "train": [
            "model",
            "steps",
            "minutes",
            "batch_rays",
            "lr",
            "lr_final_factor",
            "background",
            "render_chunk",
            "device",
            "precision",
            "unknown_key",
        ],
        "model": [
            "n_samples",
            "n_importance",
            "pos_freqs",
            "dir_freqs",
            "width",
            "depth",
            "density_bias_init",
            "unknown_key",
        ],
        "bounds": ["near", "far", "center", "radius", "up"],
        "top": ["train", "model", "bounds", "scene"],
        "whole": [None],
    }[section]
    key = draw(st.sampled_from(keys))
    # model sizes stay small: a crafted config.json can still ask for a huge model (see the report)
    value = draw(
        st.one_of(
            json_value, any_float, st.just("__drop__"), st.integers(-3, 64), st.lists(any_float, min_size=3, max_size=3)
        )
    )
    if section == "model" and isinstance(value, int) and not isinstance(value, bool) and abs(value) > 256:
        value = 256
    return section, key, value


@fuzz(120)
@given(mutations=st.lists(config_mutation(), min_size=1, max_size=3), load=st.integers(0, 3))
def test_run_config_json_reads_valid_or_fails_cleanly(tiny_run, mutations, load):
    from nerfkit.train.checkpoint import load_run, read_run

    with scratch() as d:
        run = copy_run(tiny_run, d / "run")
        cfg = json.loads((run / "config.json").read_text())
        for section, key, value in mutations:
            if section == "whole":
                cfg = value
                continue
            if not isinstance(cfg, dict):
                continue
            target = cfg if section == "top" else cfg.get(section)
            if isinstance(target, dict):
                if value == "__drop__":
                    target.pop(key, None)
                else:
                    target[key] = value
        (run / "config.json").write_text(dump_json(cfg))
        info = attempt(read_run, run)
        if info is not None:
            b = info.bounds
            assert math.isfinite(b.near) and math.isfinite(b.far) and 0 <= b.near < b.far
            assert np.isfinite(b.center).all() and b.center.shape == (3,)
            assert np.isfinite(b.up).all() and b.up.shape == (3,) and abs(np.linalg.norm(b.up) - 1) < 1e-3
            assert math.isfinite(b.radius) and b.radius > 0
            assert isinstance(info.train.steps, int) and isinstance(info.train.lr, float)
        if load == 0:  # building the model too (a quarter of the examples: it is slower)
            loaded = attempt(load_run, run)
            if loaded is not None:
                import torch

                model, _, step = loaded
                assert isinstance(step, int) and step >= 0
                assert all(torch.isfinite(p).all() for p in model.parameters())


@st.composite
def checkpoint_mutation(draw):
    import torch

    kind = draw(st.sampled_from(["top", "top", "tensor", "extra", "drop"]))
    tensors = st.builds(
        lambda shape, dtype, fill: torch.full(shape, fill, dtype=torch.float32).to(dtype),
        st.lists(st.integers(0, 4), max_size=3).map(tuple),
        st.sampled_from([torch.float32, torch.float64, torch.int64, torch.bool, torch.float16]),
        st.sampled_from([0.0, 1.0, float("nan"), float("inf"), -1e30]),
    )
    plain = st.one_of(
        st.none(),
        st.integers(-5, 10**6),
        st.text(max_size=8),
        any_float,
        st.lists(st.integers(), max_size=3),
        st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
        tensors,
    )
    if kind == "top":
        return (
            kind,
            draw(
                st.sampled_from(
                    [
                        "format",
                        "version",
                        "model_name",
                        "step",
                        "model",
                        "model_extra",
                        "optimizer",
                        "train_seconds",
                        "rows",
                    ]
                )
            ),
            draw(plain),
        )
    if kind == "drop":
        return kind, draw(st.sampled_from(["format", "version", "model_name", "step", "model", "model_extra"])), None
    if kind == "tensor":
        return kind, draw(st.integers(0, 100)), draw(st.one_of(tensors, st.sampled_from(["nan", "inf", "same_shape"])))
    return kind, None, draw(st.one_of(json_value.map(json.dumps), st.text(max_size=10)))


@pytest.mark.slow
@fuzz(80)
@given(mutations=st.lists(checkpoint_mutation(), min_size=1, max_size=3), corrupt=st.integers(0, 4), data=st.data())
def test_checkpoints_load_finite_or_fail_cleanly(tiny_run, mutations, corrupt, data):
    import torch

    from nerfkit.train.checkpoint import load_run

    with scratch() as d:
        run = copy_run(tiny_run, d / "run")
        path = sorted((run / "checkpoints").glob("step_*.pt"))[-1]
        ckpt = torch.load(path, weights_only=True)
        for kind, key, value in mutations:
            if kind == "top":
                ckpt[key] = value
            elif kind == "drop":
                ckpt.pop(key, None)
            elif kind == "extra":
                ckpt["model_extra"] = value
            elif isinstance(ckpt.get("model"), dict) and ckpt["model"]:
                names = sorted(ckpt["model"])
                name = names[key % len(names)]
                old = ckpt["model"][name]
                if value == "same_shape":
                    value = torch.randn_like(old.float())
                elif isinstance(value, str):  # "nan" or "inf" in one weight
                    bad = float(value)
                    value = old.clone().float()
                    if value.numel():
                        value.view(-1)[0] = bad
                ckpt["model"][name] = value
        torch.save(ckpt, path)
        if corrupt == 0:  # and sometimes the bytes too
            path.write_bytes(corrupt_bytes(path.read_bytes(), data.draw))
        loaded = attempt(load_run, run)
        if loaded is not None:
            model, _, step = loaded
            assert isinstance(step, int) and step >= 0
            assert all(torch.isfinite(p).all() for p in model.parameters())
