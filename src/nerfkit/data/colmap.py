"""COLMAP models (``cameras``/``images``/``points3D``, binary or text) <-> :class:`Scene`.

COLMAP's camera axes are OpenCV's (+x right, +y down, +z forward) and its pixel
coordinates put the centre of the top-left pixel at (0.5, 0.5), as nerfkit does, so poses
and K carry over unchanged: ``c2w = inverse(image.cam_from_world())``. Distorted camera
models (SIMPLE_RADIAL, OPENCV, ...) are undistorted to pinhole images with pycolmap's
own undistorter. Reading and writing go through pycolmap.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import fail
from ..images import load_image_uint8
from ..io.paths import refuse_special_file, resolve_inside, safe_output_name
from .llff import holdout_indices
from .scene import Scene, Views, estimate_center, estimate_near_far, estimate_up, point_views
from .validate import check_intrinsics, check_near_far, check_poses, check_scene

if TYPE_CHECKING:  # pragma: no cover
    import pycolmap

MODEL_FILES = ("cameras", "images")
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")


def import_pycolmap(where: object, need: str = "reading COLMAP models needs pycolmap"):
    """pycolmap, or a clear error at ``where`` (``need``: what needs it) that says how to install it.
    SIGTERM stays Python's (:func:`nerfkit.io.stop.take_back_sigterm`): nerfkit imports
    pycolmap here, and elsewhere only once a pycolmap object exists."""
    from ..io import stop

    try:
        import pycolmap
    except ImportError:
        raise fail(where, need, "pip install 'nerfkit[sfm]'") from None
    stop.take_back_sigterm()  # from the stack dump pycolmap's first import sets for it
    return pycolmap


def is_model_dir(folder: Path) -> bool:
    """True when ``folder`` holds a COLMAP model (cameras and images, .bin or .txt)."""
    return folder.is_dir() and any(
        all((folder / f"{n}{ext}").is_file() for n in MODEL_FILES) for ext in (".bin", ".txt")
    )


def find_colmap_model(path: str | Path) -> Path | None:
    """The model folder for ``path``: the folder itself, or ``sparse/0``, ``sparse``,
    ``colmap/sparse/0`` below it (the largest-numbered layouts COLMAP and nerfstudio write)."""
    path = Path(path)
    for cand in (path, path / "sparse" / "0", path / "sparse", path / "colmap" / "sparse" / "0"):
        if is_model_dir(cand):
            return cand
    sparse = path / "sparse"
    if sparse.is_dir():  # sparse/1, sparse/2, ... when model 0 is missing
        for cand in sorted(p for p in sparse.iterdir() if p.is_dir()):
            if is_model_dir(cand):
                return cand
    return None


def find_image_dir(model_dir: Path) -> Path | None:
    """The photos of a model: ``images/`` in the project folder (up to three levels above)."""
    for up in (model_dir, *list(model_dir.parents)[:3]):
        if (up / "images").is_dir():
            return up / "images"
    return None


_PRECHECK = """
import sys
try:
    import pycolmap
    pycolmap.Reconstruction(sys.argv[1])
except BaseException as e:
    print(" ".join(str(e).split())[:300] or type(e).__name__, file=sys.stderr)
    sys.exit(3)
