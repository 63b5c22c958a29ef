"""Camera poses without tags: structure-from-motion with pycolmap (COLMAP).

What nerfstudio's ``ns-process-data`` and instant-ngp's ``colmap2nerf`` do:

1. SIFT features (images limited to ``max_image_size`` pixels for speed),
2. exhaustive matching (every pair; small sets) or sequential matching (neighbours in
   file-name order; long captures),
3. incremental mapping with one shared camera (SIMPLE_RADIAL: focal, centre, k1),
4. a registration report: how many photos got a pose, and why the others did not,
5. a world frame (:mod:`nerfkit.sfm.frame`): metric from the ArUco tags seen in the
   photos, else normalised.

The output folder holds ``colmap/database.db`` and the aligned model ``colmap/sparse/0``;
:func:`nerfkit.sfm.build_dataset` then writes the undistorted dataset. Steps 1-3 each run in
a child process (:mod:`nerfkit.capture.colmap_calls`), so that Ctrl-C or SIGTERM ends them
at once; ``colmap/`` replaces an earlier run's only when SfM finishes.
"""

from __future__ import annotations

import shutil
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..capture import colmap_calls
from ..capture.points import camera_neighbours, match_pairs, quiet_colmap, sfm_pycolmap
from ..data.colmap import write_reconstruction
from ..errors import NerfkitError, fail, problem_of
from ..images import list_images
from ..io.atomic import replacing_folder

if TYPE_CHECKING:  # pragma: no cover
    import pycolmap

MATCHERS = ("auto", "exhaustive", "sequential", "spatial")
# "auto" matches every pair up to this many photos; beyond, "spatial" when guide poses (a
# tag's) cover half the photos, else "sequential" (neighbours in name order).
EXHAUSTIVE_MAX = 100
# "spatial" matches each photo with a guide pose with this many others whose poses see most
# alike, and every photo with its neighbours in name order (sequential's pairs and more).
# On a 56-photo capture: about half the pairs of exhaustive matching, SfM about a third
# faster, held-out views within 0.1 dB at the same step (benchmarks/capture_real.py --sfm).
SPATIAL_NEIGHBOURS = 20
FEW_FEATURES = 100


@dataclass
class SfmReport:
    """What structure-from-motion achieved.

    Attributes:
        n_photos: photos found; registered: names that got a pose;
        unregistered: name -> reason for the others;
        n_points: sparse 3D points; reprojection_error: mean, pixels;
        n_models: separate reconstructions found (only the largest is used);
        matcher: "exhaustive", "sequential" or "spatial"; seconds: stage -> wall time;
        frame: how the world frame was fixed (tag / normalised), human readable.
    """

    n_photos: int
    registered: list[str]
    unregistered: dict[str, str]
    n_points: int
    reprojection_error: float
    n_models: int
    matcher: str
    seconds: dict[str, float] = field(default_factory=dict)
    frame: str = ""
    camera: dict = field(default_factory=dict)
    ground: dict | None = None  # the table plane found in the points (no tag), see ground.py
    # the camera file's focal length against the one SfM found (capture.focal.FocalCheck.as_json)
    focal_check: dict | None = None

    def summary(self) -> str:
        """A few lines for the terminal."""
        lines = [
            f"registered {len(self.registered)} of {self.n_photos} photos "
            f"({self.n_points} points, mean reprojection error {self.reprojection_error:.2f} px, "
            f"{self.matcher} matching, {sum(self.seconds.values()):.0f} s)"
        ]
        if self.n_models > 1:
            lines.append(f"  SfM found {self.n_models} separate models; using the largest")
        for name, why in sorted(self.unregistered.items()):
            lines.append(f"  not registered: {name}: {why}")
        if self.frame:
            lines.append(f"  world frame: {self.frame}")
        if self.focal_check is not None:
            from ..capture.focal import FocalCheck

            lines.append(FocalCheck.from_json(self.focal_check).line())
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {
            "n_photos": self.n_photos,
            "n_registered": len(self.registered),
            "registered": self.registered,
            "unregistered": self.unregistered,
            "n_points": self.n_points,
            "reprojection_error": self.reprojection_error,
            "n_models": self.n_models,
            "matcher": self.matcher,
            "seconds": self.seconds,
            "frame": self.frame,
            "camera": self.camera,
            "ground": self.ground,
            "focal_check": self.focal_check,
        }


