"""Nerfstudio-style ``transforms.json``, read and written.

Layout (nerfstudio's, plus an optional ``"nerfkit"`` block)::

    {
      "camera_model": "OPENCV",
      "fl_x": 500.0, "fl_y": 500.0, "cx": 320.0, "cy": 240.0, "w": 640, "h": 480,
      "k1": 0, "k2": 0, "p1": 0, "p2": 0,
      "frames": [{"file_path": "images/IMG_0930.JPG", "transform_matrix": [[...4x4...]],
                  "split": "train"}, ...],
      "train_filenames": [...], "val_filenames": [...], "test_filenames": [...],
      "nerfkit": {"near": 0.1, "far": 0.6, "center": [x, y, z], "up": [0, 0, 1], ...}
    }

* ``transform_matrix`` is camera-to-world with **OpenGL** camera axes (+y up, +z backward);
  :func:`nerfkit.cameras.opengl_to_opencv` converts.
* ``cx, cy`` put pixel centres at +0.5, as nerfkit does (OpenCV's are 0.5 smaller).
* Intrinsics may be given per frame (the same keys inside a frame override the top level).
* The split comes from each frame's ``"split"`` (nerfkit), else nerfstudio's
  ``*_filenames`` lists, else every frame is a training view.
* Non-zero distortion (``k1 k2 k3 k4 p1 p2``) is removed on load with OpenCV (with a
  warning); fisheye models are refused.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..cameras import opencv_to_opengl, opengl_to_opencv
from ..config import load_json
from ..errors import fail
from ..io.atomic import atomic_path, refuse_foreign_files, replacing_folder, write_json
from ..io.paths import distinct_names, path_kind, refuse_special_file, resolve_inside, safe_output_name
from .blender import focal_from_angle, frame_image_path
from .ply import read_points_ply, write_points_ply
from .scene import Scene, Views, estimate_center, estimate_up
from .validate import (
    MAX_SIDE,
    check_count,
    check_fov,
    check_intrinsics,
    check_near_far,
    check_number,
    check_plane,
    check_poses,
    check_scene,
    check_vector3,
    check_within_reach,
    near_far_from_cameras,
    short_repr,
)

SPLITS = ("train", "val", "test")
DIST_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
KEEP_SUFFIXES = {".jpg", ".jpeg", ".png"}
POINTS_FILE = "sparse_pc.ply"  # nerfstudio's name for the sparse points


def image_file_name(name: str) -> str:
    """File name for a view named after its photo: the photo's own name when it is a JPEG
    or PNG, else the name plus ``.png`` (``IMG_1.HEIC`` -> ``IMG_1.HEIC.png``). Always a
    plain name (:func:`nerfkit.io.paths.safe_output_name`): a crafted one never leaves the folder."""
    base = safe_output_name(name)
    return base if Path(base).suffix.lower() in KEEP_SUFFIXES else base + ".png"


def _number(d: dict, key: str, where: str, default=None) -> float | None:
    v = d.get(key)
    return default if v is None else check_number(v, where, key)


def _side(d: dict, key: str, where: str) -> int | None:
    """Image width or height ("w", "h"): whole pixels, or None when absent."""
    v = d.get(key)
    return None if v is None else check_count(v, where, key, 1, MAX_SIDE)


def _undistort(image: np.ndarray, K: np.ndarray, dist: dict[str, float], where: str) -> tuple[np.ndarray, np.ndarray]:
    """Remove OpenCV distortion; K and the result use nerfkit's +0.5 pixel convention."""
    import cv2

    h, w = image.shape[:2]
    coeffs = np.array([dist["k1"], dist["k2"], dist["p1"], dist["p2"], dist["k3"]], np.float64)
    K_cv = K.astype(np.float64).copy()
    K_cv[:2, 2] -= 0.5
    try:
        newK, _ = cv2.getOptimalNewCameraMatrix(K_cv, coeffs, (w, h), 0.0, (w, h))
        out = cv2.undistort(image, K_cv, coeffs, None, newK)
    except cv2.error as e:
        raise fail(
            where,
            f"cannot undistort with k1 k2 p1 p2 k3 = {coeffs.tolist()} ({short_repr(str(e))})",
            "Check the distortion coefficients",
        ) from None
    K_new = np.array(newK, dtype=np.float64)
    K_new[:2, 2] += 0.5
    return out, check_intrinsics(K_new, where, "intrinsics after undistortion", w, h).astype(np.float64)