"""


REEXPORT = "The model is truncated or corrupt; re-export it from COLMAP"

# COLMAP's camera models: model id -> number of parameters (pycolmap.CameraModelId, ids 0-17)
CAMERA_MODEL_PARAMS = dict(enumerate((3, 4, 4, 5, 8, 8, 12, 5, 4, 5, 12, 16, 4, 5, 3, 4, 6, 2)))


def cameras_bin_problem(data: bytes) -> str | None:
    """What is wrong with the bytes of a ``cameras.bin``, or None. Each record is
    ``int32 id, int32 model, uint64 width, uint64 height, double params[k]`` with ``k`` set
    by the model (:data:`CAMERA_MODEL_PARAMS`), so the file's length is known exactly: one cut
    short would otherwise be read with the missing parameters filled in (a wrong focal length
    or principal point, and no error). A model id newer than :data:`CAMERA_MODEL_PARAMS` ends
    the walk unjudged (None): pycolmap knows it."""
    import struct

    if len(data) < 8:
        return "the file is truncated"
    (count,) = struct.unpack_from("<Q", data)
    at = 8
    for i in range(count):
        if at + 24 > len(data):
            return f"the file is truncated (camera {i + 1} of {count})"
        camera_id, model, _, _ = struct.unpack_from("<iiQQ", data, at)
        if model not in CAMERA_MODEL_PARAMS:
            return None
        at += 24 + 8 * CAMERA_MODEL_PARAMS[model]
        if at > len(data):
            return f"the file is truncated (camera {camera_id}'s parameters)"
    if at != len(data):
        return f"{len(data) - at} bytes follow its {count} cameras"
    return None


def _precheck_binary_model(model_dir: Path) -> None:
    """Read a binary model once in a child process whose memory is capped.

    pycolmap trusts the counts in a binary model's headers: 8 crafted bytes (a points3D.bin
    declaring 10^15 points) make it allocate until the machine runs out of memory, and a
    crafted file could crash it. A text model is bounded by its size, so only binary
    models are checked. Skipped where ``resource`` does not exist (Windows).
    """
    import struct

    size = 0
    for f in sorted(model_dir.glob("*.bin")):
        n = f.stat().st_size
        size += n
        with open(f, "rb") as fh:
            head = fh.read(8)
        # Every binary model file starts with a uint64 record count; a record takes >= 8 bytes.
        if len(head) < 8 or struct.unpack("<Q", head)[0] > (n - 8) // 8:
            count = struct.unpack("<Q", head)[0] if len(head) == 8 else None
            raise fail(
                f,
                "cannot read the COLMAP model: "
                + (
                    f"the file declares {count} records but holds {n} bytes"
                    if count is not None
                    else "the file is truncated"
                ),
                REEXPORT,
            )
    cameras = model_dir / "cameras.bin"
    # (a file too large to walk here is left to the capped reader below)
    small = cameras.is_file() and cameras.stat().st_size <= 64 * 1024**2
    problem = cameras_bin_problem(cameras.read_bytes()) if small else None
    if problem is not None:
        raise fail(
            cameras,
            f"cannot read the COLMAP model: {problem}",
            REEXPORT,
        )
    try:
        import resource
    except ImportError:  # pragma: no cover - Windows
        return
    import signal
    import subprocess
    import sys

    limit = 512 * 1024**2 + 64 * size  # pycolmap holds a model in a few times its file size
    # pycolmap reads ~100 MB/s; a corrupt count can also make it loop past the end of a file
    cpu_seconds = int(10 + size / 1e6)

    def cap_child() -> None:
        resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))
        resource.setrlimit(resource.RLIMIT_CPU, (cpu_seconds, cpu_seconds + 5))

    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PRECHECK, str(model_dir)],
            preexec_fn=cap_child,
            capture_output=True,
            text=True,
            timeout=10 * cpu_seconds + 60,
        )
    except subprocess.TimeoutExpired:
        raise fail(
            model_dir,
            "cannot read the COLMAP model: reading it did not finish",
            "The files may be truncated or corrupt",
        ) from None
    if proc.returncode != 0:
        lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
        if proc.returncode > 0 and lines:
            reason = lines[-1][:300]
        elif proc.returncode in (-signal.SIGXCPU, -signal.SIGKILL):
            reason = f"pycolmap was still reading after {cpu_seconds} s of CPU time"
        else:
            reason = f"pycolmap crashed, exit code {proc.returncode}"
        raise fail(
            model_dir,
            f"cannot read the COLMAP model ({reason})",
            "The files may be truncated or corrupt, or declare more data than they hold",
        )


def read_model(model_dir: str | Path) -> pycolmap.Reconstruction:
    """Read a COLMAP model folder (binary or text) with pycolmap; NerfkitError when it can't."""
    model_dir = Path(model_dir)
    pycolmap = import_pycolmap(model_dir)
    if not is_model_dir(model_dir):
        raise fail(model_dir, "not a COLMAP model folder", "Expected cameras.bin/images.bin/points3D.bin (or .txt)")
    for f in sorted([*model_dir.glob("*.bin"), *model_dir.glob("*.txt")]):  # what pycolmap and the precheck read
        refuse_special_file(f)
    if any((model_dir / f"{n}.bin").is_file() for n in MODEL_FILES):
        _precheck_binary_model(model_dir)
    check_text_quaternions(model_dir)
    try:
        return pycolmap.Reconstruction(str(model_dir))
    except Exception as e:  # noqa: BLE001 - pycolmap raises ValueError/RuntimeError on bad files
        reason = " ".join(str(e).split())[:300]  # pycolmap's messages can span lines
        raise fail(
            model_dir, f"cannot read the COLMAP model ({reason})", "The files may be truncated or corrupt"
        ) from None


