"""Camera poses of object photos from the tag(s) they show (``cv2.solvePnP``).

World frame: the frame of the tag (``--tag-id``) or of the layout (``--layout``):
origin at the tag centre (layouts: the layout's origin), ``x`` to the right and ``y`` up
the printed tag, ``z`` out of the tag toward the cameras. The scene's ``up`` is ``+z``,
the tag-plane normal pointing toward the cameras, so orbits circle about the table's
normal. Units are those of ``--tag-size`` (metres).

One tag: ``SOLVEPNP_IPPE_SQUARE`` (made for one square; both of its solutions are checked
and the better kept, the ratio of their errors recorded as ``pose_ambiguity``). Several
tags of a layout: all visible corners jointly (SQPnP and per-tag IPPE starts, refined with
Levenberg-Marquardt); a tag that disagrees with the others (occluded by the object,
lifted paper) is dropped and the pose refitted.

A fit is judged against what the calibration and the tag's size make plausible
(:func:`error_limit`): by default ``max(3 x the calibration's held-out error, 1 px, 2% of the
tag's side in pixels)``, so large tags in big photos are not held to a small-photo figure.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import option
from ..errors import fail
from ..images import held_as
from .aruco import Detection, Layout, quad_sides, square_corners, tag_pose_in_layout
from .camera import Camera, camera_from_focal, common_lens, exif_fx, other_lens
from .photos import PhotoRecord, blur_hint, frame_turns, keep_one_lens, turn_into_frame

UP = np.array([0.0, 0.0, 1.0], np.float32)
# Automatic error limit: this many times the calibration's held-out error ...
HELDOUT_FACTOR = 3.0
# ... assumed held-out error (px) when the camera does not say (EXIF focal length) ...
DEFAULT_HELDOUT_PX = 1.0
# ... and at least this (px), and this fraction of the tag side in pixels (corner precision
# scales with the tag's size in the photo: blur, JPEG, print quality).
FLOOR_PX = 1.0
FLOOR_OF_TAG_SIDE = 0.02


@dataclass
class PoseConfig:
    """Options of ``nerfkit poses``."""

    max_error: float = option(
        0.0,
        "skip photos whose pose reprojection error (RMS, pixels) exceeds this; 0: "
        "automatic, max(3 x the calibration's held-out error, 1 px, 2% of the tag's side "
        "in pixels)",
        min=0,
    )
    min_tag_px: float = option(
        16.0, "skip photos whose tag is smaller than this many pixels across (too small for a reliable pose)", min=0
    )
    refine_focal: bool = option(
        True,
        "fit the focal length to the tags of these photos when they pin it (the "
        "principal point, aspect ratio and distortion stay the camera's): a phone focused "
        "on a near object has a longer focal length than when it photographed the sheet",
    )


@dataclass
class PosedPhoto:
    """A photo with its pose.

    Attributes:
        name: file name; path: full path.
        c2w: (4, 4) float64 camera-to-world, OpenCV axes, world = tag/layout frame.
        error_px: RMS reprojection error of the tag corners.
        camera: the camera of this photo's size (OpenCV convention).
        turns: clockwise quarter turns that bring the upright photo into the camera's
            frame (a photo held the other way); the pose is that of the turned photo.
    """

    name: str
    path: Path
    c2w: np.ndarray
    error_px: float
    camera: Camera
    turns: int = 0


def rt_to_c2w(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """OpenCV's world-to-camera (rvec, tvec) -> (4, 4) camera-to-world."""
    import cv2

    R = cv2.Rodrigues(np.asarray(rvec, np.float64))[0]
    c2w = np.eye(4)
    c2w[:3, :3] = R.T
    c2w[:3, 3] = -R.T @ np.ravel(tvec)
    return c2w


def reprojection_rms(obj: np.ndarray, img: np.ndarray, rvec, tvec, K, dist) -> float:
    import cv2

    proj, _ = cv2.projectPoints(obj.reshape(-1, 1, 3).astype(np.float64), rvec, tvec, K, dist)
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img.reshape(-1, 2)) ** 2, axis=1))))


