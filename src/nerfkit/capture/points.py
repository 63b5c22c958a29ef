"""Sparse 3D points from posed photos: COLMAP's point triangulator with the poses held.

Also the COLMAP steps that use known (or guessed) poses, which structure from motion
(:mod:`nerfkit.sfm.colmap`) shares: pairs of neighbouring cameras and matching only those.

A tag capture has poses but no structure. Gaussian splatting starts best from points on
the surfaces (3DGS initialises from the SfM points), so :func:`triangulate_views` runs
what ``colmap point_triangulator`` does, through pycolmap: SIFT features on the
(undistorted) views, matching (every pair up to ``EXHAUSTIVE_MAX`` views, else each view
with its ``neighbours`` nearest cameras, chosen from the known poses), then triangulation
and point-only bundle adjustment with the cameras fixed. Returns points in the views'
world frame with their colours and reprojection errors.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..data.colmap import SparsePoints, import_pycolmap, reconstruction_points
from ..data.scene import Views
from ..errors import fail
from . import colmap_calls

EXHAUSTIVE_MAX = 120


def triangulate_views(
    views: Views,
    work: str | Path | None = None,
    max_features: int = 4096,
    neighbours: int = 20,
    max_error: float = 2.0,
    min_track: int = 3,
    threads: int = -1,
    verbose: bool = False,
) -> SparsePoints:
    """Triangulate sparse points from posed views with their images (e.g. a dataset's
    train split: undistorted, pinhole, nerfkit's conventions).

    Args:
        views: posed views with images (all of one size; one pinhole camera per view).
        work: folder for COLMAP's scratch files (images, database); a temporary folder
            inside it is made and removed. None: the system's temporary folder.
        max_features: SIFT features per image; neighbours: views matched with each view
            beyond ``EXHAUSTIVE_MAX`` views.
        max_error, min_track: points kept have a mean reprojection error <= ``max_error``
            pixels and are seen in at least ``min_track`` views.
    Raises:
        NerfkitError without pycolmap or when the views have no images.
    """
    pycolmap = sfm_pycolmap()
    import cv2

    if not views.has_images or len(views) < 2:
        raise fail("triangulation", f"needs at least 2 views with images, got {len(views)}")
    assert views.images is not None  # has_images
    if work is not None:
        Path(work).mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".triangulate-", dir=None if work is None else str(work)))
    try:
        image_dir = tmp / "images"
        image_dir.mkdir()
        names = [f"{i:05d}.png" for i in range(len(views))]
        for name, img in zip(names, views.images):
            cv2.imwrite(str(image_dir / name), np.ascontiguousarray(img[..., ::-1]))
        db_path = tmp / "database.db"
        with quiet_colmap(verbose):
            _extract(pycolmap, db_path, image_dir, names, views, max_features, threads)
            _match(pycolmap, db_path, names, views.c2w, neighbours, threads)
            posed = tmp / "posed"
            posed.mkdir()
            _posed_reconstruction(pycolmap, db_path, names, views.c2w).write(str(posed))
            options = pycolmap.IncrementalPipelineOptions()
            options.num_threads = threads
            (tmp / "sparse").mkdir()
            colmap_calls.run(
                "triangulate_points", db_path, image_dir, tmp / "sparse", options=options, reconstruction=posed
            )
            rec = pycolmap.Reconstruction(str(tmp / "sparse"))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    view_names = views.names or [str(i) for i in range(len(views))]
    return reconstruction_points(rec, max_error, min_track, dict(zip(names, view_names)).__getitem__)


def _extract(
    pycolmap, db_path: Path, image_dir: Path, names: list[str], views: Views, max_features: int, threads: int
) -> None:
    K = views.K[0].astype(np.float64)
    if not np.allclose(views.K, K, rtol=1e-5, atol=1e-4):
        raise fail("triangulation", "the views have different intrinsics; one shared camera is needed")
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"  # nerfkit's K and COLMAP's share pixel centres at +0.5
    reader.camera_params = f"{K[0, 0]},{K[1, 1]},{K[0, 2]},{K[1, 2]}"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.sift.max_num_features = max_features
    colmap_calls.run(
        "extract_features",
        db_path,
        image_dir,
        image_names=names,
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )


def _match(pycolmap, db_path: Path, names: list[str], c2w: np.ndarray, neighbours: int, threads: int) -> None:
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    if len(names) <= EXHAUSTIVE_MAX:
        colmap_calls.run("match_exhaustive", db_path, matching_options=matching, device=pycolmap.Device.cpu)
        return
    match_pairs(
        pycolmap,
        db_path,
        [(names[i], names[j]) for i, j in camera_neighbours(c2w, neighbours)],
        matching,
        pycolmap.TwoViewGeometryOptions(),
    )


def _posed_reconstruction(pycolmap, db_path: Path, names: list[str], c2w: np.ndarray):
    """An empty reconstruction of the database's cameras and images, every frame posed
    from ``c2w`` (the poses triangulation keeps fixed)."""
    rec = pycolmap.Reconstruction()
    index = {n: i for i, n in enumerate(names)}
    with pycolmap.Database.open(db_path) as db:
        cams, rigs, frames, images = (
            db.read_all_cameras(),
            db.read_all_rigs(),
            db.read_all_frames(),
            db.read_all_images(),
        )
    for c in cams:
        rec.add_camera(c)
    for r in rigs:
        rec.add_rig(r)
    for f in frames:
        rec.add_frame(f)
    for im in images:
        m = c2w[index[im.name]].astype(np.float64)
        R, t = m[:3, :3], m[:3, 3]
        image = pycolmap.Image(im.name, [], im.camera_id, im.image_id)
        image.frame_id = im.frame_id
        rec.add_image(image)
        rec.frame(im.frame_id).rig_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(R.T), -R.T @ t)
    for f in frames:
        rec.register_frame(f.frame_id)
    return rec


def sfm_pycolmap():
    """pycolmap for structure-from-motion, or the clear error that says how to install it."""
    return import_pycolmap("poses --method colmap", "structure-from-motion needs pycolmap")


@contextlib.contextmanager
def quiet_colmap(verbose: bool) -> Iterator[None]:
    """Silence COLMAP's INFO/WARNING log lines unless ``verbose``; what it logs goes to
    stderr only (its logging library otherwise leaves log files in the temporary folder)."""
    import pycolmap

    old = pycolmap.logging.minloglevel, pycolmap.logging.logtostderr
    pycolmap.logging.logtostderr = True
    if not verbose:
        pycolmap.logging.minloglevel = 2
    try:
        yield
    finally:
        pycolmap.logging.minloglevel, pycolmap.logging.logtostderr = old


def camera_neighbours(c2w: np.ndarray, k: int) -> list[tuple[int, int]]:
    """Pairs ``(i, j)``, ``i < j``, joining each camera to the ``k`` others that see most
    alike: nearest in position, with the angle between optical axes as a tie-breaker
    (distance in units of the median camera spacing plus the axes' angle in radians).

    Args:
        c2w: (n, 4, 4) camera-to-world (OpenCV axes); k: neighbours per camera.
    """
    n = len(c2w)
    pos = c2w[:, :3, 3].astype(np.float64)
    axis = c2w[:, :3, 2].astype(np.float64)
    dist = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    spacing = float(np.median(np.sort(dist, axis=1)[:, 1])) if n > 1 else 1.0
    angle = np.arccos(np.clip(axis @ axis.T, -1.0, 1.0))
    cost = dist / max(spacing, 1e-12) + angle
    np.fill_diagonal(cost, np.inf)
    pairs = set()
    for i in range(n):
        for j in np.argsort(cost[i])[: min(k, n - 1)]:
            pairs.add((min(i, int(j)), max(i, int(j))))
    return sorted(pairs)


def match_pairs(
    pycolmap, db_path: Path, pairs: list[tuple[str, str]], matching, verification, seed: int | None = None
) -> None:
    """Match and verify the features of these photo pairs only (a pairs file beside the
    database), in a child process (:func:`.colmap_calls.run`, with ``seed``)."""
    pairs_file = db_path.parent / "pairs.txt"
    pairs_file.write_text("".join(f"{a} {b}\n" for a, b in pairs))
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = str(pairs_file)
    colmap_calls.run(
        "match_image_pairs",
        db_path,
        matching_options=matching,
        pairing_options=pairing,
        verification_options=verification,
        device=pycolmap.Device.cpu,
        seed=seed,
    )