def camera_matrix(camera) -> np.ndarray:
    """K (3, 3) float64 of a pinhole pycolmap camera."""
    return np.asarray(camera.calibration_matrix(), np.float64)


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) of a unit quaternion ``q`` (4,) in pycolmap's order (x, y, z, w)."""
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def image_c2w(image) -> np.ndarray:
    """Camera-to-world (4, 4) float64 of a posed pycolmap image (OpenCV axes). A rotation
    quaternion of another length than 1 is normalised, as COLMAP does; a zero or non-finite
    one (no rotation at all) is a ``np.linalg.LinAlgError``."""
    pose = image.cam_from_world()
    w2c = np.eye(4)
    w2c[:3] = np.asarray(pose.matrix(), np.float64)
    q = np.asarray(pose.rotation.quat, np.float64)
    norm = math.hypot(*q)
    if not (math.isfinite(norm) and norm > 0):
        raise np.linalg.LinAlgError(f"rotation quaternion {q.tolist()} of image {image.name!r} has no direction")
    if abs(norm - 1.0) > 1e-9:  # pycolmap takes it as it is: a scaled, not a rigid, rotation
        w2c[:3, :3] = quaternion_matrix(q / norm)
    return np.linalg.inv(w2c)


def check_text_quaternions(model_dir: Path) -> None:
    """Refuse a text model whose ``images.txt`` or ``frames.txt`` gives a rotation quaternion
    (QW QX QY QZ) that is zero or not finite, naming the file and line: pycolmap would take a
    zero one for no rotation at all. Lines it cannot read are left to pycolmap, which says so."""
    # (file, first quaternion field, whether each record has a second line: images.txt's points)
    for name, first, two_lines in (("images", 1, True), ("frames", 2, False)):
        path = model_dir / f"{name}.txt"
        if (model_dir / f"{name}.bin").exists() or not path.is_file():
            continue
        with open(path, encoding="utf-8", errors="replace") as f:
            lines = iter(enumerate(f, 1))
            for number, line in lines:
                line = line.strip()
                if not line or line.startswith("#"):
                    continue
                if two_lines:
                    next(lines, None)  # the image's 2D points
                fields = line.split()
                try:
                    q = [float(v) for v in fields[first : first + 4]]
                except ValueError:
                    continue
                if len(q) < 4:
                    continue
                norm = math.hypot(*q)
                if not math.isfinite(norm) or norm == 0:
                    what = "zero: no rotation at all" if norm == 0 else "not finite"
                    raise fail(
                        f"{path}:{number}",
                        f"{name[:-1]} {fields[0]} has the rotation quaternion "
                        f"{' '.join(fields[first : first + 4])} (QW QX QY QZ), which is {what}",
                        "The model is corrupt; export it from COLMAP again",
                    )


def undistort(image: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray]:
    """Undistort a (H, W, 3) uint8 photo taken with a pycolmap camera.

    Returns ``(pinhole_image, K)``; pinhole cameras are returned unchanged. The output
    size can differ slightly from the input (pycolmap keeps only valid pixels).
    """
    import pycolmap

    if camera.model_name in PINHOLE_MODELS:
        return image, camera_matrix(camera)
    bitmap, pinhole = pycolmap.undistort_image(
        pycolmap.UndistortCameraOptions(), pycolmap.Bitmap.from_array(np.ascontiguousarray(image)), camera
    )
    return np.asarray(bitmap.to_array()).reshape(pinhole.height, pinhole.width, 3), camera_matrix(pinhole)


def near_far_from_points(
    c2w: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    points: np.ndarray,
    lo: float = 1.0,
    hi: float = 99.0,
    margin: float = 0.1,
) -> tuple[float, float] | None:
    """Depth range of 3D points (P, 3) seen by cameras c2w (N, 4, 4) with intrinsics K (N, 3, 3).

    Per camera, the depths of the points inside its image; over all cameras the ``lo``-th
    and ``hi``-th percentiles, widened by ``margin``. None when too few points are visible.
    """
    depths = []
    for c, k in zip(c2w.astype(np.float64), K.astype(np.float64)):
        x = (points - c[:3, 3]) @ c[:3, :3]  # camera-frame coordinates
        z = x[:, 2]
        front = z > 1e-9
        uv = (x[front] @ k.T)[:, :2] / z[front, None]
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
        depths.append(z[front][inside])
    d = np.concatenate(depths) if depths else np.zeros(0)
    if d.size < 10:
        return None
    near, far = np.percentile(d, lo), np.percentile(d, hi)
    return float(near * (1 - margin)), float(far * (1 + margin))


