"""Checks shared by every loader. Each raises :class:`NerfkitError` naming the file and field."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import fail
from .scene import estimate_near_far

# Refuse images beyond this many pixels per split (a crafted header could ask for terabytes).
MAX_PIXELS = 4_000_000_000
# Coordinates and focal lengths beyond this are refused: float32 (and squared distances) overflow.
MAX_COORD = 1e15
# Image sides beyond this many pixels are refused in camera and transforms files.
MAX_SIDE = 100_000


def short_repr(value) -> str:
    """A short repr of a (possibly huge) value read from a file, for messages."""
    r = repr(value)
    return r if len(r) <= 60 else r[:57] + "..."


def _array(value, where: str, field: str) -> np.ndarray:
    """``np.asarray(value)``; ragged lists and integers too large for numpy are a NerfkitError."""
    try:
        return np.asarray(value)
    except (ValueError, TypeError, OverflowError):
        raise fail(where, f"'{field}' is not an array of numbers (ragged or mixed lists?)") from None


def _is_number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def check_number(
    value,
    where: str,
    field: str,
    above: float | None = None,
    below: float | None = None,
    expected: str = "a finite number",
) -> float:
    """A finite number (not a bool, nor a string), strictly between ``above`` and ``below`` when given."""
    ok = (
        _is_number(value)
        and abs(value) <= MAX_COORD
        and (above is None or value > above)
        and (below is None or value < below)
    )
    if not ok:
        raise fail(where, f"'{field}' is {short_repr(value)}, expected {expected}")
    return float(value)


def check_count(value, where: str, field: str, lo: int, hi: int) -> int:
    """A whole number in [lo, hi]: an int, or a float without a fraction (not a bool)."""
    if not (_is_number(value) and lo <= value <= hi and float(value).is_integer()):
        raise fail(where, f"'{field}' is {short_repr(value)}, expected a whole number from {lo} to {hi}")
    return int(value)


def check_fov(angle, where: str, field: str = "camera_angle_x") -> float:
    """A horizontal field of view in radians, in (0, pi)."""
    return check_number(angle, where, field, 0.0, math.pi, "the horizontal field of view in radians (0, pi)")


def check_numbers(value, where: str, field: str) -> np.ndarray:
    """Finite numbers of any shape (a JSON list or an array) as float64."""
    a = _array(value, where, field)
    if a.dtype.kind not in "fiu":
        raise fail(where, f"'{field}' must hold numbers, got {short_repr(value)}")
    a = a.astype(np.float64)
    if not (np.isfinite(a).all() and np.abs(a).max(initial=0.0) <= MAX_COORD):
        raise fail(where, f"'{field}' has NaN or inf values (or values beyond {MAX_COORD:g})")
    return a


def check_poses(c2w: ArrayLike, where: str, field: str, tol: float = 1e-3) -> np.ndarray:
    """Validate (N, 4, 4) rigid camera-to-world matrices; return them as float32.

    Accepts (N, 3, 4) too and appends the [0, 0, 0, 1] row.
    """
    c2w = _array(c2w, where, field)
    if c2w.dtype.kind not in "fiu":
        raise fail(where, f"'{field}' has dtype {c2w.dtype}, expected numbers", "Store poses as float32")
    if c2w.ndim != 3 or c2w.shape[1:] not in ((4, 4), (3, 4)):
        raise fail(where, f"'{field}' has shape {c2w.shape}, expected (N, 4, 4) camera-to-world matrices")
    if c2w.shape[1] == 3:
        bottom = np.broadcast_to(np.array([0, 0, 0, 1], c2w.dtype), (c2w.shape[0], 1, 4))
        c2w = np.concatenate([c2w, bottom], axis=1)
    c2w = c2w.astype(np.float64)
    # Finite in float64 but beyond float32 (e.g. 1e300) would turn into inf when stored.
    bad = ~(np.isfinite(c2w) & (np.abs(c2w) <= MAX_COORD)).all(axis=(1, 2))
    if bad.any():
        raise fail(
            where,
            f"'{field}'[{int(np.argmax(bad))}] has NaN or inf values (or values beyond {MAX_COORD:g})",
            "Remove or re-estimate that pose",
        )
    if not np.allclose(c2w[:, 3], [0, 0, 0, 1], atol=tol):
        i = int(np.argmax(~np.isclose(c2w[:, 3], [0, 0, 0, 1], atol=tol).all(axis=1)))
        raise fail(where, f"'{field}'[{i}] last row is {c2w[i, 3].tolist()}, expected [0, 0, 0, 1]")
    R = c2w[:, :3, :3]
    ortho_err = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = (ortho_err > 10 * tol) | (np.abs(det - 1.0) > 10 * tol)
    if bad.any():
        i = int(np.argmax(bad))
        raise fail(
            where,
            f"'{field}'[{i}] rotation is not rigid (|R R^T - I| = {ortho_err[i]:.3g}, det = {det[i]:.3g})",
            "Poses must be rotations plus translations, without scale or reflection",
        )
    return c2w.astype(np.float32)


def check_intrinsics(K: np.ndarray, where: str, field: str, width: int, height: int) -> np.ndarray:
    """Validate a (3, 3) or (N, 3, 3) pinhole matrix of ``width`` x ``height`` images (its
    principal point no further outside the image than half its size); return it as float32."""
    K = _array(K, where, field)
    if K.dtype.kind not in "fiu" or K.shape[-2:] != (3, 3) or K.ndim not in (2, 3):
        raise fail(where, f"'{field}' has shape {K.shape} and dtype {K.dtype}, expected a 3x3 float matrix")
    if not np.isfinite(K).all() or np.abs(K).max(initial=0.0) > MAX_COORD:
        raise fail(where, f"'{field}' has NaN or inf values (or values beyond {MAX_COORD:g})")
    Ks = K.reshape(-1, 3, 3)
    if (Ks[:, 0, 0] <= 0).any() or (Ks[:, 1, 1] <= 0).any():
        raise fail(where, f"'{field}' has a zero or negative focal length", "fx and fy must be positive pixels")
    if (
        not np.allclose(Ks[:, 2], [0, 0, 1])
        or not np.allclose(Ks[:, 1, 0], 0)
        or not np.allclose(Ks[:, 0, 1], 0, atol=1e-3 * Ks[:, 0, 0].max())
    ):
        raise fail(where, f"'{field}' is not of the form [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
    cx, cy = Ks[:, 0, 2], Ks[:, 1, 2]
    off = (cx < -0.5 * width) | (cx > 1.5 * width) | (cy < -0.5 * height) | (cy > 1.5 * height)
    if off.any():
        i = int(np.argmax(off))
        raise fail(
            where,
            f"'{field}' puts the principal point at ({cx[i]:g}, {cy[i]:g}), far outside the "
            f"{width}x{height} image: intrinsics of images of another size?",
            "fx, fy, cx and cy are pixels of the images as stored: scale them by the images' size over the "
            "size they were calibrated at",
        )
    return K.astype(np.float32)


def check_images(images: np.ndarray, where: str, field: str) -> np.ndarray:
    """Validate (N, H, W, 3) images; return them as uint8.

    Float images must lie in [0, 1]; uint8 are taken as they are.
    """
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3:
        hint = "Composite RGBA onto a background first" if images.ndim == 4 and images.shape[-1] == 4 else None
        raise fail(where, f"'{field}' has shape {images.shape}, expected (N, H, W, 3) RGB images", hint)
    if images.shape[0] == 0 or images.shape[1] == 0 or images.shape[2] == 0:
        raise fail(where, f"'{field}' is empty (shape {images.shape})")
    if images.dtype == np.uint8:
        return images
    if images.dtype.kind == "f":
        if not np.isfinite(images).all():
            raise fail(where, f"'{field}' has NaN or inf pixels")
        lo, hi = float(images.min()), float(images.max())
        if lo < 0.0 or hi > 1.0:
            raise fail(
                where,
                f"'{field}' float pixels span [{lo:.3g}, {hi:.3g}], expected [0, 1]",
                "Store images as uint8 0-255 or float 0-1",
            )
        return (images * 255.0 + 0.5).astype(np.uint8)
    raise fail(where, f"'{field}' has dtype {images.dtype}, expected uint8 (0-255) or float (0-1)")


def check_near_far(near: Any, far: Any, where: str) -> tuple[float, float]:
    """``near`` and ``far`` (numbers, or any JSON value to refuse) as finite floats, 0 <= near < far."""
    try:
        near, far = float(near), float(far)
    except (TypeError, ValueError, OverflowError):
        raise fail(where, f"near/far must be numbers, got near={short_repr(near)}, far={short_repr(far)}") from None
    if not (np.isfinite(near) and np.isfinite(far)):
        raise fail(where, f"near/far must be finite, got near={near}, far={far}")
    if near < 0 or near >= far:
        raise fail(where, f"near={near} and far={far}: need 0 <= near < far", "Fix the depth range of the scene")
    return float(near), float(far)


def near_far_from_cameras(c2w: np.ndarray, center: np.ndarray, where: str, fix: str) -> tuple[float, float]:
    """:func:`~nerfkit.data.scene.estimate_near_far`, refused when the cameras give no depth range."""
    near, far = estimate_near_far(c2w, center)
    if not (np.isfinite(near) and np.isfinite(far) and 0 <= near < far):
        raise fail(
            where,
            f"cannot estimate near/far from the cameras (got {near:.3g}, {far:.3g}: do they all sit at one spot?)",
            fix,
        )
    return near, far


def check_vector3(v, where: str, field: str, unit: bool = False) -> np.ndarray:
    """A finite (3,) vector as float32 (normalised when ``unit``)."""
    a = _array(v, where, field)
    if a.dtype.kind not in "fiu" or a.size != 3:
        raise fail(where, f"'{field}' must be 3 numbers, got shape {a.shape} dtype {a.dtype}")
    a = a.astype(np.float64).reshape(3)
    if not (np.isfinite(a).all() and np.abs(a).max() <= MAX_COORD):
        raise fail(where, f"'{field}' is {a.tolist()}, expected finite numbers")
    if unit:
        n = float(np.linalg.norm(a))
        if n < 1e-8:
            raise fail(where, f"'{field}' is the zero vector, expected a direction")
        a = a / n
    return a.astype(np.float32)


def check_plane(v, where: str, field: str) -> np.ndarray:
    """A plane ``(nx, ny, nz, d)`` (``n . x + d = 0``) as float32 with a unit normal."""
    a = _array(v, where, field)
    if a.dtype.kind not in "fiu" or a.size != 4:
        raise fail(where, f"'{field}' must be 4 numbers (nx, ny, nz, d), got shape {a.shape} dtype {a.dtype}")
    a = a.astype(np.float64).reshape(4)
    n = float(np.linalg.norm(a[:3]))
    if not (np.isfinite(a).all() and np.abs(a).max() <= MAX_COORD) or n < 1e-8:
        raise fail(where, f"'{field}' is {a.tolist()}, expected a finite plane with a non-zero normal")
    return (a / n).astype(np.float32)


# the largest coordinate or depth a scene may hold, in its own units: float32 training (a
# 1e13-unit scene's grid divided by zero) has no precision left for detail far beyond it
MAX_EXTENT = 1e7


def check_extent(scene, where: str) -> None:
    """Refuse a scene whose cameras, centre or depth range reach past :data:`MAX_EXTENT`."""
    reach = max(
        [float(scene.far), float(np.abs(np.asarray(scene.center, np.float64)).max())]
        + [float(np.abs(np.asarray(v.c2w, np.float64)[:, :3, 3]).max()) for v in scene.splits.values() if len(v)]
    )
    if reach > MAX_EXTENT:
        raise fail(
            where,
            f"its cameras or depth range reach {reach:.3g} units from the origin (at most {MAX_EXTENT:.0e} train "
            "in float32)",
            "Move the scene to the origin and scale it down: its units are yours to choose",
        )


def check_scene(scene, where: str | None = None, need: str = "train"):
    """Check a loaded :class:`~nerfkit.data.scene.Scene` end to end; return it unchanged.

    Every loader calls this last, so no format can hand the trainer NaN poses, a
    non-positive focal length, near >= far, or images that disagree with their cameras.
    """
    where = str(where or scene.source or "dataset")
    if len(scene.splits[need]) == 0:
        if need == "train":
            raise fail(where, "has no training views")
        other = scene.split_with_images(need)
        raise fail(where, f"has no {need} views", f"Choose a split that has (--split {other})" if other else None)
    for split, v in scene.splits.items():
        n = len(v)
        if not (
            isinstance(v.width, (int, np.integer))
            and isinstance(v.height, (int, np.integer))
            and v.width > 0
            and v.height > 0
        ):
            raise fail(where, f"the {split} views have image size {v.width}x{v.height}, expected positive pixels")
        if n == 0:
            continue
        check_poses(v.c2w, where, f"{split} poses")
        K = check_intrinsics(v.K, where, f"{split} intrinsics", int(v.width), int(v.height))
        if K.shape != (n, 3, 3):
            raise fail(where, f"the {split} split has {n} poses but intrinsics of shape {K.shape}")
        if v.images is not None and v.images.size > 0:
            im = v.images
            if im.dtype != np.uint8 or im.shape != (n, v.height, v.width, 3):
                raise fail(
                    where,
                    f"the {split} images are {im.shape} {im.dtype}, expected ({n}, {v.height}, {v.width}, 3) uint8",
                )
        if v.names is not None and len(v.names) != n:
            raise fail(where, f"the {split} split has {n} views but {len(v.names)} names")
    check_near_far(scene.near, scene.far, where)
    check_extent(scene, where)
    check_vector3(scene.center, where, "center")
    up = check_vector3(scene.up, where, "up")
    if abs(float(np.linalg.norm(up)) - 1.0) > 1e-3:
        raise fail(where, f"'up' {up.tolist()} is not a unit vector")
    if scene.table is not None:
        scene.table = check_plane(scene.table, where, "table_plane")
    if scene.points is not None:
        scene.points, scene.point_colors = check_points(scene.points, scene.point_colors, where)
    if scene.point_views is not None:
        scene.point_views = check_point_views(
            scene.point_views, where, 0 if scene.points is None else len(scene.points), len(scene.train)
        )
    if scene.tags is not None:
        scene.tags = check_tags(scene.tags, where)
    return scene


def check_within_reach(
    c2w: np.ndarray, center: np.ndarray, near: float, far: float, where: str, field: str = "center"
) -> None:
    """Refuse a stated ``center`` (3,) (the file's ``field``) that no ray reaches: the object's
    sphere about it is at most half the depth range across, so when every camera (``c2w``
    (n, 4, 4)) is farther from the centre than ``far`` plus that, every ray ends before the
    object and training learns nothing."""
    if len(c2w) == 0:
        return
    dist = np.linalg.norm(np.asarray(c2w, np.float64)[:, :3, 3] - np.asarray(center, np.float64), axis=1)
    if float(dist.min()) > far + 0.5 * (far - near):
        raise fail(
            where,
            f"'{field}' {np.round(center, 4).tolist()} is {float(dist.min()):.4g} or more from every camera, but "
            f"rays end at far = {far:.4g}: no ray reaches the object",
            f"Store the object's centre as '{field}' (or leave it out to have it estimated), or a larger 'far'",
        )


def check_point_views(v, where: str, n_points: int, n_train: int, field: str = "points_train_views") -> np.ndarray:
    """Which train views saw which sparse point: (k, 2) integer rows ``(point, train view)``
    within ``n_points`` and ``n_train``, as int32."""
    a = _array(v, where, field)
    if a.dtype.kind not in "iu" or a.ndim != 2 or a.shape[1] != 2:
        raise fail(where, f"'{field}' must be (k, 2) integers (point, train view), got shape {a.shape} dtype {a.dtype}")
    if a.size and (a.min() < 0 or a[:, 0].max() >= n_points or a[:, 1].max() >= n_train):
        raise fail(
            where,
            f"'{field}' names points or train views the dataset does not have ({n_points} points, "
            f"{n_train} train views)",
            "Write the dataset again (nerfkit poses or nerfkit dataset)",
        )
    return a.astype(np.int32)


def check_tags(v, where: str, field: str = "tags") -> np.ndarray:
    """The printed tags' corners, (n, 4, 3) finite numbers with n >= 1, as float32."""
    a = _array(v, where, field)
    if a.dtype.kind not in "fiu" or a.ndim != 3 or a.shape[1:] != (4, 3) or len(a) == 0:
        raise fail(
            where,
            f"'{field}' must be (n, 4, 3) numbers (each printed tag's corners), got shape {a.shape} dtype {a.dtype}",
        )
    if not (np.isfinite(a).all() and np.abs(a).max() <= MAX_COORD):
        raise fail(where, f"'{field}' holds non-finite or huge coordinates")
    return a.astype(np.float32)


def check_points(xyz, rgb, where: str, field: str = "points") -> tuple[np.ndarray, np.ndarray]:
    """Sparse points ``xyz`` (m, 3) finite, and their colours ``rgb`` (m, 3) uint8 (None:
    grey), as float32 and uint8 arrays."""
    a = _array(xyz, where, field)
    if a.dtype.kind not in "fiu" or a.ndim != 2 or a.shape[1] != 3:
        raise fail(where, f"'{field}' must be (m, 3) numbers, got shape {a.shape} dtype {a.dtype}")
    if not (np.isfinite(a).all() and (a.size == 0 or np.abs(a).max() <= MAX_COORD)):
        raise fail(where, f"'{field}' holds non-finite or huge coordinates")
    if rgb is None:
        c = np.full(a.shape, 128, np.uint8)
    else:
        c = _array(rgb, where, f"{field} colours")
        if c.shape != a.shape or c.dtype.kind not in "iu" or (c.size and (c.min() < 0 or c.max() > 255)):
            raise fail(
                where,
                f"the colours of '{field}' must be {a.shape} integers in 0..255, got shape {c.shape} dtype {c.dtype}",
            )
    return a.astype(np.float32), c.astype(np.uint8)
