"""Posed photos -> a NeRF dataset: undistort, crop, resize, split, bounds, write.

Writes into the dataset folder:

* ``images/<photo name>``: undistorted, cropped, resized views (JPEG/PNG photos keep
  their file name; other formats get ``.png`` appended);
* ``transforms.json``: nerfstudio layout (see :mod:`nerfkit.data.nerfstudio`);
* ``dataset.npz``: the course layout with ``K``, ``near``, ``far``, ``center``, ``up`` and
  ``names_*`` (each view's photo file name);
* ``coverage.png``: where the photos look from, seen from above, with the widest gap among
  them (:mod:`nerfkit.capture.coverage`; ``transforms.json`` keeps the figures, and how well
  the photos agree on the table, :mod:`nerfkit.capture.agreement`);
* ``poses.json`` (written by ``nerfkit poses``) is the input: every photo's pose or the
  reason it has none, the camera, and the tag settings, so ``nerfkit dataset`` can
  rebuild the dataset with other options without re-detecting.

This module is where OpenCV pixel coordinates become nerfkit's (+0.5).
"""

from __future__ import annotations

import json
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..cameras import pixel_to_ray, plane_hit
from ..config import MIN_RESAMPLED_SIDE, load_json, option
from ..data.nerfstudio import write_transforms_json
from ..data.npz import save_npz
from ..data.scene import Scene, Views, estimate_center, point_views
from ..data.validate import MAX_SIDE, check_count, check_points, check_poses, check_scene, short_repr
from ..errors import advice, fail
from ..images import common_size
from ..io.atomic import write_json
from ..io.paths import resolve_inside
from ..scene_extent import FEW_TRAIN_VIEWS, MIN_OBJECT_POINTS, inside_quads, object_box, object_points, sphere_radius
from .aruco import quad_sides
from .camera import Camera, camera_from_dict, nerfkit_K
from .poses import UP, PosedPhoto
from .undistort import make_undistorter, output_size, resize_K_nerfkit

if TYPE_CHECKING:  # pragma: no cover
    from ..data.colmap import SparsePoints
    from .agreement import Agreement

POSES_FILE = "poses.json"
NPZ_FILE = "dataset.npz"
# the chart of where the photos look from
COVERAGE_PLOT = "coverage.png"
# what z = 0 is in a dataset posed in the tags' frame (its summary's table_from)
TAG_PLANE = "the tags' plane, z = 0"
# What build_dataset writes into its folder (checked with nerfkit.io.paths.guard_outputs).
DATASET_OUTPUTS = (NPZ_FILE, "transforms.json", "images", "sparse_pc.ply", COVERAGE_PLOT)


@dataclass
class DatasetConfig:
    """Options of the dataset step (``nerfkit dataset``, and ``nerfkit poses``)."""

    max_side: int = option(
        512,
        "downscale views so the longer side is at most this many pixels (0: keep size)",
        min=MIN_RESAMPLED_SIDE,
        off=0,
    )
    val_every: int = option(10, "every Nth posed photo (in name order) goes to the val split (0: none)", min=0)
    test_every: int = option(10, "every Nth posed photo goes to the test split, offset from val (0: none)", min=0)
    center: str = option(
        "", "object centre 'x,y,z' in the tag frame (metres); default: the point the cameras look at", metavar="X,Y,Z"
    )
    near: float | None = option(None, "near bound along rays (default: from the cameras and the tag size)", above=0)
    far: float | None = option(None, "far bound along rays (default: from the cameras and the tag size)", above=0)
    jpeg_quality: int = option(95, "JPEG quality of the written views", min=1, max=100)
    points: bool = option(
        True,
        "triangulate sparse 3D points from the train views with the poses held (COLMAP's "
        "point triangulator; they initialise --model splat). Needs pycolmap",
    )