@dataclass
class SparsePoints:
    """Triangulated points: ``xyz`` (m, 3) float32 world coordinates, ``rgb`` (m, 3)
    uint8 colours, ``error`` (m,) mean reprojection error in pixels, ``track`` (m,) the
    length of each point's feature track, ``seen_by``: the names of the photos in each
    point's track (a photo may give a point two features), or None."""

    xyz: np.ndarray
    rgb: np.ndarray
    error: np.ndarray
    track: np.ndarray
    seen_by: list[tuple[str, ...]] | None = None

    def __len__(self) -> int:
        return len(self.xyz)


def reconstruction_points(
    rec, max_error: float = 2.0, min_track: int = 3, photo_name: Callable[[str], str] | None = None
) -> SparsePoints:
    """The points of a pycolmap reconstruction (in its current frame) seen by
    ``min_track`` or more images with a mean reprojection error <= ``max_error`` px, with
    the photos that see each one (``photo_name``: COLMAP's image name -> the photo's name;
    default the same)."""
    pts = list(rec.points3D.values())
    xyz = np.array([p.xyz for p in pts], np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in pts], np.uint8).reshape(-1, 3)
    err = np.array([p.error for p in pts], np.float64)
    track = np.array([p.track.length() for p in pts], np.int64)
    keep = (err <= max_error) & (track >= min_track) & np.isfinite(xyz).all(1)
    image_name = {i: rec.images[i].name for i in rec.reg_image_ids()}
    name = photo_name or (lambda n: n)
    seen_by = [
        tuple(sorted({name(image_name[e.image_id]) for e in p.track.elements if e.image_id in image_name}))
        for p, k in zip(pts, keep)
        if k
    ]
    return SparsePoints(xyz[keep].astype(np.float32), rgb[keep], err[keep].astype(np.float32), track[keep], seen_by)