def solve_pose(det: Detection, camera: Camera, layout: Layout) -> tuple[np.ndarray | None, float, str, dict]:
    """Pose of one photo in the layout's frame.

    Returns:
        ``(c2w, error_px, reason, info)``: c2w (4, 4) or None with the reason when the
        photo has no usable tag.
    """
    import cv2

    K, dist = camera.K, camera.dist
    obj, img, used = layout.match(det)
    if not used:
        seen = sorted({int(i) for i in det.ids})
        if not seen:
            return None, float("nan"), "no tags found", {}
        want = ", ".join(map(str, layout.ids[:8]))
        return None, float("nan"), f"tag {want} not found (saw ids {seen})", {}
    info: dict = {"tags_used": used}
    candidates: list[tuple[np.ndarray, np.ndarray]] = []
    ambiguity = None
    for tag in used if layout.charuco is None else []:
        i = list(det.ids).index(tag)
        side = float(np.linalg.norm(layout.tags[tag] - np.roll(layout.tags[tag], -1, axis=0), axis=1).mean())
        ok, rvecs, tvecs, errs = cv2.solvePnPGeneric(
            square_corners(side), det.corners[i].reshape(-1, 1, 2), K, dist, flags=cv2.SOLVEPNP_IPPE_SQUARE
        )
        if not ok:
            continue
        errs = np.ravel(errs)
        if len(errs) == 2 and len(used) == 1:
            ambiguity = float(max(errs) / max(min(errs), 1e-9))
        T_sheet_tag = tag_pose_in_layout(layout.tags[tag])
        for rv, tv in zip(rvecs, tvecs):
            T_cam_tag = np.eye(4)
            T_cam_tag[:3, :3] = cv2.Rodrigues(rv)[0]
            T_cam_tag[:3, 3] = np.ravel(tv)
            T_cam_sheet = T_cam_tag @ np.linalg.inv(T_sheet_tag)
            candidates.append((cv2.Rodrigues(T_cam_sheet[:3, :3])[0], T_cam_sheet[:3, 3].reshape(3, 1)))
    if len(obj) >= 6 and (len(used) > 1 or layout.charuco is not None):
        ok, rv, tv = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_SQPNP)
        if ok:
            candidates.append((rv, tv))
    if not candidates:
        return None, float("nan"), "pose estimation failed", info
    best = None
    for rv, tv in candidates:
        rv, tv = rv.astype(np.float64).copy(), tv.astype(np.float64).copy()
        if len(obj) > 4:  # one square: IPPE alone (LM refinement measured no better)
            rv, tv = cv2.solvePnPRefineLM(obj, img, K, dist, rv, tv)
        err = reprojection_rms(obj, img, rv, tv, K, dist)
        if best is None or err < best[0]:
            best = (err, rv, tv)
    assert best is not None  # candidates is not empty, and the first one is taken
    err, rv, tv = best
    if ambiguity is not None:
        info["pose_ambiguity"] = round(ambiguity, 2)
    c2w = rt_to_c2w(rv, tv)
    if c2w[2, 3] <= 0:  # the camera would be behind the tag plane: a failed fit
        return None, err, "camera below the tag plane (bad fit)", info
    return c2w, err, "", info


def error_limit(camera: Camera, side_px: float, cfg: PoseConfig) -> tuple[float, str]:
    """(largest plausible RMS reprojection error in px, how it was set) for a photo whose
    largest tag used is ``side_px`` across."""
    if cfg.max_error > 0:
        return cfg.max_error, "--max-error"
    held = camera.heldout_rms if camera.heldout_rms is not None else DEFAULT_HELDOUT_PX
    parts = {
        f"{HELDOUT_FACTOR:g} x held-out {held:.2f} px": HELDOUT_FACTOR * held,
        "floor": FLOOR_PX,
        f"{FLOOR_OF_TAG_SIDE * 100:g}% of the tag side": FLOOR_OF_TAG_SIDE * side_px,
    }
    how = max(parts, key=parts.__getitem__)
    return parts[how], how


def detection_limit(det: Detection, camera: Camera, layout: Layout, cfg: PoseConfig) -> tuple[float, str]:
    """:func:`error_limit` for a photo's detection: by the largest of the layout's tags it shows."""
    sides = [
        tag_side_px(det, int(t))
        for t in set(int(i) for i in det.ids)
        if int(t) in layout.tags and layout.charuco is None
    ]
    return error_limit(camera, max(sides, default=0.0), cfg)


