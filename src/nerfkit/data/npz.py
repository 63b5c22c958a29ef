"""The course's npz layout, read and written.

Keys (all arrays, no pickles)::

    images_train (N, H, W, 3) uint8     c2ws_train (N, 4, 4)   required
    images_val   (M, H, W, 3) uint8     c2ws_val   (M, 4, 4)   optional, together
    c2ws_test    (T, 4, 4)                                     optional (render path)
    focal ()     or  K (3, 3)                                  one is required
    near (), far (), images_test, names_train/val/test (str)   optional (nerfkit's)
    capture () (1: real photos), table_plane (4,) (nx, ny, nz, d)  optional (nerfkit's)
    points_xyz (P, 3), points_rgb (P, 3) uint8 (sparse 3D points)  optional (nerfkit's)
    points_train_views (k, 2) int (point, train view that saw it)  optional (nerfkit's)
    tags (n, 4, 3) (corners of the printed tags on the table)      optional (nerfkit's)

``focal`` alone means ``fx = fy = focal``, ``cx = W / 2``, ``cy = H / 2``.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from ..errors import NerfkitError, fail
from ..io.atomic import write_npz
from ..io.paths import refuse_special_file
from .scene import Scene, Views, estimate_center, estimate_up
from .validate import (
    MAX_PIXELS,
    check_images,
    check_intrinsics,
    check_near_far,
    check_plane,
    check_poses,
    check_scene,
    check_vector3,
    check_within_reach,
    near_far_from_cameras,
)

SPLITS = ("train", "val", "test")


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    """Read every array of an npz without pickles, refusing headers that lie about size."""
    where = str(path)
    if not path.exists():
        raise fail(where, "no such file", "Check the path")
    if path.is_dir():
        raise fail(where, "is a folder, expected an .npz file")
    refuse_special_file(path)
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as e:
        raise fail(where, f"not a valid .npz file ({e})", "Create it with numpy.savez") from None
    arrays: dict[str, np.ndarray] = {}
    with zf:
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            key = info.filename[:-4]
            try:
                with zf.open(info) as f:
                    version = np.lib.format.read_magic(f)
                    read_header = (
                        np.lib.format.read_array_header_1_0
                        if version == (1, 0)
                        else np.lib.format.read_array_header_2_0
                    )
                    shape, _, dtype = read_header(f)
                    if dtype.hasobject:
                        raise fail(
                            where,
                            f"'{key}' is an object array (pickled data)",
                            "nerfkit never loads pickles; store plain numeric or string arrays",
                        )
                    n_bytes = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
                    if n_bytes > info.file_size or n_bytes > MAX_PIXELS * 3:
                        raise fail(
                            where,
                            f"'{key}' declares shape {shape} ({n_bytes} bytes) but holds {info.file_size} bytes",
                            "The file is truncated or corrupt; re-export it",
                        )
                with zf.open(info) as f:
                    arrays[key] = np.lib.format.read_array(f, allow_pickle=False)
            except NerfkitError:
                raise
            except Exception as e:  # corrupt member: zlib, header, or short read
                raise fail(
                    where,
                    f"cannot read array '{key}' ({type(e).__name__}: {e})",
                    "The file is truncated or corrupt; re-export it",
                ) from None
    if not arrays:
        raise fail(where, "holds no arrays", "Expected the course layout: images_train, c2ws_train, focal, ...")
    return arrays


def _scalar(arrays: dict, key: str, where: str) -> float:
    a = arrays[key]
    if a.dtype.kind not in "fiu" or a.size != 1:
        raise fail(where, f"'{key}' must be a single number, got shape {a.shape} dtype {a.dtype}")
    v = float(a.reshape(()))
    if not np.isfinite(v):
        raise fail(where, f"'{key}' is {v}")
    return v


def _names(arrays: dict, split: str, n: int, where: str) -> list[str] | None:
    key = f"names_{split}"
    if key not in arrays:
        return None
    a = arrays[key]
    if a.dtype.kind not in "US" or a.shape != (n,):
        raise fail(where, f"'{key}' must be {n} strings, got shape {a.shape} dtype {a.dtype}")
    return [s.decode("utf-8", "replace") if isinstance(s, bytes) else str(s) for s in a.tolist()]


def load_npz(path: str | Path, need: str = "train") -> Scene:
    """Load a course-layout npz into a :class:`Scene`, validating every field.

    ``need`` is the split that must be there: ``train`` normally; a file of held-out views
    (only ``images_test``, ``c2ws_test`` and ``focal``) loads with ``need="test"``.
    """
    path = Path(path)
    where = str(path)
    arrays = _read_npz(path)
    base = "train" if need == "train" or "c2ws_train" in arrays else need
    for key in (f"images_{base}", f"c2ws_{base}"):
        if key not in arrays:
            raise fail(
                where,
                f"missing key '{key}' (found: {', '.join(sorted(arrays))})",
                "Expected the course layout: images_train, c2ws_train, images_val, c2ws_val, c2ws_test, focal",
            )
    train_images = check_images(arrays[f"images_{base}"], where, f"images_{base}")
    n, h, w, _ = train_images.shape
    if n * h * w > MAX_PIXELS:
        raise fail(where, f"images_{base} holds {n * h * w} pixels, more than nerfkit loads at once")

    if "K" in arrays:
        K = check_intrinsics(arrays["K"], where, "K", w, h)
    elif "focal" in arrays:
        focal = _scalar(arrays, "focal", where)
        if focal <= 0:
            raise fail(where, f"'focal' is {focal}, must be positive (pixels)")
        K = check_intrinsics(np.array([[focal, 0, w / 2], [0, focal, h / 2], [0, 0, 1]]), where, "focal", w, h)
    else:
        raise fail(where, "missing 'focal' (or 'K')", "Add the focal length in pixels as 'focal' or a 3x3 'K'")

    def views(split: str) -> Views:
        img_key, pose_key = f"images_{split}", f"c2ws_{split}"
        if img_key in arrays and pose_key not in arrays:
            raise fail(where, f"'{img_key}' is present but '{pose_key}' is missing")
        if pose_key not in arrays:
            return Views.empty(w, h)
        c2w = check_poses(arrays[pose_key], where, pose_key)
        images = None
        if img_key in arrays and arrays[img_key].size > 0:
            images = check_images(arrays[img_key], where, img_key)
            if images.shape[0] != c2w.shape[0]:
                raise fail(where, f"'{img_key}' has {images.shape[0]} images but '{pose_key}' has {c2w.shape[0]} poses")
            if images.shape[1:3] != (h, w):
                raise fail(
                    where,
                    f"'{img_key}' images are {images.shape[2]}x{images.shape[1]}, but training images are {w}x{h}",
                )
        Ks = np.broadcast_to(K, (c2w.shape[0], 3, 3)).astype(np.float32).copy() if K.ndim == 2 else K
        if Ks.shape[0] != c2w.shape[0]:
            raise fail(where, f"'K' has {Ks.shape[0]} matrices but '{pose_key}' has {c2w.shape[0]} poses")
        return Views(c2w, Ks, w, h, images, _names(arrays, split, c2w.shape[0], where))

    if K.ndim == 3 and K.shape[0] != n:
        raise fail(where, "a per-view 'K' of shape (N, 3, 3) is only supported for the train split; store one 3x3 K")
    train, val, test = views("train"), views("val"), views("test")
    ref = views(base)
    center = estimate_center(ref.c2w)
    up = estimate_up(ref.c2w)
    if "near" in arrays or "far" in arrays:
        if not ("near" in arrays and "far" in arrays):
            raise fail(where, "has only one of 'near' and 'far'", "Store both or neither")
        near, far = check_near_far(_scalar(arrays, "near", where), _scalar(arrays, "far", where), where)
    else:
        near, far = near_far_from_cameras(ref.c2w, center, where, "Store the depth range as 'near' and 'far'")
    if "center" in arrays:  # given, not estimated from the cameras: it must lie where rays reach
        center = check_vector3(arrays["center"], where, "center")
        check_within_reach(ref.c2w, center, near, far, where)
    if "up" in arrays:
        up = check_vector3(arrays["up"], where, "up", unit=True)
    capture = bool(_scalar(arrays, "capture", where)) if "capture" in arrays else False
    table = check_plane(arrays["table_plane"], where, "table_plane") if "table_plane" in arrays else None
    points = arrays.get("points_xyz")
    colors = arrays.get("points_rgb")
    if colors is not None and points is None:
        raise fail(where, "'points_rgb' is present but 'points_xyz' is missing")
    seen = arrays.get("points_train_views")
    if seen is not None and points is None:
        raise fail(where, "'points_train_views' is present but 'points_xyz' is missing")
    return check_scene(
        Scene(
            train,
            val,
            test,
            near,
            far,
            center,
            up,
            source=where,
            capture=capture,
            table=table,
            points=points,
            point_colors=colors,
            tags=arrays.get("tags"),
            point_views=seen,
        ),
        need=need,
    )


def save_npz(scene: Scene, path: str | Path) -> None:
    """Write a scene in the course layout plus nerfkit's optional keys (atomically)."""
    K = scene.train.K[0]
    size = (scene.train.width, scene.train.height)
    for split, v in scene.splits.items():
        if len(v) and v.has_images and (v.width, v.height) != size:
            raise fail(
                path,
                f"the {split} images are {v.width}x{v.height}, the training images {size[0]}x{size[1]}",
                "The course npz holds one image size; export to transforms.json instead, or resample the images",
            )
        if len(v) and not np.allclose(v.K, K, rtol=1e-5, atol=1e-4):
            raise fail(
                path,
                f"the {split} views have intrinsics that differ from the first training view",
                "The course npz holds one K; export to transforms.json instead, or resample the images",
            )
    out: dict[str, np.ndarray | np.generic] = {
        "focal": np.float32(K[0, 0]),
        "K": K.astype(np.float32),
        "near": np.float32(scene.near),
        "far": np.float32(scene.far),
        "center": np.asarray(scene.center, np.float32),
        "up": np.asarray(scene.up, np.float32),
    }
    if scene.capture:
        out["capture"] = np.uint8(1)
    if scene.table is not None:
        out["table_plane"] = np.asarray(scene.table, np.float32)
    if scene.points is not None:
        out["points_xyz"] = np.asarray(scene.points, np.float32)
        out["points_rgb"] = (
            np.full(out["points_xyz"].shape, 128, np.uint8)
            if scene.point_colors is None
            else np.asarray(scene.point_colors, np.uint8)
        )
        if scene.point_views is not None:
            out["points_train_views"] = np.asarray(scene.point_views, np.int32)
    if scene.tags is not None:
        out["tags"] = np.asarray(scene.tags, np.float32)
    for split, v in scene.splits.items():
        if len(v) == 0 and split != "train":
            continue
        out[f"c2ws_{split}"] = v.c2w.astype(np.float32)
        if v.images is not None:
            out[f"images_{split}"] = v.images
        if v.names is not None:
            out[f"names_{split}"] = np.array(v.names, dtype=str)
    write_npz(path, **out)