def _intrinsics(cam: dict, image_size: tuple[int, int] | None, where: str) -> tuple[np.ndarray, tuple[int, int]]:
    """A frame's pinhole K and image size from fl_x/fl_y/cx/cy/w/h (or camera_angle_x)."""
    w, h = _side(cam, "w", where), _side(cam, "h", where)
    size = image_size
    if size is None:
        if w is None or h is None:
            raise fail(where, 'needs "w" and "h" when images are not loaded')
        size = (w, h)
    w = size[0] if w is None else w
    h = size[1] if h is None else h
    fx = _number(cam, "fl_x", where)
    if fx is None:
        if cam.get("camera_angle_x") is None:
            raise fail(where, 'no focal length: expected "fl_x" (or "camera_angle_x")')
        fx = focal_from_angle(check_fov(cam["camera_angle_x"], where), w)
    fy = _number(cam, "fl_y", where, fx)
    cx = _number(cam, "cx", where, w / 2.0)
    cy = _number(cam, "cy", where, h / 2.0)
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], np.float64)
    if size != (w, h):
        sx, sy = size[0] / w, size[1] / h
        if abs(sx - sy) > 0.01:
            raise fail(where, f"image is {size[0]}x{size[1]} but w, h say {w}x{h}")
        K[0] *= sx
        K[1] *= sy  # a uniformly downscaled copy (nerfstudio's images_2, ...)
    return check_intrinsics(K, where, "intrinsics", *size).astype(np.float64), size


def _frame_split(fr: dict, by_list: dict[str, str], where: str) -> str | None:
    """The frame's split: its "split", else the *_filenames lists; None when they leave it out."""
    fp = str(fr["file_path"])
    split = fr.get("split")
    if split is None:
        split = by_list.get(fp, by_list.get(fp.lstrip("./"), "train" if not by_list else None))
        if split is None:
            return None  # listed in none of the *_filenames: nerfstudio ignores it too
    if split not in SPLITS:
        raise fail(where, f"split {short_repr(split)} is not one of train, val, test")
    return split


def _read_frame(
    fr,
    data: dict,
    folder: Path,
    by_list: dict[str, str],
    where: str,
    load_images: bool,
    background,
    allow_outside: bool = False,
) -> tuple[str, tuple, bool] | None:
    """(split, (c2w, K, size, image, name), undistorted) of one frame; None when no split lists it."""
    from ..images import load_image_uint8

    if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
        raise fail(where, 'each frame needs "file_path" and "transform_matrix"')
    split = _frame_split(fr, by_list, where)
    if split is None:
        return None
    c2w = opengl_to_opencv(check_poses([fr["transform_matrix"]], where, "transform_matrix")[0].astype(np.float64))
    cam = {
        key: fr.get(key, data.get(key)) for key in ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", *DIST_KEYS)
    }
    fp = str(fr["file_path"])
    image = load_image_uint8(frame_image_path(folder, fp, where, allow_outside), background) if load_images else None
    K, size = _intrinsics(cam, None if image is None else (image.shape[1], image.shape[0]), where)
    dist = {key: (_number(cam, key, where) or 0.0) for key in DIST_KEYS}
    if dist["k4"]:
        raise fail(where, "k4 (a fisheye or rational distortion term) is not supported", "Undistort the images first")
    if any(dist.values()):
        if image is None:
            raise fail(where, "has lens distortion, which nerfkit removes only when it loads the images")
        image, K = _undistort(image, K, dist, where)
    name = fr["name"] if isinstance(fr.get("name"), str) else Path(fp).name
    return split, (c2w, K, size, image, name), any(dist.values())


def _split_lists(data: dict) -> dict[str, str]:
    """File name -> split from nerfstudio's ``*_filenames`` lists."""
    by_list: dict[str, str] = {}
    for s in SPLITS:
        names = data.get(f"{s}_filenames")
        if isinstance(names, list):
            for n in names:
                by_list[str(n)] = s
                by_list[str(Path(str(n)).as_posix()).lstrip("./")] = s
    return by_list