def tag_side_px(det: Detection, tag: int) -> float:
    return float(quad_sides(det.corners[list(det.ids).index(tag)]))


def tag_errors(det: Detection, c2w: np.ndarray, camera: Camera, layout: Layout, used: list[int]) -> dict[int, float]:
    """RMS reprojection error (px) of each used tag under the pose ``c2w``."""
    import cv2

    w2c = np.linalg.inv(c2w)
    rvec = cv2.Rodrigues(w2c[:3, :3])[0]
    ids = list(det.ids)
    return {
        t: reprojection_rms(layout.tags[t], det.corners[ids.index(t)], rvec, w2c[:3, 3], camera.K, camera.dist)
        for t in used
    }


def solve_pose_robust(det: Detection, camera: Camera, layout: Layout, limit: float):
    """:func:`solve_pose`, then, while the fit exceeds ``limit`` and more than one tag is
    used, drop the tag that fits worst and refit. Dropped tags go to ``info["tags_dropped"]``."""
    c2w, err, reason, info = solve_pose(det, camera, layout)
    dropped: dict[int, float] = {}
    while c2w is not None and err > limit and len(info.get("tags_used", [])) > 1 and layout.charuco is None:
        errs = tag_errors(det, c2w, camera, layout, info["tags_used"])
        worst = max(errs, key=errs.__getitem__)
        det = det.without([worst])
        c2w2, err2, reason2, info2 = solve_pose(det, camera, layout)
        if c2w2 is None or err2 >= err:
            break
        dropped[worst] = round(errs[worst], 2)
        c2w, err, reason, info = c2w2, err2, reason2, info2
    if dropped:
        info["tags_dropped"] = {str(t): e for t, e in dropped.items()}
    return c2w, err, reason, info


def choose_tag(records: list[PhotoRecord]) -> tuple[int, str]:
    """The tag id seen in the most photos, and a note about the choice."""
    counts: dict[int, int] = {}
    for r in records:
        if r.detection is not None:
            for t in set(int(i) for i in r.detection.ids):
                counts[t] = counts.get(t, 0) + 1
    if not counts:
        raise fail("poses", "no tags found in any photo")
    best = min(counts, key=lambda t: (-counts[t], t))
    note = f"using tag {best} (seen in {counts[best]} photos)"
    others = {t: c for t, c in counts.items() if t != best}
    if others:
        note += (
            f"; also seen: {', '.join(f'{t} ({c})' for t, c in sorted(others.items()))}. Pass --tag-id to "
            "choose another, or --layout to use several tags together"
        )
    return best, note


# An object standing on a sheet of several tags: the camera file's layout is used, or with
# none a layout is estimated from the object photos, when at least this share of the photos
# with tags show two or more (the tags around a figure's feet: each photo hides some) ...
SEVERAL_TAGS_SHARE = 0.5
# ... in this many rounds of posing the photos on it and placing each tag where they see it.
LAYOUT_ROUNDS = 3


def several_tags(
    records: list[PhotoRecord], tags: set[int] | None = None, size: tuple[int, int] | None = None
) -> tuple[list[PhotoRecord], list[PhotoRecord], bool]:
    """The photos that show two or more tags (of ``tags``; None: any), those that show a tag
    at all, and whether the first are enough to pose on a layout of several tags: two
    photos or more, and :data:`SEVERAL_TAGS_SHARE` of the second. Only photos of ``size``
    (width, height) count, when given."""
    with_tags = [
        r for r in records if r.detection is not None and len(r.detection.ids) and (size is None or r.size == size)
    ]
    several = [r for r in with_tags if len({int(i) for i in r.detected.ids if tags is None or int(i) in tags}) >= 2]
    return several, with_tags, len(several) >= 2 and len(several) >= SEVERAL_TAGS_SHARE * len(with_tags)


