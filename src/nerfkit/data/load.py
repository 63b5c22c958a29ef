"""Load any supported dataset into a :class:`Scene`, choosing the reader by path.

Supported (file or folder):

* the course npz (``*.npz``, or a folder holding exactly one ``.npz``);
* Blender-style synthetic scenes (a folder with ``transforms_train.json``, or that file);
* nerfstudio / instant-ngp ``transforms.json`` (the file, or a folder holding it);
* LLFF forward-facing scenes (a folder with ``poses_bounds.npy`` and ``images/``, or that
  file; it wins over a COLMAP model in the same folder, as the papers use its poses);
* COLMAP models (a folder with ``cameras``/``images``/``points3D`` ``.bin`` or ``.txt``,
  or a project folder with ``sparse/0`` and ``images/``), without re-running SfM.

Also the resampling every format shares: :func:`resample_scene` resizes images and
scales ``K`` so that the cameras stay exact.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..config import MIN_DOWNSCALE, MIN_RESAMPLED_SIDE, range_problem
from ..errors import NerfkitError, fail
from ..io.paths import path_kind, refuse_special_file
from .npz import load_npz
from .scene import Scene, Views
from .validate import MAX_PIXELS, check_scene

FORMATS = ("a course .npz, a Blender folder (transforms_train.json), a transforms.json, an LLFF folder "
           "(poses_bounds.npy), or a COLMAP model folder")


def output_size(width: int, height: int, size: int | None = None, downscale: float | None = None) -> tuple[int, int]:
    """Image size after resampling: ``size`` = new longest side in pixels, or ``downscale`` = divisor.

    Neither given: unchanged. Both given: an error (they would disagree).
    """
    if size is not None and downscale is not None:
        raise fail("--size/--downscale", "give one of them, not both")
    if size is not None:
        if size < 1:
            raise fail("--size", f"{size} must be a positive number of pixels")
        s = size / max(width, height)
    elif downscale is not None:
        problem = range_problem(downscale, float, min=MIN_DOWNSCALE)
        if problem:
            raise fail("--downscale", problem, "It divides the image size: 2 halves the images")
        s = 1.0 / downscale
    else:
        return width, height
    new = max(1, round(width * s)), max(1, round(height * s))
    if min(new) < MIN_RESAMPLED_SIDE <= min(width, height):
        flag = "--size" if size is not None else "--downscale"
        most = (f"--size {math.ceil(MIN_RESAMPLED_SIDE * max(width, height) / min(width, height))} or more"
                if size is not None else f"--downscale {min(width, height) / MIN_RESAMPLED_SIDE:g} or less")
        raise fail(flag, f"would resample the {width}x{height} images to {new[0]}x{new[1]}, too small to hold a "
                         f"scene (at least {MIN_RESAMPLED_SIDE} pixels a side)", f"Use {most}")
    return new


def scale_intrinsics(K: np.ndarray, width: int, height: int, new_width: int, new_height: int) -> np.ndarray:
    """K (..., 3, 3) for images resampled from ``width x height`` to ``new_width x new_height``.

    Pixel edges map to pixel edges (u' = u * new_width / width), so with pixel centres at
    +0.5 the rays through corresponding image points are unchanged.
    """
    sx, sy = new_width / width, new_height / height
    out = np.array(K, dtype=np.float64, copy=True)
    out[..., 0, :] *= sx
    out[..., 1, :] *= sy
    return out.astype(np.float32)


def resize_image(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resample a (H, W, 3) uint8 image to (height, width, 3): area averaging when shrinking,
    bicubic when enlarging."""
    from PIL import Image

    if image.shape[1] == width and image.shape[0] == height:
        return image
    shrink = width <= image.shape[1] and height <= image.shape[0]
    method = Image.Resampling.BOX if shrink else Image.Resampling.BICUBIC
    return np.asarray(Image.fromarray(image).resize((width, height), method))


def resample_views(views: Views, new_width: int, new_height: int) -> Views:
    """The same cameras at another image size (images resized, K scaled)."""
    if (new_width, new_height) == (views.width, views.height):
        return views
    if views.images is not None and len(views.images) * new_width * new_height > MAX_PIXELS:
        raise fail(f"{new_width}x{new_height}", f"resampling {len(views.images)} images to this size needs more than "
                   f"{MAX_PIXELS:.2g} pixels", "Choose a smaller --size")
    images = None
    if views.images is not None:
        images = (np.stack([resize_image(im, new_width, new_height) for im in views.images])
                  if len(views.images) else np.zeros((0, new_height, new_width, 3), np.uint8))
    K = scale_intrinsics(views.K, views.width, views.height, new_width, new_height)
    return replace(views, K=K, width=new_width, height=new_height, images=images)


def resample_scene(scene: Scene, size: int | None = None, downscale: float | None = None) -> Scene:
    """Every split resampled (see :func:`output_size`); poses, near/far unchanged."""
    if output_size(scene.train.width, scene.train.height, size, downscale) == (scene.train.width, scene.train.height):
        return scene
    return replace(scene, **{name: resample_views(v, *output_size(v.width, v.height, size, downscale))
                             for name, v in scene.splits.items()})


def detect_format(path: str | Path) -> str:
    """'npz', 'blender', 'transforms', 'llff' or 'colmap' for a dataset path; NerfkitError otherwise."""
    from .blender import blender_folder
    from .colmap import find_colmap_model
    from .llff import llff_folder

    path = Path(path)
    kind = path_kind(path)
    refuse_special_file(path, kind)
    if kind is None:
        raise fail(path, "no such file or folder", "Check the path")
    if kind != "dir":
        if path.name == "poses.json" and (path.parent / "dataset.npz").is_file():
            raise fail(path, "is the record of the photos' poses, not the dataset", f"Give {path.parent / 'dataset.npz'}")
        if path.suffix.lower() == ".npz":
            return "npz"
        if blender_folder(path) is not None:
            return "blender"
        if path.suffix.lower() == ".json":
            return "transforms"
        if llff_folder(path) is not None:
            return "llff"
        if path.suffix.lower() in (".bin", ".txt") and find_colmap_model(path.parent) is not None:
            return "colmap"
        raise fail(path, "unrecognised dataset file", f"Expected {FORMATS}")
    npzs = sorted(path.glob("*.npz"))
    if len(npzs) == 1:
        return "npz"
    if len(npzs) > 1:
        raise fail(path, f"holds {len(npzs)} .npz files ({', '.join(p.name for p in npzs[:4])})",
                   "Pass the one you mean")
    if blender_folder(path) is not None:
        return "blender"
    if (path / "transforms.json").is_file():
        return "transforms"
    if llff_folder(path) is not None:
        return "llff"
    if find_colmap_model(path) is not None:
        return "colmap"
    raise fail(path, "folder holds no dataset nerfkit recognises", _folder_hint(path) or f"Expected {FORMATS}")


def is_run_folder(path: Path) -> bool:
    """Whether ``path`` is a trained run's folder (its config.json, and checkpoints or model.pt)."""
    return path.is_dir() and (path / "config.json").is_file() and \
        ((path / "checkpoints").is_dir() or (path / "model.pt").is_file())


def _folder_hint(path: Path) -> str | None:
    """What to give instead of a folder that holds no dataset: a capture's own dataset, a
    run's dataset, or how to make one from the photos it holds."""
    from ..images import image_files

    if (path / "dataset" / "dataset.npz").is_file():
        return f"This is a capture's folder: its dataset is {path / 'dataset'}"
    if is_run_folder(path):
        import json

        try:
            data = json.loads((path / "config.json").read_text())["train"]["data"]
        except (OSError, ValueError, KeyError, TypeError):
            data = None
        where = f" trained on {data}" if isinstance(data, str) and data else ""
        return (f"This is a trained run's folder{where}: pass that dataset, or continue the run with "
                f"`nerfkit train --resume {path}`")
    if image_files(path):
        return (f"It holds photos without poses: make a dataset of them with `nerfkit poses {path} --out DATASET` "
                "(or the whole flow with `nerfkit capture`)")
    return None


def dataset_inputs(path: str | Path) -> list[Path]:
    """What reading the dataset at ``path`` reads, for the guard that never writes an input
    (:func:`~nerfkit.io.paths.guard_outputs`): the path; the folder of a dataset named by one
    of its files (a ``transforms.json`` or ``poses_bounds.npy`` with images beside it); and a
    COLMAP model's photo folder (the project's ``images/``, found above the model)."""
    path = Path(path)
    out = [path]
    if path.is_file() and path.suffix.lower() != ".npz":
        out.append(path.parent)
    try:
        fmt = detect_format(path)
    except NerfkitError:
        return out
    if fmt == "colmap":
        from .colmap import find_image_dir

        images = find_image_dir(path if path.is_dir() else path.parent)
        out += [images] if images is not None else []
    return out


def load_scene(
    path: str | Path,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    size: int | None = None,
    downscale: float | None = None,
    allow_outside: bool = False,
    need: str = "train",
) -> Scene:
    """Read a dataset file or folder (any supported format) into a Scene.

    Args:
        background: RGB in [0, 1] under transparent pixels (RGBA formats; default black).
        size, downscale: optional resampling, see :func:`output_size`.
        allow_outside: accept image paths outside the dataset folder (``--allow-outside-paths``).
        need: the split that must be present: ``train``, or the split an evaluation reads
            (a file of held-out views needs no training split).
    Raises NerfkitError naming the path when the format is unsupported or the data is bad.
    """
    path = Path(path)
    fmt = detect_format(path)
    if fmt == "npz":
        if path.is_dir():
            path = next(path.glob("*.npz"))
        scene = resample_scene(load_npz(path, need=need), size, downscale)
    elif fmt == "blender":
        from .blender import load_blender

        scene = load_blender(path, background=background, size=size, downscale=downscale, allow_outside=allow_outside,
                             need=need)
    elif fmt == "llff":
        from .llff import load_llff

        scene = load_llff(path, size=size, downscale=downscale, allow_outside=allow_outside)
    elif fmt == "colmap":
        from .colmap import load_colmap

        scene = load_colmap(path, background=background, size=size, downscale=downscale, allow_outside=allow_outside)
    else:
        scene = resample_scene(_load_transforms(path, background, allow_outside, need), size, downscale)
    return check_scene(scene, scene.source or str(path), need=need)  # the same guarantees for every format


def _load_transforms(path: Path, background, allow_outside: bool, need: str) -> Scene:
    """nerfstudio / instant-ngp transforms.json through :mod:`nerfkit.data.nerfstudio`."""
    try:
        from .nerfstudio import load_transforms_json
    except ImportError:
        raise fail(path, "transforms.json support (nerfkit.data.nerfstudio) is not installed in this build",
                   "Convert the dataset to a course .npz first") from None
    return load_transforms_json(path, background=background, allow_outside=allow_outside, need=need)