def _stack_views(per_split: dict[str, list], where: str, load_images: bool, need: str = "train") -> dict[str, Views]:
    """Views per split from the frames' (c2w, K, size, image, name); pose-less splits empty."""
    views: dict[str, Views] = {}
    for split, items in per_split.items():
        if not items:
            continue
        sizes = sorted({it[2] for it in items})
        if len(sizes) > 1:
            raise fail(
                where,
                f"the {split} frames have different image sizes {sizes}",
                "nerfkit needs one image size per split; resize the images to one size",
            )
        w, h = sizes[0]
        images = np.stack([it[3] for it in items]) if load_images else None
        views[split] = Views(
            np.stack([it[0] for it in items]).astype(np.float32),
            np.stack([it[1] for it in items]).astype(np.float32),
            w,
            h,
            images,
            [it[4] for it in items],
        )
    if need not in views:
        raise fail(
            where,
            f"has no {'training' if need == 'train' else need} frames",
            f'Mark some frames "split": "{need}" or list them in {need}_filenames',
        )
    ref = views[need]
    for split in SPLITS:
        views.setdefault(split, Views.empty(ref.width, ref.height))
    return views


def _add_pose_only_splits(views: dict[str, Views], nk: dict, where: str, need: str = "train") -> None:
    """Fill empty splits from ``nerfkit.poses_only`` (render paths: poses without images)."""
    poses_only = nk.get("poses_only") or {}
    if not isinstance(poses_only, dict):
        raise fail(
            where,
            f"'nerfkit.poses_only' is {short_repr(poses_only)}, expected an object: split -> list of 4x4 matrices",
            "Fix or re-export the file",
        )
    train = views[need]  # the K and size of the views with images
    for split, mats in poses_only.items():
        if split in SPLITS and len(views[split]) == 0 and mats:
            c2w = opengl_to_opencv(check_poses(mats, where, f"nerfkit.poses_only.{split}").astype(np.float64))
            views[split] = Views(
                c2w.astype(np.float32), np.repeat(train.K[:1], len(c2w), axis=0), train.width, train.height
            )


def _scene_bounds(nk: dict, train: Views, where: str) -> tuple[np.ndarray, np.ndarray, float, float]:
    """center, up, near, far: from the ``nerfkit`` block, else estimated from the cameras."""
    center = check_vector3(nk["center"], where, "nerfkit.center") if "center" in nk else estimate_center(train.c2w)
    up = check_vector3(nk["up"], where, "nerfkit.up", unit=True) if "up" in nk else estimate_up(train.c2w)
    if "near" in nk or "far" in nk:
        near, far = check_near_far(nk.get("near"), nk.get("far"), where)
    else:
        near, far = near_far_from_cameras(train.c2w, center, where, "Store the depth range as nerfkit.near and far")
    if "center" in nk:  # stated, not estimated from the cameras: it must lie where rays reach
        check_within_reach(train.c2w, center, near, far, where, "nerfkit.center")
    return center.astype(np.float32), up.astype(np.float32), near, far


def load_transforms_json(
    path: str | Path,
    load_images: bool = True,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    allow_outside: bool = False,
    need: str = "train",
) -> Scene:
    """Read a nerfstudio-style transforms.json (or a folder holding one) into a Scene.

    ``background`` (RGB in [0, 1]) goes under transparent pixels of RGBA images; images
    outside the file's folder are refused unless ``allow_outside``; ``need`` is the split
    that must have frames.
    """
    path = Path(path)
    if path_kind(path) == "dir":
        path = path / "transforms.json"
    where = str(path)
    data = load_json(
        path, "no such file", "Expected a nerfstudio transforms.json", "The file may be truncated; re-export it"
    )
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list) or not data["frames"]:
        raise fail(where, 'expected an object with a non-empty "frames" list')
    model = str(data.get("camera_model", "OPENCV")).upper()
    if model not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        raise fail(
            where,
            f"camera_model {model[:40]} is not supported",
            "Undistort the images first (e.g. with nerfstudio's ns-process-data) and use OPENCV/PINHOLE",
        )
    nk = data.get("nerfkit") or {}
    if not isinstance(nk, dict):
        raise fail(where, f"'nerfkit' is {short_repr(nk)}, expected an object", "Fix or re-export the file")

    by_list = _split_lists(data)
    per_split: dict[str, list] = {s: [] for s in SPLITS}
    undistorted = 0
    for k, fr in enumerate(data["frames"]):
        frame = _read_frame(
            fr, data, path.parent, by_list, f"{where} frames[{k}]", load_images, background, allow_outside
        )
        if frame is not None:
            split, item, was_distorted = frame
            per_split[split].append(item)
            undistorted += was_distorted
    if undistorted:
        warnings.warn(
            f"{where}: {undistorted} frames have lens distortion (k1 k2 p1 p2 ...); nerfkit undistorted "
            "them on load (pinhole K updated). Undistort once beforehand to avoid this each time",
            stacklevel=2,
        )

    views = _stack_views(per_split, where, load_images, need)
    _add_pose_only_splits(views, nk, where, need)
    center, up, near, far = _scene_bounds(nk, views["train"] if len(views["train"]) else views[need], where)
    table = check_plane(nk["table_plane"], where, "nerfkit.table_plane") if nk.get("table_plane") is not None else None
    points, colors = _read_points(data, path.parent, where, allow_outside)
    return check_scene(
        Scene(
            views["train"],
            views["val"],
            views["test"],
            near,
            far,
            center,
            up,
            source=where,
            capture=nk.get("capture") is True,
            table=table,
            points=points,
            point_colors=colors,
            tags=nk.get("tags"),
        ),
        need=need,
    )