def layout_from_photos(
    records: list[PhotoRecord], camera: Camera, tag_size: float, cfg: PoseConfig
) -> tuple[Layout | None, str]:
    """The layout of the tags the photos show together, estimated from the photos
    themselves, and a note; ``(None, "")`` when fewer than :data:`SEVERAL_TAGS_SHARE` of the
    photos with tags show two or more (one tag beside the object: nothing to place).

    The tags start where their single-tag poses put them relative to the most-seen tag
    (:func:`~.calibrate.initial_layout`, medians over the photos); then, for
    :data:`LAYOUT_ROUNDS` rounds, the photos are posed on the layout (a tag that disagrees
    is dropped, :func:`solve_pose_robust`) and every tag but the reference is placed where
    their rays through its corners meet the sheet's plane (:func:`~.calibrate.refine_layout`).
    A tag whose median reprojection error over the photos exceeds their median error limit
    (a tag of another size, one not lying on the sheet's plane) is left out. The world is
    the reference tag's frame, as with ``--tag-id``. Photos of another size than the
    camera's are left out of the estimate."""
    from .calibrate import initial_layout, layout_change, refine_layout

    several, with_tags, enough = several_tags(records, size=(camera.width, camera.height))
    if not enough:
        return None, ""
    layout, ref = initial_layout(several, camera.K, camera.dist, tag_size)
    by_name = {r.name: r for r in several}
    change = float("nan")
    for _ in range(LAYOUT_ROUNDS):
        if len(layout.tags) < 2:
            return None, ""
        posed = _posed_on(several, camera, layout, cfg)
        if not posed:
            return None, ""
        new = refine_layout(by_name, _PosedFit.of(posed, camera), layout, ref, tag_size)
        change = layout_change(new, layout)
        layout = new
    posed = _posed_on(several, camera, layout, cfg)
    errors: dict[int, list[float]] = {}
    for r, c2w, _ in posed:
        shown = sorted(set(int(i) for i in r.detected.ids) & set(layout.tags))
        for t, e in tag_errors(r.detected, c2w, camera, layout, shown).items():
            errors.setdefault(t, []).append(e)
    limit = float(np.median([lim for _, _, lim in posed])) if posed else 0.0
    off = sorted(t for t, e in errors.items() if t != ref and np.median(e) > limit)
    layout = Layout({t: c for t, c in layout.tags.items() if t not in off}, source="estimated from the photos")
    if len(layout.tags) < 2:
        return None, ""
    missing = sorted({int(i) for r in with_tags for i in r.detected.ids} - set(layout.tags) - set(off))
    note = (
        f"estimated the layout of {len(layout.tags)} tags from the photos ({len(several)} of "
        f"{len(with_tags)} with tags show 2 or more; world: tag {ref}'s frame; last change "
        f"{change * 1000:.2f} mm): each photo is posed on all the tags it shows. Pass --single-tag to "
        "pose from one tag"
    )
    if off:
        note += (
            f" (tags {off} fit the photos worse than {limit:.2f} px in the median and are left out: another "
            "size, or off the sheet's plane?)"
        )
    if missing:
        note += f" (tags {missing} were never seen with the others and are left out)"
    return layout, note


def sheet_heights(records: list[PhotoRecord], camera: Camera, layout: Layout, cfg: PoseConfig) -> tuple[Layout, str]:
    """``layout`` with its corners' heights as the sheet lay for these photos, and a note.

    A sheet of tags under the object is paper, not a plane, and it lies differently from
    when the camera was calibrated (a camera file keeps the flat, printed layout): for
    :data:`LAYOUT_ROUNDS` rounds the photos showing two or more of its tags are posed on it
    and each corner's height is triangulated from them (:func:`~.calibrate.refine_heights`).
    Heights above :data:`~.calibrate.MAX_HEIGHT_OF_SIDE` of the tag side leave the layout
    flat. A ChArUco board, one tag, or too few photos showing several: the layout as it is."""
    from .calibrate import MAX_HEIGHT_OF_SIDE, refine_heights

    if layout.charuco is not None or len(layout.tags) < 2 or not layout.is_planar():
        return layout, ""
    several, _, enough = several_tags(records, set(layout.tags), size=(camera.width, camera.height))
    if not enough:
        return layout, ""
    by_name = {r.name: r for r in several}
    flat = layout
    for _ in range(LAYOUT_ROUNDS):
        posed = _posed_on(several, camera, layout, cfg)
        if len(posed) < 2:
            return flat, ""
        layout = refine_heights(by_name, _PosedFit.of(posed, camera), layout)
    height = layout.max_height()
    if height > MAX_HEIGHT_OF_SIDE * flat.tag_size:
        return flat, (
            f"the sheet's corners came out up to {height * 1000:.1f} mm off its plane, more than paper "
            "bends: posed on the flat sheet"
        )
    return layout, (
        f"the sheet lies up to {height * 1000:.2f} mm off its plane in these photos: posed on its "
        f"corners' heights, triangulated from the {len(several)} photos that show 2 or more of its tags"
    )