@dataclass
class SfmResult:
    """The largest reconstruction (in the final world frame), its folder, and the report."""

    reconstruction: pycolmap.Reconstruction
    model_dir: Path
    image_dir: Path  # the upright photos COLMAP used (the input folder, or upright copies)
    report: SfmReport
    tag_size: float | None = None  # set when the world frame is the tag's (metres)
    sources: dict[str, Path] = field(default_factory=dict)  # COLMAP image name -> the user's photo
    on_ground: bool = False  # no tag, but z = 0 is the table plane found in the sparse points
    turns: dict[str, int] = field(default_factory=dict)  # COLMAP image name -> clockwise quarter turns from upright
    # COLMAP image name -> (camera-to-world (4, 4), RMS px) of photos SfM missed that keep their tag poses
    tag_posed: dict[str, tuple[np.ndarray, float]] = field(default_factory=dict)

    def photo(self, name: str) -> Path:
        """The user's photo COLMAP knows as ``name`` (HEIC photos: their own name, not the copy's)."""
        return self.sources.get(name, self.image_dir / name)


def _say(progress: bool, msg: str) -> None:
    if progress:
        print(msg, file=sys.stderr, flush=True)


# told "features", "matching" and "mapping" as each step of :func:`run_sfm` starts
_STEP_STARTED: ContextVar[Callable[[str], None] | None] = ContextVar("sfm_step_started", default=None)


@contextmanager
def telling_steps(started: Callable[[str], None]) -> Iterator[None]:
    """Within it, ``started(name)`` is called as each step of structure-from-motion starts
    (``nerfkit capture`` numbers them under its poses heading)."""
    token = _STEP_STARTED.set(started)
    try:
        yield
    finally:
        _STEP_STARTED.reset(token)


def _started(name: str) -> None:
    started = _STEP_STARTED.get()
    if started is not None:
        started(name)


def choose_matcher(matcher: str, n_photos: int, n_guided: int = 0) -> str:
    """The matcher to run on ``n_photos`` photos, ``n_guided`` of them with guide poses."""
    if matcher not in MATCHERS:
        raise fail("--matcher", f"'{matcher}' is not one of {', '.join(MATCHERS)}")
    if matcher == "spatial" and not n_guided:
        raise fail(
            "--matcher",
            "spatial pairs the photos by their tag poses, and no photo has one",
            "Use it with --method auto on photos of a tag, or choose another matcher",
        )
    if matcher == "auto":
        if n_photos <= EXHAUSTIVE_MAX:
            return "exhaustive"
        return "spatial" if 2 * n_guided >= n_photos else "sequential"
    return matcher


def spatial_pairs(names: list[str], guides: dict[str, np.ndarray], k: int, overlap: int) -> list[tuple[str, str]]:
    """The photo pairs "spatial" matching compares: each photo with a guide pose and the
    ``k`` others whose guide poses see most alike (:func:`camera_neighbours`), and every
    photo with the next ``overlap`` in ``names``' order (so a photo without a guide pose,
    e.g. one that hides the tag, still meets the photos taken just before and after it).

    Args:
        names: the photos (COLMAP names, in name order); guides: name -> (4, 4)
            camera-to-world, for some of them; k, overlap: neighbours per photo.
    Returns:
        Pairs of names, each pair once, ordered as in ``names``.
    """
    index = {n: i for i, n in enumerate(names)}
    guided = [n for n in names if n in guides]
    pairs = set()
    if len(guided) > 1:
        c2w = np.stack([np.asarray(guides[n], dtype=np.float64) for n in guided])
        pairs |= {(index[guided[i]], index[guided[j]]) for i, j in camera_neighbours(c2w, k)}
    pairs |= {(i, j) for i in range(len(names)) for j in range(i + 1, min(i + 1 + overlap, len(names)))}
    return [(names[i], names[j]) for i, j in sorted(pairs)]