def few_views_note(n_train: int) -> str | None:
    """A note for the user when a capture leaves fewer than ``FEW_TRAIN_VIEWS`` photos to
    train on, else None."""
    if n_train >= FEW_TRAIN_VIEWS:
        return None
    return (
        f"note: {n_train} training photos. A NeRF from this few blurs and blotches what only one or two "
        "of them see (with 20 training photos a capture's held-out views lose several dB against 40); 50-100 "
        "photos around the object, at two or three heights, do better. Where no floor shows past the table's "
        'edge, `nerfkit train` holds the table to "table or not", which clears part of its blotches '
        "(--table-cover-weight)"
    )


def no_object_note(n_object: int | None, points: int) -> str | None:
    """A note for the user when the sparse points show no object standing on the table
    (``n_object`` of ``points`` above it; None: not counted), else None."""
    if n_object is None or not points or n_object >= MIN_OBJECT_POINTS:
        return None
    return (
        f"note: the sparse points show no object near the middle of the photos (only {n_object} of the "
        f"{points} rise above the table's plane there). If these photos show the printed sheet alone, give the "
        "object's photos instead (calibrate takes the sheet's). An object with little texture gives few points: "
        "then the NeRF starts from the whole region around the tag, not a box around the object, and how well "
        "the photos agree on the table is not measured (the object would count as table)"
    )


def split_indices(n: int, val_every: int, test_every: int) -> list[str]:
    """Split name for each of ``n`` photos: val at i % val_every == val_every // 2, test at
    i % test_every == 0 (if not val), train otherwise; at least one train view is kept."""
    out = []
    for i in range(n):
        if val_every > 0 and i % val_every == val_every // 2:
            out.append("val")
        elif test_every > 0 and i % test_every == 0 and n > 2:
            out.append("test")
        else:
            out.append("train")
    if "train" not in out and n:
        out[0] = "train"
    return out


def check_settings(cfg: DatasetConfig) -> None:
    """Refuse a ``--center`` that is not three numbers and ``--near``/``--far`` out of order,
    before any photo is read or posed (a later error would leave a ``poses.json`` behind)."""
    parse_center(cfg.center)
    if cfg.near is not None and cfg.far is not None and not cfg.near < cfg.far:
        raise fail("--near/--far", f"near={cfg.near:g} and far={cfg.far:g}: need near < far")


def given_center(text: str, c2w: np.ndarray) -> np.ndarray | None:
    """``--center`` (None when not given), refused when it lies farther from the cameras' mean
    position than twice their spread around it: a centre in other units than the tag's
    metres (100,100,100 for a centimetre or a millimetre) makes a dataset of empty views."""
    center = parse_center(text)
    if center is None:
        return None
    mean = c2w[:, :3, 3].mean(0)
    reach = float(np.linalg.norm(c2w[:, :3, 3] - mean, axis=1).max()) + float(np.linalg.norm(mean))
    if np.linalg.norm(center - mean) > 2 * reach:
        raise fail(
            "--center",
            f"{text} lies {np.linalg.norm(center - mean):.3g} m from the cameras, which are within "
            f"{reach:.3g} m of the tag",
            "Give it in metres in the tag's frame (the tag's centre is 0,0,0), or leave it out to estimate it",
        )
    return center


def parse_center(text: str) -> np.ndarray | None:
    if not text:
        return None
    try:
        c = np.array([float(v) for v in text.replace(" ", "").split(",")], np.float32)
    except ValueError:
        c = np.zeros(0, np.float32)
    if c.shape != (3,) or not np.isfinite(c).all():
        raise fail("--center", f"expected three numbers 'x,y,z', got '{text}'")
    return c