# The focal length refined on the object photos' own tags (`refine_focal`): a phone focused
# on a near object has a longer focal length than when it photographed the sheet (a few
# percent), and at the refined one the triangulated points fit the photos more closely than at
# the sheet's (`nerfkit poses --method tags`; figures in BENCHMARKS.md). Enough photos ...
FOCAL_MIN_PHOTOS = 8
# ... a change of more than this many standard errors of the estimate, and of this share at
# least (less changes no pose that matters) ...
FOCAL_SIGNIFICANT = 3.0
FOCAL_MIN_CHANGE = 0.005
# ... within this share of the camera's focal length (more is not focus: another lens or a
# wrong tag size in the layout) ...
FOCAL_MAX_CHANGE = 0.10
# ... and pinned to this share (one small tag seen square-on pins little).
FOCAL_MAX_STD = 0.01


@dataclass(frozen=True)
class TagFocal:
    """The focal length the tags of some photos want (:func:`tag_focal`).

    Attributes:
        focal_px: fx in pixels of the camera's size (fy follows at the camera's aspect).
        std: its standard error, a share of it.
        photos: how many photos' tags pinned it.
    """

    focal_px: float
    std: float
    photos: int


def tag_focal(records: list[PhotoRecord], camera: Camera, layout: Layout, cfg: PoseConfig) -> TagFocal | None:
    """The focal length the tags of these photos want, or None with fewer than
    :data:`FOCAL_MIN_PHOTOS` photos (or a ChArUco board, or a fit that fails).

    The photos the camera poses within their error limits give their tags' corners; one
    calibration over them (``cv2.calibrateCameraExtended``) frees the focal length alone: the
    principal point, the aspect ratio and the lens distortion stay the camera's. Photos of
    another lens or shape (which :func:`pose_records` skips) are left out."""
    import cv2

    if layout.charuco is not None:
        return None
    lens = camera.exif_f35 or common_lens(r.exif_f35 for r in records if r.detection is not None)
    obj, img = [], []
    for r in records:  # the photos pose_records would pose: of this camera's lens and shape
        if r.detection is None or other_lens(r.exif_f35, lens) or camera.compatible(*r.detected_size) is not None:
            continue
        scale = camera.width / r.detected_size[0]
        cam = camera if scale == 1 else camera.scaled_to(*r.detected_size)
        limit = detection_limit(r.detection, cam, layout, cfg)[0]
        c2w, err, _, info = solve_pose_robust(r.detection, cam, layout, limit)
        if c2w is None or err > limit:
            continue
        det = r.detection
        for tag in info.get("tags_dropped", {}):  # the tags the pose kept, as it matched them
            det = det.without([int(tag)])
        points, pixels, _ = layout.match(det)
        obj.append(points)
        img.append(((pixels + 0.5) * scale - 0.5).astype(np.float32))
    if len(obj) < FOCAL_MIN_PHOTOS:
        return None
    flags = (
        cv2.CALIB_USE_INTRINSIC_GUESS
        | cv2.CALIB_FIX_PRINCIPAL_POINT
        | cv2.CALIB_FIX_ASPECT_RATIO
        | cv2.CALIB_FIX_TANGENT_DIST
        | cv2.CALIB_FIX_K1
        | cv2.CALIB_FIX_K2
        | cv2.CALIB_FIX_K3
    )
    try:
        _, K, _, _, _, std, _, _ = cv2.calibrateCameraExtended(
            obj, img, (camera.width, camera.height), camera.K.copy(), camera.dist.copy(), flags=flags
        )
    except cv2.error:
        return None
    # the aspect ratio fixed, fy is the free parameter and fx follows it
    change, spread = float(K[1, 1] / camera.K[1, 1]), float(std.ravel()[1] / K[1, 1])
    if not (np.isfinite(change) and change > 0):
        return None
    return TagFocal(float(camera.K[0, 0]) * change, spread, len(obj))