# Formats COLMAP reads directly; others (HEIC, WebP, ...) are converted first.
COLMAP_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp"}


@dataclass
class PhotoInfo:
    """What the photo header says: upright size, EXIF orientation and 35 mm focal length."""

    path: Path
    width: int
    height: int
    orientation: int
    f35: float | None


def photo_info(path: Path) -> PhotoInfo:
    """Header facts of one photo (no pixel decoding, except for formats PIL must decode)."""
    from ..images import _open, exif_focal_35mm, orientation_tag, upright_size

    img = _open(path)
    orientation = orientation_tag(img)
    return PhotoInfo(path, *upright_size(img, orientation), orientation, exif_focal_35mm(path))


def colmap_name(photo: Path) -> str:
    """The name COLMAP knows a photo by: its own, or with ``.jpg`` / ``.png`` added to a
    format COLMAP cannot read (HEIC: JPEG copies; others: PNG)."""
    suffix = photo.suffix.lower()
    if suffix in COLMAP_SUFFIXES:
        return photo.name
    return photo.name + (".jpg" if suffix in (".heic", ".heif") else ".png")


def prepare_photos(
    photos: list[Path], work: Path, progress: bool = True, camera=None
) -> tuple[Path, list[str], dict[str, str], PhotoInfo | None, dict[str, int]]:
    """Photos COLMAP can use as nerfkit sees them (upright), all of one size.

    COLMAP ignores EXIF orientation and cannot read HEIC, while nerfkit loads photos
    upright. When a photo needs it, upright copies of all photos are written to
    ``work/images`` (JPEG inputs stay JPEG, quality 95; others become PNG).
    SfM shares one camera, so all photos take the most common upright size, or that of
    ``camera`` (a capture ``Camera``) when the most common is its transposed. A photo held
    the other way is turned into that frame by its EXIF orientation
    (:func:`nerfkit.images.turns_into_frame`); other sizes are left out, as are photos
    whose EXIF focal length says another lens or zoom than the camera's (else most photos'),
    and photos nerfkit cannot decode (COLMAP would stop at them).

    Returns (folder COLMAP reads, image names in it, left-out name -> reason, the
    header of the first photo used, with the shared size; COLMAP name -> clockwise
    quarter turns of the photos turned).
    """
    from dataclasses import replace

    from ..capture.camera import common_lens, other_lens
    from ..images import (
        common_frame,
        common_size,
        copies,
        copy_reason,
        load_image_uint8,
        turns_into_frame,
        write_image,
    )

    copied = copies(photos)
    infos, skipped = [], {name: copy_reason(first) for name, first in copied.items()}
    for p in photos:
        if p.name in copied:
            continue
        try:
            infos.append(photo_info(p))
        except NerfkitError as e:  # as the tag path records it
            skipped[p.name] = "unreadable: " + problem_of(e)
    if not infos:
        return work, [], skipped, None, {}
    size = common_size((i.width, i.height) for i in infos)
    assert size is not None  # infos is not empty
    W, H = size
    frame = common_frame([i.orientation for i in infos if (i.width, i.height) == (W, H)])
    if camera is not None and camera.compatible(W, H) and not camera.compatible(H, W):
        (W, H), frame = (H, W), None  # the camera's shape
    if camera is not None and camera.sensor_turns is not None:
        frame = camera.sensor_turns  # the calibration's frame, as the tag poses use
    lens = (camera.exif_f35 if camera is not None else None) or common_lens(i.f35 for i in infos)
    kept, turns = [], {}
    for i in infos:
        if why := other_lens(i.f35, lens):
            skipped[i.path.name] = why + " (SfM shares one camera)"
            continue
        if (i.width, i.height) == (H, W) and (turn := turns_into_frame(i.orientation, frame)) is not None:
            turns[colmap_name(i.path)] = turn
        elif (i.width, i.height) != (W, H):
            why = (
                "held the other way, with no EXIF orientation to turn it by"
                if (i.width, i.height) == (H, W)
                else "resized or cropped"
            )
            skipped[i.path.name] = (
                f"{i.width}x{i.height} upright while most photos are {W}x{H}: {why} (SfM shares one camera)"
            )
            continue
        kept.append(i)
    if not kept:
        return work, [], skipped, None, {}
    first = replace(kept[0], width=W, height=H)
    needs_copy = turns or any(i.orientation != 1 or i.path.suffix.lower() not in COLMAP_SUFFIXES for i in kept)
    if not needs_copy:
        return kept[0].path.parent, [i.path.name for i in kept], skipped, first, turns
    out = work / "images"
    _say(progress, f"sfm: writing upright copies of {len(kept)} photos for COLMAP (EXIF rotation or format)...")
    names = []
    for i in kept:
        jpeg = i.path.suffix.lower() in (".jpg", ".jpeg", ".heic", ".heif")
        name = colmap_name(i.path)
        img = load_image_uint8(i.path)
        if name in turns:
            img = np.ascontiguousarray(np.rot90(img, -turns[name]))
        if jpeg:
            from PIL import Image

            from ..io.atomic import atomic_path

            with atomic_path(out / name) as tmp:
                Image.fromarray(img).save(tmp, format="JPEG", quality=95, subsampling=0)  # 4:4:4 keeps detail
        else:
            write_image(out / name, img)
        names.append(name)
    return out, names, skipped, first, turns