def _read_points(data: dict, folder: Path, where: str, allow_outside: bool) -> tuple[np.ndarray | None, ...]:
    """The sparse points of nerfstudio's ``ply_file_path`` (e.g. ``sparse_pc.ply``), if any."""
    rel = data.get("ply_file_path")
    if rel is None:
        return None, None
    if not isinstance(rel, str):
        raise fail(where, f"'ply_file_path' is {short_repr(rel)}, expected a file name")
    path = refuse_special_file(resolve_inside(folder, rel, allow_outside, where))
    if not path.is_file():
        raise fail(
            where,
            f"'ply_file_path' names {rel[:200]!r}, which does not exist",
            "Remove the key or put the point cloud beside transforms.json",
        )
    return read_points_ply(path, f"{where} ply_file_path {rel[:200]}")


def _save_image(path: Path, image: np.ndarray, jpeg_quality: int) -> None:
    from PIL import Image

    with atomic_path(path) as tmp:
        if path.suffix.lower() in (".jpg", ".jpeg"):
            # full-resolution colour (4:4:4): 4:2:0 lost a few dB of each view's colour edges
            Image.fromarray(image).save(tmp, format="JPEG", quality=jpeg_quality, subsampling=0)
        else:
            Image.fromarray(image).save(tmp, format="PNG")


def named_paths(path: Path) -> list[str]:
    """The file paths, as written, that the transforms file at ``path`` names: its frames'
    ``file_path`` and its ``ply_file_path``; none when it cannot be read."""
    import json

    try:
        data = json.loads(path.read_text())
        frames = [f for f in data.get("frames", []) if isinstance(f, dict)]
        ply = data.get("ply_file_path")
    except (OSError, ValueError, TypeError, AttributeError):
        return []
    return [str(f["file_path"]) for f in frames if "file_path" in f] + ([ply] if isinstance(ply, str) else [])


def written_images(path: Path, image_dir: str) -> list[str]:
    """The files of ``image_dir`` (relative to it) that the transforms.json at ``path``, an
    earlier one nerfkit wrote, names (:func:`named_paths`)."""
    prefix = Path(image_dir).as_posix().rstrip("/") + "/"
    return [p[len(prefix) :] for p in named_paths(path) if p.startswith(prefix)]