def plane_hit_distance(c2w: np.ndarray, K_nk: np.ndarray, size: tuple[int, int]) -> float:
    """Nearest distance along the image's border rays (corners and edge midpoints) at which
    a camera sees the plane z = 0 from above (:func:`~nerfkit.cameras.plane_hit`), or inf
    when none of them meets it."""
    w, h = size
    uv = np.array([[0, 0], [w / 2, 0], [w, 0], [w, h / 2], [w, h], [w / 2, h], [0, h], [0, h / 2]], np.float64)
    f64 = torch.float64
    o, d = pixel_to_ray(torch.as_tensor(K_nk, dtype=f64), torch.as_tensor(c2w, dtype=f64), torch.as_tensor(uv))
    return float(plane_hit(o, d, torch.tensor([0.0, 0.0, 1.0, 0.0], dtype=f64)).min())


def estimate_bounds(
    c2w: np.ndarray, center: np.ndarray, tag_size: float, K_nk: np.ndarray, size: tuple[int, int]
) -> tuple[float, float, float]:
    """near, far and the object radius from the cameras and the tag scale.

    The object is taken to lie within a sphere about ``center`` of radius
    ``max(2.5 tag sizes, distance from the centre to the tag + one tag size)`` (it sits beside
    the tag). far reaches the far side of that sphere from every camera; near is 0.9 x the
    closest of: the sphere's near side, and the table (z = 0) at the image border.
    """
    radius = max(2.5 * tag_size, float(np.linalg.norm(center)) + tag_size)
    d = np.linalg.norm(c2w[:, :3, 3] - center, axis=1)
    near_each = [min(di - radius, plane_hit_distance(c, K_nk, size)) for di, c in zip(d, c2w)]
    near = 0.9 * float(min(near_each))
    near = max(near, 0.02 * float(d.min()))
    far = float((d + radius).max())
    return near, far, radius


def _load_view(p: PosedPhoto, base: Camera, und, out_size: tuple[int, int]) -> np.ndarray:
    import cv2

    from ..images import load_image_uint8

    img = load_image_uint8(p.path)
    if p.turns:  # held the other way: into the camera's frame, as it was posed
        img = np.ascontiguousarray(np.rot90(img, -p.turns))
    if (img.shape[1], img.shape[0]) != (p.camera.width, p.camera.height):
        raise fail(
            p.path,
            f"is now {img.shape[1]}x{img.shape[0]}, but was {p.camera.width}x{p.camera.height} when it was posed",
            "Re-run nerfkit poses",
        )
    if (img.shape[1], img.shape[0]) != (base.width, base.height):
        img = cv2.resize(img, (base.width, base.height), interpolation=cv2.INTER_AREA)
    img = und(img)
    if (img.shape[1], img.shape[0]) != out_size:
        img = cv2.resize(img, out_size, interpolation=cv2.INTER_AREA)
    return img