def run_sfm(
    image_dir: str | Path,
    out_dir: str | Path,
    matcher: str = "auto",
    max_image_size: int = 1000,
    camera_model: str = "SIMPLE_RADIAL",
    single_camera: bool = True,
    max_features: int = 4096,
    overlap: int = 10,
    threads: int = -1,
    seed: int = 0,
    progress: bool = True,
    verbose: bool = False,
    camera=None,
    refine_camera: bool = True,
    guides: dict[str, np.ndarray] | None = None,
) -> SfmResult:
    """Run SfM on the photos of ``image_dir``; write ``out_dir/colmap/{database.db,sparse/0}``.

    Args:
        matcher: "exhaustive" (all pairs), "sequential" (each photo with the next
            ``overlap`` in name order), "spatial" (by the ``guides`` poses, see
            :func:`spatial_pairs`) or "auto" (exhaustive up to 100 photos; beyond, spatial
            when guide poses cover half the photos, else sequential).
        max_image_size: photos are downscaled to this longest side for features only
            (poses and intrinsics are for the full-size photos).
        camera_model: COLMAP camera model; single_camera: one camera shared by all photos.
        threads: CPU threads (-1: all cores); seed: COLMAP's random seed. Only a run on one
            thread repeats exactly: on several, matching and mapping differ a little from run
            to run (a photo more or less registered on a large capture).
        camera: a calibrated :class:`~nerfkit.capture.camera.Camera` (``nerfkit calibrate``)
            that every photo starts from (``camera_model`` is then ignored); the photos must
            have its aspect ratio. With ``refine_camera`` bundle adjustment refines its focal
            length and radial distortion on these photos (the principal point stays:
            COLMAP's default; see :func:`colmap_camera`), else it is held fixed.
        guides: COLMAP image name (:func:`colmap_name`) -> rough camera-to-world (4, 4)
            from another source (the tag poses), to choose the pairs "spatial" matches.
    Returns:
        The largest reconstruction (COLMAP's frame; see :func:`~nerfkit.sfm.frame.align_reconstruction`).
    Raises:
        NerfkitError when there are no photos or nothing could be reconstructed.
    """
    pycolmap = sfm_pycolmap()
    image_dir = Path(image_dir)
    photos = list_images(image_dir)
    guides = guides or {}
    matcher = choose_matcher(matcher, len(photos), sum(colmap_name(p) in guides for p in photos))
    if len(photos) < 3:
        raise fail(
            image_dir,
            f"holds {len(photos)} photos; structure-from-motion needs at least 3",
            "Take 30-100 overlapping photos around the object",
        )
    work = Path(out_dir) / "colmap"
    with replacing_folder(work):  # stopped or failed: the earlier folder (or none) stays, not a half-written one
        (work / "sparse").mkdir(parents=True)
        colmap_dir, names, left_out, first, turns = prepare_photos(photos, work, progress, camera)
        if len(names) < 3:
            unreadable = sum(why.startswith("unreadable") for why in left_out.values())
            if len(photos) - unreadable < 3:
                raise fail(
                    image_dir,
                    f"{unreadable} of its {len(photos)} photos are unreadable, leaving "
                    f"{len(photos) - unreadable}; structure-from-motion needs at least 3",
                    "Replace the broken files (poses lists them)",
                )
            raise fail(
                image_dir,
                f"only {len(names)} photos share one size; structure-from-motion needs at least 3",
                "Take all photos held the same way (portrait or landscape)",
            )
        assert first is not None  # None only when no photo is kept
        given = None  # (COLMAP model, params) of the camera file
        if camera is not None:
            why = camera.compatible(first.width, first.height)
            if why:
                raise fail(
                    image_dir,
                    f"the photos do not fit the camera file: {why}",
                    "Calibrate with photos from the same camera, held the same way",
                )
            given = colmap_camera(camera.scaled_to(first.width, first.height), refine=refine_camera)
        db_path = work / "database.db"
        device = pycolmap.Device.cpu
        seconds: dict[str, float] = {}

        with quiet_colmap(verbose):
            t0 = time.perf_counter()
            _started("features")
            _say(
                progress,
                f"sfm: extracting SIFT features from {len(names)} photos (longest side <= {max_image_size} px)...",
            )
            reader = pycolmap.ImageReaderOptions()
            reader.camera_model = camera_model
            if given is not None:
                reader.camera_model, reader.camera_params = given
            elif colmap_dir != image_dir and first.f35 and camera_model == "SIMPLE_RADIAL":
                # The copies lost their EXIF; give COLMAP the focal length it would have read.
                from ..capture.camera import exif_fx

                f = exif_fx(first.f35, first.width, first.height)
                reader.camera_params = f"{f},{first.width / 2},{first.height / 2},0"
            extraction = pycolmap.FeatureExtractionOptions()
            extraction.max_image_size = max_image_size
            extraction.num_threads = threads
            extraction.sift.max_num_features = max_features
            try:
                colmap_calls.run(
                    "extract_features",
                    db_path,
                    colmap_dir,
                    image_names=names,
                    camera_mode=(pycolmap.CameraMode.SINGLE if single_camera else pycolmap.CameraMode.AUTO),
                    reader_options=reader,
                    extraction_options=extraction,
                    device=device,
                    seed=seed,
                )
            except Exception as e:  # noqa: BLE001 - e.g. an unknown camera model name
                raise fail(
                    image_dir, f"feature extraction failed ({e})", "Check --camera-model and the photos"
                ) from None
            seconds["features"] = time.perf_counter() - t0

            t0 = time.perf_counter()
            pairs = spatial_pairs(names, guides, SPATIAL_NEIGHBOURS, overlap) if matcher == "spatial" else []
            n_pairs = {"exhaustive": len(names) * (len(names) - 1) // 2, "spatial": len(pairs)}.get(
                matcher, len(names) * overlap
            )
            _started("matching")
            _say(progress, f"sfm: {matcher} matching (~{n_pairs} photo pairs)...")
            matching = pycolmap.FeatureMatchingOptions()
            matching.num_threads = threads
            verification = pycolmap.TwoViewGeometryOptions()
            verification.ransac.random_seed = seed
            if matcher == "spatial":
                match_pairs(pycolmap, db_path, pairs, matching, verification, seed=seed)
            elif matcher == "exhaustive":
                colmap_calls.run(
                    "match_exhaustive",
                    db_path,
                    matching_options=matching,
                    verification_options=verification,
                    device=device,
                    seed=seed,
                )
            else:
                pairing = pycolmap.SequentialPairingOptions()
                pairing.overlap = overlap
                colmap_calls.run(
                    "match_sequential",
                    db_path,
                    matching_options=matching,
                    pairing_options=pairing,
                    verification_options=verification,
                    device=device,
                    seed=seed,
                )
            seconds["matching"] = time.perf_counter() - t0

            t0 = time.perf_counter()
            _started("mapping")
            _say(progress, "sfm: incremental mapping...")
            options = pycolmap.IncrementalPipelineOptions()
            options.num_threads = threads
            options.random_seed = seed
            options.min_model_size = 3
            if given is not None and not refine_camera:
                options.ba_refine_focal_length = False
                options.ba_refine_principal_point = False
                options.ba_refine_extra_params = False
                options.mapper.abs_pose_refine_focal_length = False
                options.mapper.abs_pose_refine_extra_params = False
            colmap_calls.run(
                "incremental_mapping",
                db_path,
                colmap_dir,
                work / "sparse",
                options=options,
                next_image_callback=colmap_calls.SayRegistered() if progress else None,
                seed=seed,
            )
            models = written_models(pycolmap, work / "sparse")
            seconds["mapping"] = time.perf_counter() - t0

        if not models:
            why_not = {**registration_report(db_path, names, None, {}), **left_out}
            reasons = "; ".join(sorted(set(why_not.values())))[:300]
            raise fail(
                image_dir,
                f"structure-from-motion registered no photos ({reasons})",
                "Take more overlapping photos of a textured scene, or use ArUco tags (--method tags)",
            )
        best_key = max(models, key=lambda k: models[k].num_reg_images())
        rec = models[best_key]
        unregistered = {
            **registration_report(db_path, names, rec, {k: m for k, m in models.items() if k != best_key}),
            **left_out,
        }
        registered = sorted(rec.images[i].name for i in rec.reg_image_ids())
        cam = next(iter(rec.cameras.values()))
        report = SfmReport(
            n_photos=len(photos),
            registered=registered,
            unregistered=unregistered,
            n_points=rec.num_points3D(),
            reprojection_error=float(rec.compute_mean_reprojection_error()),
            n_models=len(models),
            matcher=matcher,
            seconds={k: round(v, 2) for k, v in seconds.items()},
            camera={
                "model": cam.model_name,
                "width": cam.width,
                "height": cam.height,
                "params": [float(p) for p in cam.params],
            },
        )
        # Keep one model: the largest, as sparse/0.
        model_dir = work / "sparse" / "0"
        for sub in (work / "sparse").iterdir():
            shutil.rmtree(sub) if sub.is_dir() else sub.unlink()
        write_reconstruction(rec, model_dir)
    _say(progress, "sfm: " + report.summary().splitlines()[0])
    return SfmResult(rec, model_dir, colmap_dir, report, sources={colmap_name(p): p for p in photos}, turns=turns)