def reconstruction_to_scene(
    rec: pycolmap.Reconstruction,
    image_dir: str | Path | None,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    val_every: int = 8,
    size: int | None = None,
    downscale: float | None = None,
    source: str = "",
    allow_outside: bool = False,
) -> Scene:
    """A Scene from the registered images of a reconstruction (sorted by name), with its
    well-seen points (:func:`reconstruction_points`) and the train views that saw them.

    With ``image_dir`` the photos are loaded and undistorted; without it the scene has
    poses only (pinhole K of the undistorted cameras). All views must share one image
    size after undistortion (one camera, or several of the same size).
    """
    import pycolmap

    from .resample import output_size, resize_image, scale_intrinsics

    where = source or "COLMAP model"
    images = sorted((im for im in rec.images.values() if im.has_pose), key=lambda im: im.name)
    if not images:
        raise fail(where, "has no registered images", "Re-run SfM or check the model")
    names, c2ws, Ks, pixels = [], [], [], []
    size_wh: tuple[int, int] | None = None
    pinholes: dict[int, pycolmap.Camera] = {}
    for im in images:
        cam = rec.cameras[im.camera_id]
        # before undistorting: pycolmap walks the image border, for ever on a 10^11-pixel-wide camera
        size_ok = 0 < cam.width <= 1_000_000 and 0 < cam.height <= 1_000_000
        if size_ok and im.camera_id not in pinholes:
            try:
                pinholes[im.camera_id] = (
                    cam
                    if cam.model_name in PINHOLE_MODELS
                    else pycolmap.undistort_camera(pycolmap.UndistortCameraOptions(), cam)
                )
            except Exception as e:  # noqa: BLE001 - e.g. equirectangular cameras
                raise fail(
                    where,
                    f"camera {im.camera_id} ({cam.model_name}) cannot be undistorted to a pinhole ({e})",
                    "Use a pinhole, radial or OpenCV camera model",
                ) from None
        pin = pinholes.get(im.camera_id)
        if pin is None or not (size_ok and pin.width > 0 and pin.height > 0):
            raise fail(
                where,
                f"camera {im.camera_id} has image size {cam.width}x{cam.height}",
                "The model's cameras.txt/bin is corrupt",
            )
        K = check_intrinsics(camera_matrix(pin), where, f"camera {im.camera_id}", int(pin.width), int(pin.height))
        if image_dir is not None:
            photo_path = resolve_inside(image_dir, im.name, allow_outside, where)
            photo = load_image_uint8(photo_path, background, upright=False)  # COLMAP ignores EXIF turns
            if photo.shape[:2] != (cam.height, cam.width):
                raise fail(
                    photo_path,
                    f"photo is {photo.shape[1]}x{photo.shape[0]} but the model's camera "
                    f"{im.camera_id} is {cam.width}x{cam.height}",
                    "Pass the photos the model was made from (not resized)",
                )
            photo, K = undistort(photo, cam)
        wh = (int(pin.width), int(pin.height))
        if size_wh is None:
            size_wh = wh
        elif wh != size_wh:
            raise fail(
                where,
                f"images have different sizes after undistortion ({size_wh} and {wh} for {im.name})",
                "nerfkit needs one image size per dataset; use a single camera",
            )
        out_wh = output_size(*wh, size, downscale)
        if image_dir is not None:
            pixels.append(resize_image(photo, *out_wh))
        names.append(im.name)
        try:
            c2ws.append(check_poses(image_c2w(im)[None], where, f"pose of {im.name}")[0])
        except np.linalg.LinAlgError:  # a zero or non-finite quaternion, a singular matrix
            raise fail(
                where,
                f"image {im.name!r} has a degenerate pose (its rotation quaternion is zero or not finite)",
                "The model's images.txt/bin is corrupt",
            ) from None
        Ks.append(scale_intrinsics(K, *wh, *out_wh))
    assert size_wh is not None  # images is not empty
    W, H = output_size(*size_wh, size, downscale)
    c2w = np.stack(c2ws).astype(np.float32)
    K = np.stack(Ks).astype(np.float32)
    imgs = np.stack(pixels) if pixels else None
    points = np.array([p.xyz for p in rec.points3D.values()], np.float64).reshape(-1, 3)
    center = estimate_center(c2w)
    up = estimate_up(c2w)
    nf = near_far_from_points(c2w, K, W, H, points) or estimate_near_far(c2w, center)
    if nf[1] <= 0:
        raise fail(
            where,
            "cannot tell the depth range: too few 3D points, and the cameras share no look-at point",
            "Use a model with its points3D",
        )
    near, far = check_near_far(*nf, where)
    tr, va = holdout_indices(len(names), val_every)
    all_views = Views(c2w, K, W, H, imgs, names)
    train = all_views.subset(tr)
    # COLMAP triangulates from 2 views; a model whose points all lack tracks (written from a
    # dataset that did not record which photos saw them) keeps them, with no sightings
    trackless = len(rec.points3D) > 0 and all(p.track.length() == 0 for p in rec.points3D.values())
    kept = reconstruction_points(rec, min_track=0 if trackless else 2)
    known = len(kept) > 0
    return check_scene(
        Scene(
            train,
            all_views.subset(va),
            Views.empty(W, H),
            near,
            far,
            center,
            up,
            source=source,
            points=kept.xyz if known else None,
            point_colors=kept.rgb if known else None,
            point_views=point_views(kept.seen_by, train.names) if known and not trackless else None,
        ),
        where,
    )


def load_colmap(
    path: str | Path,
    images: str | Path | None = None,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    size: int | None = None,
    downscale: float | None = None,
    val_every: int = 8,
    allow_outside: bool = False,
) -> Scene:
    """Load a COLMAP model (``path`` = model folder, or a project with ``sparse/0``) and its
    photos (``images``, default: the project's ``images/`` folder) without re-running SfM.
    Image names that lead outside the photo folder are refused unless ``allow_outside``."""
    path = Path(path)
    if path.is_file():  # one of the model's files
        path = path.parent
    model_dir = find_colmap_model(path)
    if model_dir is None:
        raise fail(path, "no COLMAP model found", "Expected cameras/images/points3D .bin or .txt here or in sparse/0")
    image_dir = Path(images) if images is not None else find_image_dir(model_dir)
    if image_dir is None:
        raise fail(
            model_dir,
            "found the COLMAP model but not its photos",
            "Put them in an images/ folder of the project, or convert with --images DIR",
        )
    if not image_dir.is_dir():
        raise fail(image_dir, "no such image folder")
    rec = read_model(model_dir)
    return reconstruction_to_scene(
        rec, image_dir, background, val_every, size, downscale, source=str(model_dir), allow_outside=allow_outside
    )