def build_dataset(
    posed: list[PosedPhoto],
    out_dir: str | Path,
    cfg: DatasetConfig,
    tag_size: float,
    jobs: int = 2,
    progress: bool = True,
    extra: dict | None = None,
    up: np.ndarray | None = None,
    on_tag_plane: bool = True,
    points: SparsePoints | None = None,
    tags: np.ndarray | None = None,
    table_from: str = TAG_PLANE,
) -> tuple[Scene, dict]:
    """Undistort, crop, resize and split ``posed`` photos, then write the dataset files.

    ``points``: the scene's sparse points when known (structure-from-motion); else, with
    ``cfg.points``, they are triangulated from the train views
    (:func:`nerfkit.capture.points.triangulate_views`). The train views that see each
    point become the scene's ``point_views``.

    ``up`` is the scene's up direction (default +z: the tag-plane normal toward the cameras).
    ``tags``: (n, 4, 3) corners of the printed tags in the world (:meth:`Layout.corners`),
    recorded with the table when the object stands on the tag's plane.
    ``on_tag_plane``: the world is the tag frame and the object stands on the tag's plane
    (z = 0), recorded as the scene's table (moved to the sparse points on the tags:
    :func:`tag_surface_height`); ``table_from`` says what that plane is (the summary's and
    transforms.json's ``table_from``). The scene is marked a real capture.
    Returns the Scene (nerfkit conventions) and a summary dict.
    """
    from tqdm import tqdm

    if not posed:
        raise fail(out_dir, "no posed photos to build a dataset from")
    out_dir = Path(out_dir)
    posed = sorted(posed, key=lambda p: p.name)
    base_size = common_size((p.camera.width, p.camera.height) for p in posed)
    base = next(p.camera for p in posed if (p.camera.width, p.camera.height) == base_size)
    assert base_size is not None  # a camera of that size was found
    und = make_undistorter(base)
    out_size = output_size(*und.size, cfg.max_side)
    K = resize_K_nerfkit(nerfkit_K(und.K), und.size, out_size).astype(np.float32)

    bar = tqdm(total=len(posed), desc="undistorting", unit="photo", disable=None if progress else True, leave=False)

    def work(p: PosedPhoto) -> np.ndarray:
        img = _load_view(p, base, und, out_size)
        bar.update(1)
        return img

    try:
        if jobs > 1:
            with ThreadPoolExecutor(jobs) as pool:
                loaded = list(pool.map(work, posed))
        else:
            loaded = [work(p) for p in posed]
    finally:
        bar.close()
    images = np.stack(loaded)
    c2w = np.stack([p.c2w for p in posed]).astype(np.float64)
    names = [p.name for p in posed]

    center = given_center(cfg.center, c2w)
    center_note = "given with --center"
    if center is None:
        center = estimate_center(c2w.astype(np.float32)).astype(np.float64)
        center_note = "the point nearest every camera's optical axis"
        mean_dist = float(np.mean(np.linalg.norm(c2w[:, :3, 3], axis=1)))
        if not np.isfinite(center).all() or np.linalg.norm(center) > 2 * mean_dist:
            center = np.zeros(3)
            center_note = "the tag centre (the cameras' optical axes do not meet near the tag)"
    near, far, radius = estimate_bounds(c2w, center, tag_size, K.astype(np.float64), out_size)
    if cfg.near is not None:
        near = float(cfg.near)
    if cfg.far is not None:
        far = float(cfg.far)
    if not 0 <= near < far:
        raise fail("--near/--far", f"near={near:g} and far={far:g}: need 0 <= near < far")

    split = split_indices(len(posed), cfg.val_every, cfg.test_every)
    views = {}
    for s in ("train", "val", "test"):
        idx = [i for i, x in enumerate(split) if x == s]
        if idx:
            views[s] = Views(
                c2w[idx].astype(np.float32),
                np.repeat(K[None], len(idx), 0),
                out_size[0],
                out_size[1],
                images[idx],
                [names[i] for i in idx],
            )
        else:
            views[s] = Views.empty(out_size[0], out_size[1])
    up = UP.copy() if up is None else (np.asarray(up, np.float64) / np.linalg.norm(up)).astype(np.float32)
    table = np.array([0.0, 0.0, 1.0, 0.0], np.float32) if on_tag_plane else None
    scene = check_scene(
        Scene(
            views["train"],
            views["val"],
            views["test"],
            near,
            far,
            center.astype(np.float32),
            up,
            source=str(out_dir),
            capture=True,
            table=table,
            tags=_lying_flat(tags) if on_tag_plane else None,
        )
    )
    points_note = "from structure-from-motion" if points is not None else "none: --no-points"
    if points is None and cfg.points:
        points, points_note = _triangulate(scene.train, out_dir, progress)
    if points is not None:
        scene.points, scene.point_colors = check_points(points.xyz, points.rgb, str(out_dir))
        scene.point_views = point_views(points.seen_by, scene.train.names)
    table_note = None if table is None else table_from
    if table is not None and scene.points is not None and scene.tags is not None:
        lift, on_tags = tag_surface_height(scene.points, scene.tags)
        if lift:
            table = np.array([0.0, 0.0, 1.0, -lift], np.float32)
            scene.table = table
            table_note = f"z = {lift * 1000:+.2f} mm, the median height of the {on_tags} sparse points on the tags"
    # the object's points as the model will find them (SceneBounds.from_scene)
    obj = (
        None
        if scene.points is None or table is None
        else object_points(scene.points, table, scene.center, sphere_radius(scene), views=scene.train)
    )
    summary = {
        "views": {s: len(v) for s, v in scene.splits.items()},
        "size": list(out_size),
        "K": np.round(K.astype(np.float64), 4).tolist(),
        "near": round(near, 5),
        "far": round(far, 5),
        "center": np.round(center, 5).tolist(),
        "center_from": center_note,
        "object_radius": round(radius, 5),
        "up": [float(u) for u in up],
        "tag_size": float(tag_size),
        "capture": True,
        "table_plane": None if table is None else table.tolist(),
        "table_from": table_note,
        "tags_on_table": 0 if scene.tags is None else len(scene.tags),
        "undistorted": base.has_distortion,
        "crop": list(und.roi),
        "source_size": list(base_size),
        "points": 0 if scene.points is None else len(scene.points),
        "points_from": points_note,
        "object_points": None if obj is None else len(obj),
        "world": "tag frame: origin at the tag centre, x right and y up along the printed tag, z out of the tag "
        "toward the cameras (= up); metres",
    }
    if len(scene.train):
        summary["coverage"] = write_coverage(scene, out_dir / COVERAGE_PLOT)
    if table is not None:
        agreement = photo_agreement(scene, obj)
        if agreement is not None:
            summary["agreement"] = agreement.as_json()
    write_transforms_json(scene, out_dir, jpeg_quality=cfg.jpeg_quality, extra={**summary, **(extra or {})})
    save_npz(scene, out_dir / NPZ_FILE)
    return scene, summary