def write_transforms_json(
    scene: Scene,
    folder: str | Path,
    write_images: bool = True,
    jpeg_quality: int = 95,
    image_dir: str = "images",
    extra: dict | None = None,
) -> Path:
    """Write ``folder/transforms.json`` (and the views' images into ``folder/image_dir``, a
    subfolder written afresh: an earlier one is replaced whole, not added to).

    Each view's file is named after ``Views.names`` (see :func:`image_file_name`), else
    ``<split>_<index>.png``. Splits without images are stored as poses only under
    ``nerfkit.poses_only``. Returns the path of transforms.json.
    """
    folder = Path(folder)
    if write_images and Path(image_dir).name in ("", ".", ".."):
        raise ValueError(f"image_dir must name a subfolder, not {image_dir!r}")
    frames, poses_only = [], {}
    lists: dict[str, list[str]] = {s: [] for s in SPLITS}
    Ks, sizes = [], []
    seen: set[str] = set()
    to_write = []  # (file name, image)
    named = [
        (split, v.names[i] if v.names is not None else f"{split}_{i:04d}.png")
        for split, v in scene.splits.items()
        if len(v) and v.has_images
        for i in range(len(v))
    ]
    flat = iter(distinct_names(named))  # (Blender's train/r_0 and val/r_0 would both be r_0)
    for split, v in scene.splits.items():
        if len(v) == 0:
            continue
        if not v.has_images:
            poses_only[split] = opencv_to_opengl(v.c2w.astype(np.float64)).tolist()
            continue
        assert v.images is not None  # has_images
        for i in range(len(v)):
            name = v.names[i] if v.names is not None else f"{split}_{i:04d}.png"
            fname = image_file_name(next(flat))
            if fname in seen:
                raise fail(folder, f"two views would both be written as '{fname}'", "Give the views distinct names")
            seen.add(fname)
            rel = f"{image_dir}/{fname}"
            to_write.append((fname, v.images[i]))
            frames.append(
                {
                    "file_path": rel,
                    "transform_matrix": opencv_to_opengl(v.c2w[i].astype(np.float64)).tolist(),
                    "split": split,
                    "name": name,
                }
            )
            lists[split].append(rel)
            Ks.append(v.K[i].astype(np.float64))
            sizes.append((v.width, v.height))
    if not frames:
        raise fail(folder, "the scene has no views with images to write")
    if write_images:
        refuse_foreign_files(folder / image_dir, written_images(folder / "transforms.json", image_dir))
        with replacing_folder(folder / image_dir) as images:
            for fname, image in to_write:
                _save_image(images / fname, image, jpeg_quality)
    shared = all(np.allclose(K, Ks[0], rtol=1e-6, atol=1e-6) for K in Ks) and len(set(sizes)) == 1

    def intr(K: np.ndarray, size: tuple[int, int]) -> dict:
        return {
            "fl_x": float(K[0, 0]),
            "fl_y": float(K[1, 1]),
            "cx": float(K[0, 2]),
            "cy": float(K[1, 2]),
            "w": int(size[0]),
            "h": int(size[1]),
        }

    out: dict = {"camera_model": "OPENCV"}
    if shared:
        out.update(intr(Ks[0], sizes[0]))
    else:
        for fr, K, size in zip(frames, Ks, sizes):
            fr.update(intr(K, size))
    out.update({"k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0})
    out["frames"] = frames
    for s in SPLITS:
        out[f"{s}_filenames"] = lists[s]
    nk = {
        "near": float(scene.near),
        "far": float(scene.far),
        "center": [float(c) for c in scene.center],
        "up": [float(u) for u in scene.up],
        "convention": "transform_matrix: camera-to-world, OpenGL camera axes; cx, cy: pixel centres at +0.5",
        "capture": bool(scene.capture),
        "table_plane": None if scene.table is None else [float(v) for v in scene.table],
    }
    if scene.tags is not None:
        nk["tags"] = np.round(np.asarray(scene.tags, np.float64), 7).tolist()
    if poses_only:
        nk["poses_only"] = poses_only
    out["nerfkit"] = {**(extra or {}), **nk}  # the scene's own values win over extra's
    if scene.points is not None:  # nerfstudio's key for the sparse points (3DGS initialisation)
        out["ply_file_path"] = POINTS_FILE
        write_points_ply(folder / POINTS_FILE, scene.points, scene.point_colors)
    path = folder / "transforms.json"
    write_json(path, out)
    return path


def is_transforms_json(path: str | Path) -> bool:
    """True for a transforms.json file or a folder holding one (cheap check for loaders)."""
    path = Path(path)
    return (path.is_file() and path.name.endswith(".json") and path.name.startswith("transforms")) or (
        path.is_dir() and (path / "transforms.json").is_file()
    )


def nerfkit_block(folder: str | Path) -> dict | None:
    """The ``nerfkit`` object of ``folder/transforms.json`` (what a dataset nerfkit built
    records: capture, tag size, pose choice...), or None when there is no such file, it is
    unreadable, or it has no such object (for hints: loading the dataset checks the file
    properly). A pipe or device there is refused, as everywhere."""
    import json

    try:
        meta = json.loads(refuse_special_file(Path(folder) / "transforms.json").read_text()).get("nerfkit")
    except (OSError, ValueError, AttributeError):
        return None
    return meta if isinstance(meta, dict) else None