def scene_to_reconstruction(
    scene: Scene, splits: tuple[str, ...] = ("train", "val", "test")
) -> pycolmap.Reconstruction:
    """A pycolmap Reconstruction with one PINHOLE camera per distinct K and every view posed.

    Image names are the views' names (``<split>_<index>.png`` when a split has none). The
    scene's sparse points become 3D points with their colours, each with a track of the
    train views that saw it (:attr:`Scene.point_views`; its features where it projects).
    """
    pycolmap = import_pycolmap(scene.source or "scene")
    rec = pycolmap.Reconstruction()
    cam_ids: dict[tuple, int] = {}
    seen = _projected_point_views(scene) if "train" in splits else {}
    tracks: dict[int, list] = {}  # point -> its features (image, index in the image)
    image_id = 0
    for split in splits:
        v = scene.splits[split]
        for i in range(len(v)):
            fx, fy, cx, cy = (float(v.K[i, 0, 0]), float(v.K[i, 1, 1]), float(v.K[i, 0, 2]), float(v.K[i, 1, 2]))
            key = (fx, fy, cx, cy, v.width, v.height)
            if key not in cam_ids:
                cam = pycolmap.Camera.create_from_model_name(len(cam_ids) + 1, "PINHOLE", fx, v.width, v.height)
                cam.params = [fx, fy, cx, cy]
                rec.add_camera_with_trivial_rig(cam)
                cam_ids[key] = cam.camera_id
            image_id += 1
            name = safe_output_name(v.names[i]) if v.names is not None else f"{split}_{i:04d}.png"
            w2c = np.linalg.inv(v.c2w[i].astype(np.float64))
            pose = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
            features = seen.get(i, []) if split == "train" else []
            image = pycolmap.Image(
                name=name,
                camera_id=cam_ids[key],
                image_id=image_id,
                points2D=[pycolmap.Point2D(xy) for _, xy in features],
            )
            rec.add_image_with_trivial_frame(image, pose)
            for k, (point, _) in enumerate(features):
                tracks.setdefault(point, []).append(pycolmap.TrackElement(image_id, k))
    if scene.points is not None:
        colours = scene.point_colors if scene.point_colors is not None else np.full(scene.points.shape, 128, np.uint8)
        for p, (xyz, rgb) in enumerate(zip(scene.points.astype(np.float64), colours.astype(np.uint8))):
            rec.add_point3D(xyz, pycolmap.Track(tracks.get(p, [])), rgb)
    return rec


def _projected_point_views(scene: Scene) -> dict[int, list]:
    """Train view -> ``[(point, xy (2,) pixels), ...]``: where each point the view saw
    (:attr:`Scene.point_views`) projects in it, for the points in front of it."""
    if scene.points is None or scene.point_views is None:
        return {}
    out: dict[int, list] = {}
    v = scene.train
    for point, view in scene.point_views.astype(np.int64):
        c2w = v.c2w[view].astype(np.float64)
        x = (scene.points[point].astype(np.float64) - c2w[:3, 3]) @ c2w[:3, :3]  # camera frame
        if x[2] > 0:
            out.setdefault(int(view), []).append((int(point), (v.K[view].astype(np.float64) @ (x / x[2]))[:2]))
    return out


def write_reconstruction(rec: pycolmap.Reconstruction, out_dir: str | Path, text: bool = False) -> Path:
    """Write a pycolmap model folder (binary, or text with ``text=True``).

    pycolmap writes into a temporary folder; each file is then moved into place through
    :func:`nerfkit.io.atomic.write_bytes`, so a crash never leaves a half-written file.
    """
    import tempfile

    from ..io.atomic import write_bytes

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out_dir) as tmp:
        (rec.write_text if text else rec.write)(tmp)
        for f in sorted(Path(tmp).iterdir()):
            write_bytes(out_dir / f.name, f.read_bytes())
    return out_dir


def write_colmap_model(
    scene: Scene, out_dir: str | Path, text: bool = False, splits: tuple[str, ...] = ("train", "val", "test")
) -> Path:
    """Write the scene's cameras and sparse points as a COLMAP model folder (PINHOLE
    cameras; :func:`scene_to_reconstruction`)."""
    return write_reconstruction(scene_to_reconstruction(scene, splits), out_dir, text)
