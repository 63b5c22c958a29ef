"""LLFF forward-facing scenes (the layout of the NeRF paper's "real forward-facing" data).

Layout::

    scene/poses_bounds.npy    (N, 17) float: per image a 3x5 matrix, row-major, and 2 bounds
    scene/images/             the N photos, in name order
    scene/images_4/, images_8/   optional copies downscaled by 4 and 8

Each row's 3x5 matrix is ``[R | t | hwf]``: the rotation's columns are the camera's
*down*, *right* and *back* axes in world coordinates (LLFF's axis order), ``t`` is the
camera centre and ``hwf`` = (height, width, focal in pixels) of the full-size photos. The
last two numbers are the near and far depth of the scene's points seen by that image.

Converted to nerfkit's convention (OpenCV axes: x right, y down, z forward) the
camera-to-world is ``[right, down, -back | t]``, the principal point the image centre.
Every 8th image (0, 8, 16, ...) is held out as the validation and test split, as the
papers score these scenes; near/far are 0.9x the smallest and 1x the largest bound.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import fail
from ..images import image_files, load_image_uint8
from ..io.paths import path_kind, refuse_special_file, resolve_inside
from .scene import Scene, Views, estimate_up
from .validate import MAX_COORD, MAX_PIXELS, check_intrinsics, check_near_far, check_poses

POSES_FILE = "poses_bounds.npy"
HOLDOUT_EVERY = 8  # every 8th image is held out for scoring (LLFF / NeRF papers)
MAX_VIEWS = 100_000


def llff_folder(path: str | Path) -> Path | None:
    """The dataset folder when ``path`` is an LLFF scene (the folder or its poses_bounds.npy)."""
    path = Path(path)
    poses = path if path.name == POSES_FILE else path / POSES_FILE
    kind = path_kind(poses)
    if kind not in ("file", "other"):
        return None
    refuse_special_file(poses, kind)  # a pipe named poses_bounds.npy: said so, never opened
    return poses.parent


def llff_to_opencv(poses: np.ndarray) -> np.ndarray:
    """LLFF (N, 3, 5) ``[down, right, back | t | hwf]`` -> (N, 4, 4) OpenCV camera-to-world."""
    c2w = np.zeros((poses.shape[0], 4, 4), np.float64)
    c2w[:, :3, 0] = poses[:, :, 1]  # right
    c2w[:, :3, 1] = poses[:, :, 0]  # down
    c2w[:, :3, 2] = -poses[:, :, 2]  # forward = -back
    c2w[:, :3, 3] = poses[:, :, 3]
    c2w[:, 3, 3] = 1.0
    return c2w


def opencv_to_llff(c2w: np.ndarray, hwf: np.ndarray) -> np.ndarray:
    """Inverse of :func:`llff_to_opencv`: (N, 4, 4) and (N, 3) or (3,) hwf -> (N, 3, 5)."""
    c2w = np.asarray(c2w, np.float64)
    n = c2w.shape[0]
    out = np.zeros((n, 3, 5), np.float64)
    out[:, :, 0] = c2w[:, :3, 1]
    out[:, :, 1] = c2w[:, :3, 0]
    out[:, :, 2] = -c2w[:, :3, 2]
    out[:, :, 3] = c2w[:, :3, 3]
    out[:, :, 4] = np.broadcast_to(np.asarray(hwf, np.float64), (n, 3))
    return out


def holdout_indices(n: int, every: int = HOLDOUT_EVERY) -> tuple[np.ndarray, np.ndarray]:
    """``(train, held_out)`` image indices: every ``every``-th image (0, every, ...) is held out,
    as the NeRF papers score LLFF and COLMAP scenes (the one rule of both loaders).

    A scene of a single image trains on it, as does ``every`` <= 0 (nothing is held out).
    Example: ``holdout_indices(20)`` holds out 0, 8 and 16.
    """
    idx = np.arange(n)
    held = idx[::every] if n > 1 and every > 0 else idx[:0]
    return np.setdiff1d(idx, held), held


def forward_facing_center(c2w: np.ndarray, near: float, far: float) -> np.ndarray:
    """A point (3,) in front of the cameras: their mean centre moved along their mean
    viewing direction to the middle of the depth range (the optical axes of a
    forward-facing capture are nearly parallel, so no point is close to all of them)."""
    forward = c2w[:, :3, 2].astype(np.float64).mean(0)
    forward /= max(np.linalg.norm(forward), 1e-12)
    return (c2w[:, :3, 3].astype(np.float64).mean(0) + 0.5 * (near + far) * forward).astype(np.float32)


def read_poses_bounds(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(poses (N, 3, 5), bounds (N, 2))`` from poses_bounds.npy, checked (one-line errors)."""
    where = str(path)
    try:
        with open(path, "rb") as f:
            magic = f.read(6)
    except OSError as e:
        raise fail(where, f"cannot be read ({e.strerror or type(e).__name__})") from None
    if magic != b"\x93NUMPY":  # (np.load takes any other file for a pickle)
        raise fail(where, "is not a .npy file", "Expected LLFF's poses_bounds.npy: an (N, 17) float array")
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise fail(
            where,
            f"cannot read it as a .npy array ({type(e).__name__}: {str(e)[:120]})",
            "Expected LLFF's poses_bounds.npy: an (N, 17) float array",
        ) from None
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "fiu":
        raise fail(
            where,
            f"has dtype {getattr(arr, 'dtype', type(arr).__name__)}, expected numbers",
            "Expected LLFF's poses_bounds.npy: an (N, 17) float array",
        )
    if arr.ndim != 2 or arr.shape[1] != 17 or not 1 <= arr.shape[0] <= MAX_VIEWS:
        raise fail(
            where,
            f"has shape {arr.shape}, expected (N, 17): a 3x5 pose and 2 bounds per image",
            "Is this LLFF's poses_bounds.npy?",
        )
    arr = arr.astype(np.float64)
    bad = ~(np.isfinite(arr) & (np.abs(arr) <= MAX_COORD)).all(axis=1)
    if bad.any():
        raise fail(
            where,
            f"row {int(np.argmax(bad))} has NaN or inf values (or values beyond {MAX_COORD:g})",
            "Remove or re-estimate that image's pose",
        )
    poses, bounds = arr[:, :15].reshape(-1, 3, 5), arr[:, 15:]
    hwf = poses[:, :, 4]
    if (hwf <= 0).any():
        i = int(np.argmax((hwf <= 0).any(axis=1)))
        raise fail(where, f"row {i}: height, width and focal {hwf[i].tolist()} must be positive")
    if not np.allclose(hwf[:, :2], hwf[:1, :2]):
        raise fail(where, "the images' heights and widths differ between rows", "All photos must have one size")
    if (bounds[:, 0] <= 0).any() or (bounds[:, 0] >= bounds[:, 1]).any():
        i = int(np.argmax((bounds[:, 0] <= 0) | (bounds[:, 0] >= bounds[:, 1])))
        raise fail(where, f"row {i}: bounds {bounds[i].tolist()} are not 0 < near < far")
    return poses, bounds