def write_coverage(scene: Scene, plot_path: Path) -> dict:
    """The coverage of ``scene``'s photos around its centre (:func:`~nerfkit.capture.coverage.measure_coverage`)
    as JSON, with its chart written to ``plot_path``."""
    from ..viz.plots import plot_coverage
    from .coverage import cap_outline, measure_coverage

    # (an empty split has no names, and measure_coverage leaves it out)
    cov = measure_coverage({s: (v.c2w, v.names or []) for s, v in scene.splits.items()}, scene.center, scene.up)
    gaps = {f"widest gap ({cov.capture.radius_deg:.0f} degrees)": cap_outline(cov.capture, scene.up)}
    if cov.train.radius_deg > cov.capture.radius_deg:
        gaps[f"widest gap of the training photos ({cov.train.radius_deg:.0f})"] = cap_outline(cov.train, scene.up)
    plot_coverage(
        plot_path,
        cov.azimuth_elevation,
        gaps,
        "where the photos look from, seen from above\n"
        "(azimuth from the world's x axis, a tag's right; the centre looks straight down)",
    )
    return {**cov.as_json(), "plot": plot_path.name}


def photo_agreement(scene: Scene, obj: np.ndarray | None = None) -> Agreement | None:
    """How well ``scene``'s training photos agree on its table around the object
    (:func:`~nerfkit.capture.agreement.measure_agreement`, the object's box left out as the
    model will find it), or None; None too without an object box (too few sparse points on
    the object), where the object, in front of the table in some photos, would count as
    table. ``obj``: the object's sparse points when already found
    (:func:`~nerfkit.scene_extent.object_points` of the scene's points and train views)."""
    from .agreement import measure_agreement

    if scene.table is None:  # no table to agree on (build_dataset asks only when there is one)
        return None
    radius = sphere_radius(scene)  # the object's box as the model will find it (SceneBounds.from_scene)
    if obj is None and scene.points is not None:
        obj = object_points(scene.points, scene.table, scene.center, radius, views=scene.train)
    box = None if obj is None else object_box(obj, scene.table, scene.center, radius)
    if box is None:
        return None
    return measure_agreement(scene.train, scene.center, scene.table, radius, box)