def written_models(pycolmap, folder: Path) -> dict[int, pycolmap.Reconstruction]:
    """The models incremental mapping wrote into ``folder`` (``0``, ``1``, ...), by number."""
    return {int(d.name): pycolmap.Reconstruction(str(d)) for d in folder.iterdir() if d.is_dir() and d.name.isdigit()}


def sfm_focal(rec) -> tuple[float, int, int] | None:
    """``(fx in pixels, width, height)`` of the camera a reconstruction's registered photos share
    (bundle adjustment's), or None when none is registered."""
    ids = list(rec.reg_image_ids())
    if not ids:
        return None
    cam = rec.cameras[rec.images[ids[0]].camera_id]
    return float(cam.focal_length_x), int(cam.width), int(cam.height)


def colmap_camera(camera, refine: bool = False) -> tuple[str, str]:
    """A capture :class:`~nerfkit.capture.camera.Camera` (OpenCV: pixel centres at
    integers, k1 k2 p1 p2 k3) as COLMAP's ``(model name, params string)``.

    Held fixed (``refine`` False): PINHOLE without distortion, OPENCV without k3, else
    FULL_OPENCV (k4..k6 = 0); the inverse of :func:`nerfkit.sfm.dataset.opencv_camera`.
    As a start for bundle adjustment (``refine``): the smallest model that holds the
    camera and one radial term, so that few photos cannot fit spurious distortion (OPENCV
    turned a 12-photo synthetic room's poses by a degree): SIMPLE_RADIAL (one focal
    length, k1) or RADIAL (k1, k2) when fx and fy agree within 1% and there is no
    tangential or k3 term, else as held fixed but never PINHOLE.
    """
    fx, fy = float(camera.K[0, 0]), float(camera.K[1, 1])
    cx, cy = float(camera.K[0, 2]) + 0.5, float(camera.K[1, 2]) + 0.5  # COLMAP's pixel centres are at +0.5
    k1, k2, p1, p2, k3 = (float(x) for x in camera.dist)
    if refine and abs(fx - fy) <= 0.01 * fx and p1 == p2 == k3 == 0.0:
        f = 0.5 * (fx + fy)
        model, params = ("SIMPLE_RADIAL", [f, cx, cy, k1]) if k2 == 0.0 else ("RADIAL", [f, cx, cy, k1, k2])
    elif not camera.has_distortion and not refine:
        model, params = "PINHOLE", [fx, fy, cx, cy]
    elif k3 == 0.0:
        model, params = "OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2]
    else:
        model, params = "FULL_OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]
    return model, ",".join(repr(p) for p in params)


