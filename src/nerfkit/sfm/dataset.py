"""From an SfM reconstruction to the same dataset the tag path writes.

:func:`sfm_dataset` is the whole ``nerfkit poses --method colmap`` pipeline: run SfM, fix
the world frame (tag, or normalised), then hand the posed photos to
:func:`nerfkit.capture.dataset.build_dataset` (undistort, crop, resize, split, near/far,
``dataset.npz`` + ``transforms.json`` + ``images/``), plus ``sfm_report.json``, which
also records where the aligned model and the photos are, so that :func:`load_sfm_result`
(``nerfkit dataset``) can rebuild the dataset from the same poses.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..data.scene import Scene
from ..errors import fail
from ..io.atomic import write_json
from .colmap import SfmReport, SfmResult, run_sfm
from .frame import align_reconstruction

if TYPE_CHECKING:  # pragma: no cover
    from ..capture.camera import Camera
    from ..capture.dataset import DatasetConfig
    from ..data.colmap import SparsePoints

REPORT_FILE = "sfm_report.json"


def opencv_camera(camera) -> Camera:
    """A pycolmap camera as the capture package's OpenCV camera (K with pixel centres at
    integers, distortion k1 k2 p1 p2 k3). Raises NerfkitError for models OpenCV's
    5-coefficient model cannot express (fisheye, FULL_OPENCV, ...)."""
    from ..capture.camera import Camera

    p = [float(x) for x in camera.params]
    name = camera.model_name
    if name == "SIMPLE_PINHOLE":
        (f, cx, cy), dist = p, [0.0] * 5
        fx = fy = f
    elif name == "PINHOLE":
        (fx, fy, cx, cy), dist = p, [0.0] * 5
    elif name == "SIMPLE_RADIAL":
        f, cx, cy, k = p
        fx = fy = f
        dist = [k, 0.0, 0.0, 0.0, 0.0]
    elif name == "RADIAL":
        f, cx, cy, k1, k2 = p
        fx = fy = f
        dist = [k1, k2, 0.0, 0.0, 0.0]
    elif name == "OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2 = p
        dist = [k1, k2, p1, p2, 0.0]
    elif name == "FULL_OPENCV" and not any(p[9:]):  # k4..k6 = 0: OpenCV's 5 coefficients
        fx, fy, cx, cy, k1, k2, p1, p2, k3 = p[:9]
        dist = [k1, k2, p1, p2, k3]
    else:
        raise fail(
            f"camera model {name}",
            "cannot be written as an OpenCV k1 k2 p1 p2 k3 camera",
            "Use --camera-model SIMPLE_RADIAL, RADIAL or OPENCV",
        )
    # COLMAP puts pixel centres at +0.5, OpenCV at integers.
    K = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
    return Camera(K, np.asarray(dist, np.float64), int(camera.width), int(camera.height), f"COLMAP {name} (SfM)")


def posed_photos(result: SfmResult) -> list:
    """The registered photos, and those that keep their tag poses (``result.tag_posed``,
    with SfM's camera), as the capture package's ``PosedPhoto`` (name order)."""
    from ..capture.poses import PosedPhoto
    from ..data.colmap import image_c2w

    rec = result.reconstruction
    cams = {cid: opencv_camera(c) for cid, c in rec.cameras.items()}
    out = []
    for i in rec.reg_image_ids():
        im = rec.images[i]
        photo = result.photo(im.name)
        out.append(
            PosedPhoto(
                photo.name, photo, image_c2w(im), image_error(rec, im), cams[im.camera_id], result.turns.get(im.name, 0)
            )
        )
    if result.tag_posed:
        shared = out[0].camera  # SfM shares one camera among the photos
        for name, (c2w, err) in result.tag_posed.items():
            photo = result.photo(name)
            out.append(
                PosedPhoto(photo.name, photo, np.asarray(c2w, np.float64), err, shared, result.turns.get(name, 0))
            )
    return sorted(out, key=lambda p: p.name)


def image_error(rec, image) -> float:
    """Mean reprojection error (pixels) of the 3D points an image sees (their track errors)."""
    errs = [rec.points3D[p.point3D_id].error for p in image.points2D if p.has_point3D()]
    return float(np.mean(errs)) if errs else float("nan")


def near_far_from_model(result: SfmResult) -> tuple[float, float] | None:
    """Depth range of the sparse points seen by the registered cameras (see
    :func:`nerfkit.data.colmap.near_far_from_points`), at the photos' own resolution."""
    from ..data.colmap import image_c2w, near_far_from_points

    rec = result.reconstruction
    ims = [rec.images[i] for i in rec.reg_image_ids()]
    cam = rec.cameras[ims[0].camera_id]
    K = np.asarray(cam.calibration_matrix(), np.float64)
    c2w = np.stack([image_c2w(im) for im in ims])
    points = np.array([p.xyz for p in rec.points3D.values()], np.float64).reshape(-1, 3)
    return near_far_from_points(c2w, np.repeat(K[None], len(ims), 0), cam.width, cam.height, points)


def model_points(result: SfmResult) -> SparsePoints:
    """The reconstruction's well-seen sparse points (:func:`~nerfkit.data.colmap.reconstruction_points`),
    each with the photos that see it."""
    from ..data.colmap import reconstruction_points

    return reconstruction_points(result.reconstruction, photo_name=lambda n: result.photo(n).name)


def build_dataset(
    result: SfmResult,
    out_dir: str | Path,
    cfg: DatasetConfig | None = None,
    jobs: int = 2,
    progress: bool = True,
    extra: dict | None = None,
    write_report: bool = True,
    tags: np.ndarray | None = None,
) -> tuple[Scene, dict]:
    """Write the dataset of an aligned SfM result with the tag path's dataset builder.

    In the tag frame (``result.tag_size`` set) the builder's tag-based bounds are used;
    in a normalised frame near/far come from the sparse points (unless ``cfg`` sets them).
    ``extra`` joins what the dataset records about itself. Writes ``sfm_report.json`` too
    unless ``write_report`` is false (a rebuild in place keeps the one it read). Returns the
    scene and the builder's summary. ``tags``: the printed tags' corners in the tag frame
    (recorded only in it).
    """
    from dataclasses import replace

    from ..capture.dataset import TAG_PLANE, DatasetConfig
    from ..capture.dataset import build_dataset as capture_build_dataset

    cfg = cfg or DatasetConfig()
    tag_size = result.tag_size
    if tag_size is None:
        nf = near_far_from_model(result)
        if nf is not None:
            cfg = replace(
                cfg, near=cfg.near if cfg.near is not None else nf[0], far=cfg.far if cfg.far is not None else nf[1]
            )
        # Only sizes the object sphere in the summary once near/far are given.
        tag_size = 0.1 * float(np.mean([np.linalg.norm(p.c2w[:3, 3]) for p in posed_photos(result)]))
    extra = {
        "world": result.report.frame,
        "poses": "structure-from-motion (COLMAP via pycolmap)",
        "sfm": {k: v for k, v in result.report.to_dict().items() if k not in ("registered",)},
        **(extra or {}),
    }
    scene, summary = capture_build_dataset(
        posed_photos(result),
        out_dir,
        cfg,
        tag_size,
        jobs=jobs,
        progress=progress,
        extra=extra,
        on_tag_plane=result.tag_size is not None or result.on_ground,
        points=model_points(result) if cfg.points else None,
        tags=tags if result.tag_size is not None else None,
        table_from=TAG_PLANE if result.tag_size is not None else "the table plane found in the sparse points, z = 0",
    )
    if write_report:
        write_json(Path(out_dir) / REPORT_FILE, {**result.report.to_dict(), "model": saved_model(result, out_dir)})
    return scene, summary


def saved_model(result: SfmResult, out_dir: str | Path) -> dict:
    """What :func:`load_sfm_result` needs besides the report: the aligned model's folder
    (relative to ``out_dir`` when inside it), the photos' folder and each COLMAP image's
    photo, the photos turned into the camera's frame, the world frame's tag size (metres, or
    None) and whether z = 0 is the table."""
    out = Path(out_dir).resolve()
    model = result.model_dir.resolve()
    folders = {p.parent.resolve() for p in result.sources.values()} or {result.image_dir.resolve()}
    return {
        "dir": str(model.relative_to(out) if model.is_relative_to(out) else model),
        "photos_dir": str(folders.pop()) if len(folders) == 1 else None,
        "photos": {name: p.name for name, p in sorted(result.sources.items())},
        "turned_deg": {name: 90 * t for name, t in sorted(result.turns.items())},
        "tag_size": result.tag_size,
        "on_ground": result.on_ground,
        "tag_posed": {
            name: {"c2w": np.round(c2w, 9).tolist(), "error_px": round(err, 4)}
            for name, (c2w, err) in sorted(result.tag_posed.items())
        },
    }


def load_sfm_result(folder: str | Path, allow_outside: bool = False) -> SfmResult:
    """The aligned SfM result ``nerfkit poses`` left in a dataset folder (its
    ``sfm_report.json`` and model), to rebuild the dataset from the same poses.

    Each photo must lie in the recorded photo folder, and the model inside ``folder``
    (``allow_outside``: anywhere).
    """
    from ..capture.points import sfm_pycolmap
    from ..config import load_json
    from ..data.validate import short_repr
    from ..errors import advice
    from ..io.paths import resolve_inside

    folder = Path(folder)
    path = folder / REPORT_FILE
    redo = "Re-run nerfkit poses --force (or nerfkit dataset --pose-source tags)"
    data = load_json(
        path,
        "no such file: the folder holds no structure-from-motion model (nerfkit poses left none: "
        "--method tags, or SfM's poses were not taken)",
        "Rebuild from the tag poses (nerfkit dataset --pose-source tags), or run nerfkit poses --method auto",
        redo,
    )
    model = data.get("model") if isinstance(data, dict) else None
    if not isinstance(model, dict):
        raise fail(path, "records no SfM model to rebuild the dataset from (an older nerfkit wrote it)", redo)
    with advice(redo):
        try:
            model_dir = resolve_inside(folder, model["dir"], allow_outside, f"{path} model.dir")
            if not (model_dir / "images.bin").is_file() and not (model_dir / "images.txt").is_file():
                raise fail(model_dir, "holds no COLMAP model (the colmap folder was moved or deleted)")
            photos_dir = Path(model["photos_dir"])
            sources = {
                str(name): resolve_inside(photos_dir, file, allow_outside, f"{path} model.photos")
                for name, file in model["photos"].items()
            }
            fields = (
                "n_photos",
                "registered",
                "unregistered",
                "n_points",
                "reprojection_error",
                "n_models",
                "matcher",
                "seconds",
                "frame",
                "camera",
                "ground",
            )
            report = SfmReport(**{k: data[k] for k in fields})
            if isinstance(data.get("focal_check"), dict):  # (none before nerfkit compared focal lengths)
                report.focal_check = data["focal_check"]
            tag_size = model["tag_size"]
            if tag_size is not None and not (isinstance(tag_size, (int, float)) and tag_size > 0):
                raise fail(path, f"model.tag_size is {tag_size!r}, expected a length in metres or null")
            on_ground = bool(model["on_ground"])
            turned = model.get("turned_deg", {})
            if not all(name in sources and deg in (90, 180, 270) for name, deg in turned.items()):
                raise fail(path, f"model.turned_deg is {short_repr(turned)}, expected photo name -> 90, 180 or 270")
            tag_posed = _read_tag_posed(model.get("tag_posed", {}), sources, path)
        except (KeyError, TypeError, AttributeError) as e:
            raise fail(path, f"malformed SfM report ({type(e).__name__}: {e})") from None
    try:
        rec = sfm_pycolmap().Reconstruction(str(model_dir))
    except Exception as e:  # pycolmap raises its own errors for unreadable models
        raise fail(model_dir, f"cannot read the COLMAP model ({type(e).__name__}: {e})", redo) from None
    return SfmResult(
        rec,
        model_dir,
        photos_dir,
        report,
        tag_size=None if tag_size is None else float(tag_size),
        sources=sources,
        on_ground=on_ground,
        turns={n: int(d) // 90 for n, d in turned.items()},
        tag_posed=tag_posed,
    )


def _read_tag_posed(data, sources: dict, path: Path) -> dict[str, tuple[np.ndarray, float]]:
    """``model.tag_posed`` of an SfM report (:func:`saved_model`), checked."""
    from ..data.validate import short_repr

    expected = "expected photo name (of model.photos) -> {c2w: a 4x4 camera-to-world, error_px}"
    if not isinstance(data, dict):
        raise fail(path, f"model.tag_posed is {short_repr(data)}, {expected}")
    out = {}
    for name, entry in data.items():
        try:
            c2w, err = np.array(entry["c2w"], np.float64), float(entry["error_px"])
            ok = (
                name in sources and c2w.shape == (4, 4) and np.isfinite(c2w).all() and np.allclose(c2w[3], [0, 0, 0, 1])
            )
        except (TypeError, ValueError, KeyError, IndexError):
            ok = False
        if not ok:
            raise fail(path, f"model.tag_posed has {short_repr(name)}: {short_repr(entry)}, {expected}")
        out[name] = (c2w, err)
    return out


def sfm_dataset(
    image_dir: str | Path,
    out_dir: str | Path,
    cfg: DatasetConfig | None = None,
    matcher: str = "auto",
    max_image_size: int = 1000,
    tag_size: float | None = None,
    tag_id: int = 0,
    tag_dict: str = "DICT_4X4_50",
    camera_model: str = "SIMPLE_RADIAL",
    threads: int = -1,
    seed: int = 0,
    jobs: int = 2,
    progress: bool = True,
    verbose: bool = False,
    ground: bool = True,
    camera=None,
) -> tuple[Scene, SfmReport, dict]:
    """Photos -> SfM -> world frame -> dataset in ``out_dir``: the scene, SfM's report and the
    dataset builder's summary (what ``nerfkit poses`` says of the dataset, as for the tag path).

    The world frame is the tag's (metres, +z up) when ``tag_size`` is given and tag
    ``tag_id`` is seen in at least 3 registered photos, else normalised (see
    :func:`nerfkit.sfm.frame.align_reconstruction`; without a tag and with ``ground``, the
    table plane found in the sparse points becomes z = 0 and the dataset's table, as a tag's
    would). ``cfg`` holds the dataset options
    (size, splits, near/far) shared with the tag path. COLMAP's files stay in
    ``out_dir/colmap`` (database and the aligned model ``sparse/0``). ``camera``: a
    calibrated camera SfM starts from (see :func:`~nerfkit.sfm.colmap.run_sfm`); the report
    compares its focal length with the one SfM finds (:mod:`~nerfkit.capture.focal`).
    """
    from ..capture.focal import focal_check
    from .colmap import sfm_focal

    result = run_sfm(
        image_dir,
        out_dir,
        matcher=matcher,
        max_image_size=max_image_size,
        camera_model=camera_model,
        threads=threads,
        seed=seed,
        progress=progress,
        verbose=verbose,
        camera=camera,
    )
    shared = sfm_focal(result.reconstruction)
    checked = focal_check(camera, sfm=None if shared is None else (*shared, result.reconstruction.num_reg_images()))
    result.report.focal_check = None if checked is None else checked.as_json()
    align_reconstruction(result, tag_size=tag_size, tag_id=tag_id, tag_dict=tag_dict, progress=progress, ground=ground)
    from ..capture.aruco import Layout

    tags = (
        Layout.single(tag_id, result.tag_size).corners() if result.tag_size is not None else None
    )  # the tag at the origin
    extra = {"focal_check": result.report.focal_check} if camera is not None else None
    scene, summary = build_dataset(result, out_dir, cfg, jobs=jobs, progress=progress, extra=extra, tags=tags)
    return scene, result.report, summary