def refine_focal(
    records: list[PhotoRecord], camera: Camera, layout: Layout, cfg: PoseConfig, warn: bool = True
) -> tuple[Camera, str]:
    """``camera`` with its focal length fitted to the tags of these photos, and a note ("" when
    kept as it is, unremarkably): :func:`focal_refined` of :func:`tag_focal`."""
    return focal_refined(camera, tag_focal(records, camera, layout, cfg), warn)


def focal_refined(camera: Camera, estimate: TagFocal | None, warn: bool = True) -> tuple[Camera, str]:
    """``camera`` with the focal length its photos' tags want (``estimate``, :func:`tag_focal`),
    and a note ("" when kept as it is, unremarkably).

    The new focal length is taken when :data:`FOCAL_MIN_PHOTOS` photos or more pin it to
    :data:`FOCAL_MAX_STD` and it moves by more than :data:`FOCAL_SIGNIFICANT` standard errors and
    :data:`FOCAL_MIN_CHANGE`, within :data:`FOCAL_MAX_CHANGE`; beyond, the camera is kept with a
    warning (``warn``; else a plain note: the caller compares the focal lengths itself,
    :mod:`~nerfkit.capture.focal`). The principal point, aspect ratio and distortion stay the
    camera's."""
    if estimate is None:
        return camera, ""
    f0, f, spread = float(camera.K[0, 0]), estimate.focal_px, estimate.std
    change = f / f0 - 1.0
    said = (
        f"the tags of {estimate.photos} photos want a focal length {change * 100:+.1f}% off the camera's "
        f"({f0:.1f} -> {f:.1f} px, +/- {spread * 100:.2f}%)"
    )
    significant = np.isfinite(f) and abs(change) > max(FOCAL_SIGNIFICANT * spread, FOCAL_MIN_CHANGE)
    if significant and abs(change) > FOCAL_MAX_CHANGE:  # said however loosely pinned: the poses' scale is off
        if not warn:
            return camera, f"{said}: more than a phone's focus moves it, so the camera's is kept"
        return camera, (
            f"WARNING: {said}: more than a phone's focus moves it, so the camera's is kept. Another phone, "
            "lens or zoom than the calibration's? Calibrate with it, or leave out --camera"
        )
    if not significant or spread > FOCAL_MAX_STD:
        return camera, ""
    refined = Camera(
        camera.K.copy(),
        camera.dist.copy(),
        camera.width,
        camera.height,
        f"{camera.source}, focal length refined on these photos' tags",
        camera.heldout_rms,
        camera.sensor_turns,
        camera.exif_f35,
    )
    refined.K[:2, :2] *= 1.0 + change
    why = (
        "a phone focused near has a longer focal length than when it photographed the sheet"
        if camera.heldout_rms is not None
        else "a focal length not calibrated is approximate"
    )
    return refined, f"{said}: posed with it ({why}; --no-refine-focal keeps the camera's)"


def _posed_on(
    records: list[PhotoRecord], camera: Camera, layout: Layout, cfg: PoseConfig
) -> list[tuple[PhotoRecord, np.ndarray, float]]:
    """``(record, c2w, error limit)`` of the photos :func:`solve_pose_robust` poses on ``layout``."""
    out = []
    for r in records:
        limit = detection_limit(r.detected, camera, layout, cfg)[0]
        c2w, _, _, _ = solve_pose_robust(r.detected, camera, layout, limit)
        if c2w is not None:
            out.append((r, c2w, limit))
    return out


@dataclass
class _PosedFit:
    """Posed photos in the shape :func:`~.calibrate.refine_layout` reads a calibration's fit."""

    K: np.ndarray
    dist: np.ndarray
    keys: list
    rvecs: list
    tvecs: list

    @staticmethod
    def of(posed: list[tuple[PhotoRecord, np.ndarray, float]], camera: Camera) -> _PosedFit:
        import cv2

        w2cs = [np.linalg.inv(c2w) for _, c2w, _ in posed]
        return _PosedFit(
            camera.K,
            camera.dist,
            [r.name for r, _, _ in posed],
            [cv2.Rodrigues(w2c[:3, :3])[0] for w2c in w2cs],
            [w2c[:3, 3] for w2c in w2cs],
        )