def registration_report(db_path: Path, names: list[str], rec, others: dict) -> dict[str, str]:
    """Why each photo missing from ``rec`` was not registered: name -> reason.

    Reads the feature/match database: too few features, no verified partner photo,
    a separate (smaller) model, or matches that did not yield a pose.
    """
    import pycolmap

    min_inliers = pycolmap.TwoViewGeometryOptions().min_num_inliers
    db = pycolmap.Database.open(str(db_path))
    try:
        ids = {im.name: im.image_id for im in db.read_all_images()}
        n_feat = {name: db.num_keypoints_for_image(i) if db.exists_keypoints(i) else 0 for name, i in ids.items()}
        pair_ids, geoms = db.read_two_view_geometries()
    finally:
        db.close()
    partners: dict[int, int] = {}
    best: dict[int, int] = {}
    for pid, g in zip(pair_ids, geoms):
        a, b = pycolmap.pair_id_to_image_pair(pid)
        n = len(g.inlier_matches)
        for i in (a, b):
            best[i] = max(best.get(i, 0), n)
            if n >= min_inliers:
                partners[i] = partners.get(i, 0) + 1
    in_rec = set() if rec is None else {rec.images[i].name for i in rec.reg_image_ids()}
    in_other = {}
    for m in others.values():
        for i in m.reg_image_ids():
            in_other[m.images[i].name] = m.num_reg_images()
    out = {}
    for name in names:
        if name in in_rec:
            continue
        image_id = ids.get(name)
        if image_id is None:
            out[name] = "could not be read by COLMAP"
        elif n_feat.get(name, 0) < FEW_FEATURES:
            out[name] = f"only {n_feat.get(name, 0)} features (blurred, dark or textureless?)"
        elif partners.get(image_id, 0) == 0:
            out[name] = (
                f"matched no other photo (best pair: {best.get(image_id, 0)} verified matches, "
                f"needs {min_inliers}); too little overlap with the others?"
            )
        elif name in in_other:
            out[name] = f"in a separate model of {in_other[name]} photos that did not connect to the main one"
        else:
            out[name] = f"matched {partners[image_id]} photos but no pose could be estimated from them"
    return out