# points within this share of a tag's side from its plane count as on the printed tag
TAG_SURFACE_BAND = 0.05
# fewer points than this on the tags leave the table on the tags' plane
MIN_TAG_SURFACE_POINTS = 30


def tag_surface_height(points: np.ndarray, tags: np.ndarray) -> tuple[float, int]:
    """Where the sparse points put the printed tags' surface: ``(height, count)``, the
    median height above z = 0 of the ``count`` points (m, 3) over the tags (n, 4, 3) lying
    on z = 0, within :data:`TAG_SURFACE_BAND` of a tag's side of that plane.

    The tags' plane comes from their detected corners; the points, from features matched
    across the photos. When the two disagree (a corner detector's bias of a fraction of a
    pixel, a tag printed on card), the table's texture is seen at the points' height.
    Height 0.0 when fewer than :data:`MIN_TAG_SURFACE_POINTS` points are on the tags.
    Example: 40 points at z = 0.001 over a 0.1-wide tag at the origin -> (0.001, 40).
    """
    tags = np.asarray(tags, np.float64)
    points = np.asarray(points, np.float64)
    side = float(quad_sides(tags).mean())
    near = points[np.abs(points[:, 2]) <= TAG_SURFACE_BAND * side]
    on = near[inside_quads(near[:, :2], tags[..., :2])]
    if len(on) < MIN_TAG_SURFACE_POINTS:
        return 0.0, len(on)
    return float(np.median(on[:, 2])), len(on)


def _lying_flat(tags) -> np.ndarray | None:
    """The tags (n, 4, 3) that lie on the table z = 0 (within 1% of their side): a layout
    may place a tag elsewhere (a second sheet standing up), and it is no paper on the table."""
    if tags is None:
        return None
    t = np.asarray(tags, np.float64)
    side = quad_sides(t)
    flat = np.abs(t[..., 2]).max(1) <= 0.01 * side
    return t[flat].astype(np.float32) if flat.any() else None


def _triangulate(train: Views, out_dir: Path, progress: bool) -> tuple[SparsePoints | None, str]:
    """Sparse points of the train views, or None and why not."""
    from ..errors import NerfkitError
    from .points import triangulate_views

    if progress:
        print(f"triangulating sparse points from {len(train)} train views (pycolmap)...", file=sys.stderr, flush=True)
    try:
        pts = triangulate_views(train, out_dir)
    except (NerfkitError, RuntimeError, ValueError) as e:  # no pycolmap, or COLMAP found no matches
        return None, f"none ({e})"
    return pts, (
        f"triangulated from {len(train)} train views with the poses held (median "
        f"reprojection error {float(np.median(pts.error)) if len(pts) else 0:.2f} px)"
    )


# ---------------------------------------------------------------- poses.json


def posed_none(path: str | Path) -> bool:
    """Whether ``path`` is a poses.json of `nerfkit poses` that posed no photo: the record of a
    failed try, which the next one replaces."""
    try:
        record = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return False
    return isinstance(record, dict) and record.get("format") == "nerfkit-poses" and record.get("photos_posed") == 0


def write_poses_json(path: str | Path, records, posed: list[PosedPhoto], camera: Camera, meta: dict) -> None:
    """Every photo's outcome and pose (OpenCV axes), the camera and the tag settings."""
    by_name = {p.name: p for p in posed}
    photos = []
    for r in records:
        d = r.summary()
        if r.name in by_name:
            d["c2w"] = np.round(by_name[r.name].c2w, 8).tolist()
        photos.append(d)
    write_json(
        path,
        {
            "format": "nerfkit-poses",
            "version": 1,
            "pose_convention": "c2w: camera-to-world, OpenCV camera axes (+x right, +y down, +z forward) of the "
            "upright photo turned clockwise by turned_deg (photos held the other way)",
            "camera": {
                "K": camera.K.tolist(),
                "dist": camera.dist.tolist(),
                "width": camera.width,
                "height": camera.height,
                "sensor_turns": camera.sensor_turns,
                "source": camera.source,
            },
            **meta,
            "photos_posed": len(posed),
            "photos_skipped": len(records) - len(posed),
            "photos": photos,
        },
    )