def exif_camera(records: list[PhotoRecord]) -> tuple[Camera, str]:
    """A distortion-free camera from the photos' EXIF FocalLengthIn35mmFilm (most common
    value and size), or a NerfkitError when the photos carry none."""
    values = [(r.exif_f35, r.detected_size) for r in records if r.exif_f35 and r.detection is not None]
    if not values:
        raise fail(
            "poses",
            "no --camera given and the photos have no EXIF FocalLengthIn35mmFilm",
            "Run nerfkit calibrate on photos of the tag sheet and pass --camera camera.json, "
            "or give the focal length with --focal-px",
        )
    f35, size = max(set(values), key=values.count)
    fx = exif_fx(f35, *size)
    cam = camera_from_focal(fx, size[0], size[1], f"EXIF FocalLengthIn35mmFilm {f35:g} mm")
    cam.exif_f35 = f35
    note = (
        f"no --camera: using the EXIF focal length {f35:g} mm (35 mm equivalent) -> fx = fy = {fx:.1f} px at "
        f"{size[0]}x{size[1]}, principal point at the centre, no lens distortion. Calibrate for better poses"
    )
    return cam, note


def turn_into_camera_frame(records: list[PhotoRecord], camera: Camera) -> dict[str, str]:
    """Turn each photo held the other way (its upright size the camera's transposed) into the
    camera's frame (:func:`~.photos.turn_into_frame`): the frame the camera file records,
    else the one most such photos were taken in. Returns why each photo that could not be
    turned was not, by name. Turned photos fit the camera, so a second call turns nothing."""
    frame = camera.sensor_turns
    if frame is None:
        frame = frame_turns([r for r in records if r.detection is not None and not camera.compatible(*r.detected_size)])
    unturned = {}
    for r in records:
        if r.detection is None:
            continue
        w, h = r.detected_size
        if camera.compatible(w, h) and not camera.compatible(h, w):
            not_turned = turn_into_frame(r, frame)
            if not_turned and frame is None:  # (so the camera does not record its frame either)
                not_turned += " (re-run nerfkit calibrate: its camera files record it)"
            if not_turned:
                unturned[r.name] = f"{held_as(w, h)} while the camera is {camera.width}x{camera.height}: {not_turned}"
    return unturned


def pose_records(records: list[PhotoRecord], camera: Camera, layout: Layout, cfg: PoseConfig) -> list[PosedPhoto]:
    """Pose every readable photo; marks each record used or skipped with the reason.

    A photo held the other way is turned into the camera's frame
    (:func:`turn_into_camera_frame`). A photo whose
    EXIF focal length says it was taken with another lens or zoom than the camera's (else
    most photos') is skipped (:func:`~.photos.keep_one_lens`). The camera is scaled to each
    photo's size (a photo resized alike).
    """
    posed = []
    cams: dict[tuple[int, int], Camera] = {}
    unturned = turn_into_camera_frame(records, camera)
    for r in keep_one_lens(records, camera.exif_f35):
        if r.detection is None:
            continue
        w, h = r.detected_size
        why = unturned.get(r.name) or camera.compatible(w, h)
        if why:
            r.skip(why)
            continue
        cam = cams.setdefault((w, h), camera.scaled_to(w, h))
        det = r.detection
        limit, how = detection_limit(det, cam, layout, cfg)
        c2w, err, reason, info = solve_pose_robust(det, cam, layout, limit)
        r.info.update(info)
        if c2w is None:
            r.error_px = None if not np.isfinite(err) else err
            r.skip(reason + (blur_hint(records, r) if reason.startswith(("no tags", "tag ")) else ""))
            continue
        r.error_px = err
        side = max((tag_side_px(det, t) for t in info.get("tags_used", []) if layout.charuco is None), default=None)
        if side is not None and side < cfg.min_tag_px:
            r.skip(f"tag too small ({side:.0f} px across < {cfg.min_tag_px:g} px) for a reliable pose")
            continue
        if err > limit:
            r.skip(f"bad fit: reprojection error {err:.2f} px > {limit:.2f} px ({how})" + blur_hint(records, r))
            continue
        r.used = True
        r.reason = ""
        posed.append(PosedPhoto(r.name, r.path, c2w, err, cam, r.turns))
    return posed
