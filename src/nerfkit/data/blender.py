"""Blender-style synthetic datasets (the original NeRF release: lego, chair, ...).

Layout::

    scene/transforms_train.json   {"camera_angle_x": 0.691, "frames": [
    scene/transforms_val.json        {"file_path": "./train/r_0", "transform_matrix": 4x4}, ...]}
    scene/transforms_test.json
    scene/train/r_0.png ...       RGBA PNGs

``transform_matrix`` is camera-to-world with OpenGL camera axes; it is converted with
:func:`nerfkit.cameras.opengl_to_opencv`. The focal length is
``0.5 * W / tan(0.5 * camera_angle_x)`` with the principal point at the image centre.
Transparent pixels are composited on ``background`` (black by default, as in the course npz).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..cameras import opengl_to_opencv
from ..config import load_json
from ..errors import fail
from ..images import IMAGE_SUFFIXES, load_image_uint8
from ..io.paths import resolve_inside
from .scene import Scene, Views, estimate_center, estimate_near_far, estimate_up
from .validate import check_fov, check_intrinsics, check_near_far, check_poses, check_scene

SPLITS = ("train", "val", "test")


def blender_folder(path: str | Path) -> Path | None:
    """The dataset folder when ``path`` is a Blender dataset (folder or one of its json files)."""
    path = Path(path)
    if path.is_file() and path.name in {f"transforms_{s}.json" for s in SPLITS}:
        return path.parent
    if path.is_dir() and any((path / f"transforms_{s}.json").is_file() for s in SPLITS):
        return path
    return None


def focal_from_angle(camera_angle_x: float, width: int) -> float:
    """Focal length in pixels of a pinhole camera with horizontal field of view ``camera_angle_x`` (radians)."""
    return 0.5 * width / math.tan(0.5 * camera_angle_x)


def frame_image_path(folder: Path, file_path: str, where: str, allow_outside: bool = False) -> Path:
    """Resolve a frame's ``file_path`` (often given without extension) to an image file
    inside ``folder`` (see :func:`nerfkit.io.paths.resolve_inside`)."""
    try:
        for name in (file_path, *(file_path + s for s in (".png", ".PNG", *sorted(IMAGE_SUFFIXES)))):
            found = Path(folder) / name
            if found.exists() and not found.is_dir():  # a pipe too: its reader refuses it, by name
                return resolve_inside(folder, name, allow_outside, where)
        resolve_inside(folder, file_path, allow_outside, where)  # outside is refused before "not found"
    except (OSError, ValueError) as e:  # a NUL byte, a name too long, a loop of links
        raise fail(
            where,
            f"frame image {file_path[:100]!r} is not a usable path ({type(e).__name__}: {e})",
            "Check the frames' file_path entries",
        ) from None
    named = Path(file_path[:200])
    looked = f"{str(named)!r}" if named.suffix else f"{str(named)!r} and it with an image suffix (.png, .jpg, ...)"
    raise fail(
        where,
        f"frame image not found: looked for {looked} in {folder}",
        "Check the frames' file_path entries and that the images were copied",
    )


def _read_split(folder: Path, split: str, background, out_size, with_images: bool, allow_outside: bool = False):
    """Cameras and images of one split; None when its json is absent."""
    from .resample import resize_image, scale_intrinsics

    json_path = folder / f"transforms_{split}.json"
    if not json_path.is_file():
        return None
    where = str(json_path)
    meta = load_json(json_path)
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
        raise fail(where, "expected an object with a 'frames' list", "Is this a Blender-style transforms file?")
    frames = meta["frames"]
    if not frames:
        raise fail(where, "'frames' is empty")
    angle = check_fov(meta.get("camera_angle_x"), where)

    poses, images, names = [], [], []
    size = None  # (width, height) of the files
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict) or "transform_matrix" not in fr or "file_path" not in fr:
            raise fail(where, f"frames[{i}] needs 'file_path' and 'transform_matrix'")
        try:
            m = np.asarray(fr["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            raise fail(where, f"frames[{i}].transform_matrix is not a 4x4 number matrix") from None
        if m.shape not in ((4, 4), (3, 4)):
            raise fail(where, f"frames[{i}].transform_matrix has shape {m.shape}, expected 4x4")
        poses.append(m if m.shape == (4, 4) else np.vstack([m, [0, 0, 0, 1]]))
        img_path = frame_image_path(folder, str(fr["file_path"]), where, allow_outside)
        names.append(str(fr["file_path"]).removeprefix("./") or img_path.stem)
        if with_images or size is None:
            img = load_image_uint8(img_path, background)
            h, w = img.shape[:2]
            if size is None:
                size = (w, h)
            elif (w, h) != size:
                raise fail(
                    img_path,
                    f"image is {w}x{h} but the split's first image is {size[0]}x{size[1]}",
                    "All images of a Blender dataset must have one size",
                )
            if with_images:
                images.append(resize_image(img, *out_size(w, h)))
    c2w_gl = check_poses(np.stack(poses), where, "transform_matrix")
    c2w = opengl_to_opencv(c2w_gl.astype(np.float64)).astype(np.float32)
    assert size is not None  # 'frames' is not empty
    w, h = size
    f = focal_from_angle(float(angle), w)
    K = check_intrinsics(np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]]), where, "camera_angle_x", w, h)
    K = scale_intrinsics(K, w, h, *out_size(w, h))
    ow, oh = out_size(w, h)
    Ks = np.repeat(K[None], len(frames), axis=0)
    return Views(c2w, Ks, ow, oh, np.stack(images) if with_images else None, names)


def load_blender(
    path: str | Path,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    size: int | None = None,
    downscale: float | None = None,
    test_images: bool = True,
    near: float | None = None,
    far: float | None = None,
    allow_outside: bool = False,
    need: str = "train",
) -> Scene:
    """Load a Blender-style dataset folder (or one of its transforms_*.json) into a Scene.

    Args:
        background: RGB in [0, 1] under transparent pixels (default black, as the course npz).
        size, downscale: optional resampling (longest side in pixels, or a divisor); K follows.
        test_images: also load the test split's images (False: its poses only, for render paths).
        near, far: depth range; default 0.5x / 1.5x the cameras' mean distance to the
            centre (2 and 6 for the original scenes, which is what they were made with).
        allow_outside: accept frame images outside the folder (see :mod:`nerfkit.io.paths`).
        need: the split that must be present (``train``; ``test`` for a folder of held-out views).
    """
    from .resample import output_size

    folder = blender_folder(path)
    if folder is None:
        raise fail(path, "not a Blender-style dataset", "Expected a folder holding transforms_train.json")

    def out_size(w: int, h: int) -> tuple[int, int]:
        return output_size(w, h, size, downscale)

    splits = {
        s: _read_split(
            folder,
            s,
            background,
            out_size,
            with_images=(s != "test" or test_images or s == need),
            allow_outside=allow_outside,
        )
        for s in SPLITS
    }
    if splits[need] is None:
        raise fail(folder, f"has no transforms_{need}.json", "A Blender dataset needs the split being read")
    ref = splits[need]
    empty = Views.empty(ref.width, ref.height)
    train, val, test = (splits[s] or empty for s in SPLITS)
    for s, v in (("train", train), ("val", val), ("test", test)):
        if len(v) and (v.width, v.height) != (ref.width, ref.height):
            raise fail(
                folder / f"transforms_{s}.json",
                f"{s} images are {v.width}x{v.height} but {need} images are {ref.width}x{ref.height}",
            )
    ref = ref if not len(train) else train
    center = estimate_center(ref.c2w)
    up = estimate_up(ref.c2w)
    n, f = estimate_near_far(ref.c2w, center)
    n, f = check_near_far(n if near is None else near, f if far is None else far, str(folder))
    return check_scene(Scene(train, val, test, n, f, center, up, source=str(folder)), need=need)