def read_poses_json(path: str | Path, allow_outside: bool = False) -> tuple[list[PosedPhoto], dict]:
    """Posed photos and the metadata from a poses.json (a dataset folder works too).

    Each photo must lie in the recorded photo folder (``allow_outside``: anywhere)."""
    path = Path(path)
    if path.is_dir():
        path = path / POSES_FILE
    data = load_json(
        path,
        "no such file",
        "Run nerfkit poses first; it writes poses.json into the dataset folder",
        "Re-run nerfkit poses",
    )
    if not isinstance(data, dict) or data.get("format") != "nerfkit-poses":
        raise fail(path, "is not a poses.json written by nerfkit poses")
    with advice("Re-run nerfkit poses"):
        camera = camera_from_dict(data.get("camera"), f"{path} camera")
        camera.source = str(data["camera"].get("source", ""))
        try:
            photos_dir = Path(data["photos_dir"])
            if not photos_dir.is_absolute():
                photos_dir = path.parent / photos_dir
            photos = data["photos"]
            if not isinstance(photos, list) or not all(isinstance(d, dict) for d in photos):
                raise fail(path, "'photos' must be a list of objects")
            posed = [
                _posed_photo(d, i, camera, photos_dir, str(path), allow_outside)
                for i, d in enumerate(photos)
                if "c2w" in d
            ]
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            raise fail(path, f"malformed poses.json ({type(e).__name__}: {short_repr(str(e))})") from None
    if not posed:
        raise fail(path, "holds no posed photos", "Check the poses run's summary for why photos were skipped")
    return posed, data


def recorded_tags(poses_meta) -> np.ndarray | None:
    """The printed tags' corners (n, 4, 3) in the layout a poses.json records, or None when
    it records none that can be read (a dataset rebuilt from it then goes without)."""
    from ..errors import NerfkitError
    from .aruco import layout_from_json

    spec = poses_meta.get("layout") if isinstance(poses_meta, dict) else None
    if not isinstance(spec, dict):
        return None
    size = poses_meta.get("tag_size")
    try:
        layout = layout_from_json(
            spec,
            POSES_FILE,
            str(poses_meta.get("dictionary", "DICT_4X4_50")),
            float(size) if isinstance(size, (int, float)) else None,
        )
        return layout.corners()
    except (NerfkitError, KeyError, TypeError, ValueError):
        return None


def _posed_photo(
    d: dict, i: int, camera: Camera, photos_dir: Path, where: str, allow_outside: bool = False
) -> PosedPhoto:
    """One photo of poses.json with its checked pose and the camera of its size."""
    w, h = d["size"]
    w = check_count(w, where, f"photos[{i}].size", 1, MAX_SIDE)
    h = check_count(h, where, f"photos[{i}].size", 1, MAX_SIDE)
    c2w = check_poses([d["c2w"]], where, f"photos[{i}].c2w")[0].astype(np.float64)
    cam = camera if (w, h) == (camera.width, camera.height) else camera.scaled_to(w, h)
    if not isinstance(d["file"], str):
        raise fail(where, f"photos[{i}].file is {short_repr(d['file'])}, expected a file name")
    path = resolve_inside(photos_dir, d["file"], allow_outside, f"{where} photos[{i}].file")
    turned = d.get("turned_deg", 0)
    if turned not in (0, 90, 180, 270) or isinstance(turned, bool):
        raise fail(where, f"photos[{i}].turned_deg is {short_repr(turned)}, expected 0, 90, 180 or 270")
    return PosedPhoto(d["file"], path, c2w, float(d.get("error_px") or 0.0), cam, int(turned) // 90)