def _image_folder(folder: Path, downscale: float | None) -> tuple[Path, float]:
    """``images_k`` when ``downscale`` is a whole k and that folder exists, else ``images``;
    and the factor still to apply by resampling."""
    if downscale is not None and float(downscale).is_integer() and int(downscale) > 1:
        sub = folder / f"images_{int(downscale)}"
        if sub.is_dir():
            return sub, 1.0
    return folder / "images", 1.0 if downscale is None else float(downscale)


def load_llff(
    path: str | Path,
    size: int | None = None,
    downscale: float | None = None,
    allow_outside: bool = False,
) -> Scene:
    """Load an LLFF scene folder (or its poses_bounds.npy) into a Scene.

    Args:
        size, downscale: optional resampling (longest side in pixels, or a divisor);
            ``downscale`` 4 or 8 reads ``images_4``/``images_8`` when they exist.
        allow_outside: accept image files that link outside the folder.
    """
    from .resample import output_size, resample_scene, resize_image, scale_intrinsics

    output_size(1, 1, size, downscale)  # refuses both at once
    folder = llff_folder(path)
    if folder is None:
        raise fail(path, "not an LLFF scene", f"Expected a folder holding {POSES_FILE} and images/")
    poses, bounds = read_poses_bounds(folder / POSES_FILE)
    img_dir, still = _image_folder(folder, downscale)
    if not img_dir.is_dir():
        raise fail(img_dir, "missing", f"An LLFF scene keeps its photos in images/ beside {POSES_FILE}")
    files = [p.name for p in image_files(img_dir)]
    if len(files) != len(poses):
        raise fail(
            img_dir,
            f"holds {len(files)} images but {POSES_FILE} has {len(poses)} poses",
            "Each photo needs one row of poses_bounds.npy, in name order",
        )
    h0, w0, _ = poses[0, :, 4]
    images, size_wh = [], None
    for name in files:
        p = resolve_inside(img_dir, name, allow_outside, img_dir)
        img = load_image_uint8(p)
        h, w = img.shape[:2]
        if size_wh is None:
            size_wh = (w, h)
            if len(files) * w * h > MAX_PIXELS:
                raise fail(
                    img_dir,
                    f"{len(files)} photos of {w}x{h} exceed {MAX_PIXELS:.2g} pixels",
                    "Use a downscaled folder (images_4, images_8) with --downscale 4 or 8",
                )
        elif (w, h) != size_wh:
            raise fail(
                p, f"image is {w}x{h} but {files[0]} is {size_wh[0]}x{size_wh[1]}", "All photos must have one size"
            )
        images.append(img)
    assert size_wh is not None  # there is at least one photo: as many as poses
    w, h = size_wh
    if abs(w / h - w0 / h0) > 0.01 * w0 / h0:
        raise fail(
            img_dir,
            f"photos are {w}x{h} but {POSES_FILE} says {w0:g}x{h0:g} (another aspect ratio)",
            "Use the photos the poses were computed for",
        )
    f = poses[:, 2, 4] * (w / w0)  # the focal in pixels of the photos at hand
    K = np.zeros((len(f), 3, 3))
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = f, f, w / 2, h / 2, 1.0
    K = check_intrinsics(K, str(folder / POSES_FILE), "hwf", w, h)
    c2w = check_poses(llff_to_opencv(poses), str(folder / POSES_FILE), "poses")
    ow, oh = output_size(w, h, None, still if still != 1.0 else None)
    if (ow, oh) != (w, h):
        images = [resize_image(im, ow, oh) for im in images]
        K = scale_intrinsics(K, w, h, ow, oh)
    views = Views(c2w, K.astype(np.float32), ow, oh, np.stack(images), [Path(n).stem for n in files])
    train_idx, held = holdout_indices(len(views))
    near, far = check_near_far(0.9 * bounds[:, 0].min(), bounds[:, 1].max(), str(folder / POSES_FILE))
    center = forward_facing_center(c2w, near, far)
    held_out = views.subset(held) if len(held) else Views.empty(ow, oh)
    scene = Scene(views.subset(train_idx), held_out, held_out, near, far, center, estimate_up(c2w), source=str(folder))
    return resample_scene(scene, size, None)


__all__ = [
    "HOLDOUT_EVERY",
    "POSES_FILE",
    "forward_facing_center",
    "holdout_indices",
    "llff_folder",
    "llff_to_opencv",
    "load_llff",
    "opencv_to_llff",
    "read_poses_bounds",
]
