"""A tag capture posed by structure-from-motion, in the tag's frame (``nerfkit poses``' default).

A tag pins a photo's pose only as well as its four corners allow: in a phone capture the
tag is often a few dozen pixels wide, and the tag poses can differ from SfM's by about a
degree (several pixels at a phone's focal length). Bundle adjustment over thousands of
features seen across all the photos pins them far better (held-out PSNR and SSIM rise:
``poses --method auto`` in BENCHMARKS.md). So ``--method auto`` poses the photos by SfM
starting from the calibrated camera, whose focal length and distortion bundle adjustment
refines (a phone focused on a near object changes its focal length by a percent or so;
holding the calibration fixed lowers the held-out SSIM). The tag's corners, triangulated
from the SfM poses, then fix scale, up and origin (on a sheet, every tag of its layout).
The tag poses are kept only when SfM falls short: fewer photos registered, the tag not
seen, or poses that disagree with the tags' (:func:`choose_poses` says why). Photos the tags
posed that SfM did not register join its photos with their tag poses (:func:`adopt_tag_poses`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..cameras import rotation_angles_deg
from ..errors import NerfkitError

# SfM must register at least this share of the photos the tags posed.
MIN_SHARE = 0.9
# Tag and SfM poses of the same photos must agree to a median of this many degrees...
MAX_ROTATION_DEG = 5.0
# ... and of this share of the median camera distance from the world origin.
MAX_SHIFT = 0.1
# A photo whose SfM pose turns more than this many degrees from its tag pose, or lies more than
# this share of the median camera distance from it, was put on the wrong side of an ambiguity
# by one of them: a small tag looks alike tilted either way, and SfM can register a photo on
# the tag's features alone (a synthetic can: one of 71 photos 584 mm and 83 degrees off, where
# the dev captures' photos differ by at most 49 mm of 262 and 9.4 degrees).
FAR_DEG = 20.0
FAR_SHIFT = 0.3
# Such a photo keeps its tag pose when the tag's other solution fits its corners at least this
# many times worse (``pose_ambiguity``; several tags: no such doubt); else it is left out.
CLEAR_TAG = 10.0
# SfM's tracks seen in at least this many photos that both posed judge the two sets of poses
# (:func:`track_errors`); with fewer such tracks the tracks do not judge
MIN_TRACKS = 50


@dataclass
class PoseChoice:
    """Which poses a tag capture's dataset gets.

    Attributes:
        result: the aligned SfM result to build the dataset from, or None: use the tag poses.
        why: one line saying which and why.
        agreement: tag poses against SfM poses over the photos both posed (median and max
            rotation difference in degrees and centre distance in metres), or None.
        adopted: the photos SfM missed that keep their tag poses (:func:`adopt_tag_poses`).
        far: the photos whose SfM and tag poses lay far apart (:func:`far_apart`), name ->
            ``(degrees, metres)``; SfM's poses of them are not used.
        focal: SfM's camera, ``(fx, width, height, photos registered)``, whether its poses are
            used or not (:func:`~nerfkit.sfm.colmap.sfm_focal`); None when SfM failed.
    """

    result: object | None
    why: str
    agreement: dict | None = None
    adopted: list[str] = field(default_factory=list)
    far: dict[str, tuple[float, float]] = field(default_factory=dict)
    focal: tuple[float, int, int, int] | None = None

    def to_dict(self) -> dict:
        return {
            "poses": "sfm" if self.result is not None else "tags",
            "why": self.why,
            "agreement": self.agreement,
            "tag_posed": self.adopted,
            "far_from_tags": {n: {"deg": round(d, 2), "m": round(m, 4)} for n, (d, m) in sorted(self.far.items())},
        }


def pose_gaps(
    tag_c2w: dict[str, np.ndarray], sfm_c2w: dict[str, np.ndarray]
) -> tuple[list[str], np.ndarray, np.ndarray, float]:
    """Per photo in both sets of poses (one world frame): ``(names, degrees, metres, distance)``,
    the rotation between its two poses, the distance between its two camera centres, and the
    median distance of the first set's cameras from the origin (0 when no photo is in both).

    Args:
        tag_c2w, sfm_c2w: photo name -> (4, 4) camera-to-world.
    """
    names = sorted(set(tag_c2w) & set(sfm_c2w))
    if not names:
        return [], np.zeros(0), np.zeros(0), 0.0
    a = np.stack([tag_c2w[n] for n in names]).astype(np.float64)
    b = np.stack([sfm_c2w[n] for n in names]).astype(np.float64)
    distance = float(np.median(np.linalg.norm(a[:, :3, 3], axis=1)))
    return names, rotation_angles_deg(a, b), np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1), distance


def pose_agreement(tag_c2w: dict[str, np.ndarray], sfm_c2w: dict[str, np.ndarray]) -> dict | None:
    """How far apart two sets of poses in one world frame are, over the photos in both
    (:func:`pose_gaps`).

    Returns:
        ``{"photos", "rot_deg_median", "rot_deg_max", "shift_median", "shift_max",
        "distance_median"}`` (shifts: camera-centre distances; distance: cameras from the
        origin), or None when no photo is in both.
    """
    names, rot, shift, distance = pose_gaps(tag_c2w, sfm_c2w)
    if not names:
        return None
    return {
        "photos": len(names),
        "rot_deg_median": float(np.median(rot)),
        "rot_deg_max": float(rot.max()),
        "shift_median": float(np.median(shift)),
        "shift_max": float(shift.max()),
        "distance_median": distance,
    }


def far_apart(tag_c2w: dict[str, np.ndarray], sfm_c2w: dict[str, np.ndarray]) -> dict[str, tuple[float, float]]:
    """The photos in both sets whose two poses turn more than :data:`FAR_DEG` degrees apart or
    lie more than :data:`FAR_SHIFT` of the median camera distance (from the origin, in the tag
    poses) apart (:func:`pose_gaps`): name -> ``(degrees, metres)``."""
    names, rot, shift, distance = pose_gaps(tag_c2w, sfm_c2w)
    far = (rot > FAR_DEG) | (shift > FAR_SHIFT * distance)
    return {n: (float(r), float(m)) for n, r, m, f in zip(names, rot, shift, far) if f}


def clear_tag(record) -> bool:
    """Whether a photo's tag pose is beyond doubt: its tag's other solution fits its corners at
    least :data:`CLEAR_TAG` times worse, or it was solved from several tags (no such ratio);
    False without its ``PhotoRecord``."""
    if record is None:
        return False
    ambiguity = record.info.get("pose_ambiguity")
    return ambiguity is None or ambiguity >= CLEAR_TAG


def unregister(result, names: set[str]) -> None:
    """Take the photos ``names`` (the user's file names) out of ``result``'s reconstruction (their
    points' tracks lose them) and write the model again."""
    from ..data.colmap import write_reconstruction

    rec = result.reconstruction
    for i in list(rec.reg_image_ids()):
        if result.photo(rec.images[i].name).name in names:
            deregister(rec, rec.images[i])
    write_reconstruction(rec, result.model_dir)


def deregister(rec, image) -> None:
    """Take ``image`` out of the pycolmap reconstruction ``rec`` (pycolmap 4 registers frames, 3 images)."""
    if hasattr(rec, "deregister_frame"):
        rec.deregister_frame(image.frame_id)
    else:  # pragma: no cover - pycolmap 3
        rec.deregister_image(image.image_id)


def judge(n_tag_posed: int, n_registered: int, in_tag_frame: bool, agreement: dict | None) -> str | None:
    """None when the SfM poses are to be used, else why not (one clause)."""
    if not in_tag_frame:
        return "the tag was found in fewer than 3 of the photos SfM registered, so SfM has no metric frame"
    if n_registered < MIN_SHARE * n_tag_posed:
        return f"SfM registered {n_registered} photos, the tags posed {n_tag_posed}"
    if agreement is None:
        return "SfM registered none of the photos the tags posed"
    if agreement["rot_deg_median"] > MAX_ROTATION_DEG:
        return f"SfM's poses turn a median {agreement['rot_deg_median']:.1f} degrees from the tags'"
    if agreement["shift_median"] > MAX_SHIFT * agreement["distance_median"]:
        return (
            f"SfM's cameras sit a median {agreement['shift_median'] * 100:.1f} cm from the tags' "
            f"(cameras {agreement['distance_median'] * 100:.0f} cm away)"
        )
    return None


def choose_poses(
    photos: str | Path,
    out: str | Path,
    tag_posed: list,
    camera,
    tag_id: int,
    tag_size: float,
    dictionary: str,
    tag_corners: np.ndarray | None = None,
    matcher: str = "auto",
    max_image_size: int = 1000,
    progress: bool = True,
    threads: int = -1,
    records: list | None = None,
    layout=None,
    pose_cfg=None,
) -> PoseChoice:
    """Run SfM on a tag capture and decide whether its poses replace the tag poses.

    Args:
        photos: the capture's folder; out: the dataset folder (COLMAP's files go to
            ``out/colmap``).
        tag_posed: the tag path's ``PosedPhoto`` list (world: tag or sheet frame).
        camera: a calibrated camera SfM starts from, or None (SfM estimates it from the
            EXIF focal length).
        tag_id, tag_size: the tag that fixes the frame; tag_corners: its (4, 3) corners in
            a sheet layout's frame (None: the tag's own frame is the world).
        threads: COLMAP's threads (-1: all cores; 1: the same result every run).
        records, layout, pose_cfg: the photos' records, layout and ``PoseConfig`` the tag
            poses came from; given, the photos SfM misses keep their tag poses
            (:func:`adopt_tag_poses`).

    Returns:
        A :class:`PoseChoice`; SfM failing is a reason to keep the tag poses, not an error.
    """
    from .colmap import colmap_name, run_sfm, sfm_focal
    from .frame import align_reconstruction, reconstruction_c2w

    guides = {colmap_name(Path(p.path)): p.c2w for p in tag_posed}  # to choose the pairs SfM matches
    try:
        result = run_sfm(
            photos,
            out,
            matcher=matcher,
            max_image_size=max_image_size,
            progress=progress,
            threads=threads,
            camera=camera,
            guides=guides,
        )
    except NerfkitError as e:  # no photos that match, pycolmap missing, ...
        return PoseChoice(None, f"tag poses: structure-from-motion failed ({e})")
    shared = sfm_focal(result.reconstruction)  # (its focal length, before any photo is taken out)
    focal = None if shared is None else (*shared, result.reconstruction.num_reg_images())
    several = layout is not None and tag_corners is not None and len(layout.tags) > 1
    align_reconstruction(
        result,
        tag_size=tag_size,
        tag_id=tag_id,
        tag_dict=dictionary,
        progress=progress,
        ground=False,
        tag_corners=tag_corners,
        layout_tags=layout.tags if several else None,
    )
    names, c2w = reconstruction_c2w(result.reconstruction)
    names = [result.photo(n).name for n in names]
    tag_c2w, sfm_c2w = {p.name: p.c2w for p in tag_posed}, dict(zip(names, c2w))
    agreement = pose_agreement(tag_c2w, sfm_c2w)
    reason = judge(len(tag_posed), len(names), result.tag_size is not None, agreement)
    if reason is not None:
        return PoseChoice(None, f"tag poses: {reason}", agreement, focal=focal)
    assert agreement is not None  # judge() passes no SfM result without an agreement
    why = (
        f"SfM poses in the tag's frame: {len(names)} photos registered (the tags posed {len(tag_posed)}); "
        f"the tag poses differ from them by a median {agreement['rot_deg_median']:.2f} degrees and "
        f"{agreement['shift_median'] * 1000:.1f} mm"
    )
    far = far_apart(tag_c2w, sfm_c2w)
    errors = track_errors(result, [p for p in tag_posed if p.name not in far])  # a flipped photo fits neither
    if errors is not None:
        agreement = {**agreement, "track_px": list(errors)}
        fit = (
            f"SfM's feature tracks fit its poses to {errors[0]:.2f} px and the tag poses to {errors[1]:.2f} px (median)"
        )
        if errors[1] <= errors[0]:
            return PoseChoice(None, f"tag poses: {fit}", agreement, focal=focal)
        why += f"; {fit}"
    left: dict[str, str] = {}
    if far:
        unregister(result, set(far))
        by_name = {r.name: r for r in records or []}
        for n, (deg, m) in far.items():
            if not clear_tag(by_name.get(n)):
                left[n] = f"its poses lie {m * 1000:.0f} mm and {deg:.0f} degrees apart, its tag ambiguous"
        why += "; SfM's poses far from the tag poses (one of the two flipped), not used: " + ", ".join(
            f"{n} ({m * 1000:.0f} mm, {deg:.0f} degrees)" for n, (deg, m) in sorted(far.items())
        )
    adopted: list[str] = []
    if records is not None:
        kept = [p for p in tag_posed if p.name not in left]
        adopted, refused = adopt_tag_poses(result, kept, records, layout, pose_cfg)
        left.update(refused)
        if adopted:
            why += (
                f"; the tag poses are kept for {len(adopted)} photo{'s' * (len(adopted) != 1)} SfM did not "
                f"register (solved again with SfM's camera): {', '.join(adopted)}"
            )
    if left:
        why += "; not adopted: " + "; ".join(f"{n} ({r})" for n, r in sorted(left.items()))
    return PoseChoice(result, why, agreement, adopted, far, focal)


def retriangulated_errors(w2c: np.ndarray, rays: np.ndarray, focal: np.ndarray) -> np.ndarray:
    """Reprojection errors (n,) in pixels of one feature track seen along normalised image
    points ``rays`` (n, 2) by cameras ``w2c`` (n, 3, 4) of focal lengths ``focal`` (n,),
    its point triangulated again with the cameras held (:func:`~nerfkit.sfm.frame.triangulate`);
    inf where the point falls behind a camera."""
    from .frame import triangulate

    X = triangulate(w2c, rays)
    z = w2c[:, 2, :3] @ X + w2c[:, 2, 3]
    xy = (w2c[:, :2, :3] @ X + w2c[:, :2, 3]) / np.where(z > 1e-9, z, 1.0)[:, None]
    return np.where(z > 1e-9, np.linalg.norm(xy - rays, axis=1) * focal, np.inf)


def track_errors(result, tag_posed: list, min_views: int = 3) -> tuple[float, float] | None:
    """Which set of poses explains SfM's own feature tracks better: over the photos that SfM
    registered and the tags posed (in the same frame, turned alike), each track seen in
    ``min_views`` of them is triangulated again with SfM's poses and camera held, and with
    the tag poses and the calibrated camera; returns the median reprojection errors (pixels)
    ``(sfm, tags)``, or None with fewer than :data:`MIN_TRACKS` such tracks.

    Bundle adjustment fits SfM's poses to exactly these tracks, so the tag poses fit them as
    well only where they are the better poses: a large, sharp tag on a plain table, where
    SfM's few, weak matches bend its reconstruction."""
    import cv2

    from .colmap import colmap_name

    rec = result.reconstruction
    tags = {colmap_name(Path(p.path)): p for p in tag_posed}
    images = {i: rec.images[i] for i in rec.reg_image_ids()}
    images = {
        i: im for i, im in images.items() if im.name in tags and result.turns.get(im.name, 0) == tags[im.name].turns
    }
    sfm_w2c = {i: np.asarray(im.cam_from_world().matrix(), np.float64) for i, im in images.items()}
    tag_w2c = {i: np.linalg.inv(tags[im.name].c2w)[:3] for i, im in images.items()}
    sfm_err, tag_err, tracks = [], [], 0
    for point in rec.points3D.values():
        seen = [(el.image_id, el.point2D_idx) for el in point.track.elements if el.image_id in images]
        if len(seen) < min_views:
            continue
        tracks += 1
        xy = np.array([images[i].points2D[k].xy for i, k in seen], np.float64)
        cams = [rec.cameras[images[i].camera_id] for i, _ in seen]
        rays = np.array([np.asarray(c.cam_from_img(x), np.float64).reshape(-1)[:2] for c, x in zip(cams, xy)])
        focal = np.array([c.focal_length_x for c in cams])
        sfm_err.append(retriangulated_errors(np.stack([sfm_w2c[i] for i, _ in seen]), rays, focal))
        calibrated = [tags[images[i].name].camera for i, _ in seen]
        tag_rays = np.array(
            [  # OpenCV's pixel centres at integers, COLMAP's at +0.5
                cv2.undistortPoints((x - 0.5).reshape(1, 1, 2), c.K, c.dist).reshape(2) for c, x in zip(calibrated, xy)
            ]
        )
        tag_focal = np.array([c.K[0, 0] for c in calibrated])
        tag_err.append(retriangulated_errors(np.stack([tag_w2c[i] for i, _ in seen]), tag_rays, tag_focal))
    if tracks < MIN_TRACKS:
        return None
    return float(np.median(np.concatenate(sfm_err))), float(np.median(np.concatenate(tag_err)))


def adopt_tag_poses(result, tag_posed: list, records: list, layout, cfg) -> tuple[list[str], dict[str, str]]:
    """Give the photos the tags posed but SfM did not register their tag poses, in ``result``.

    With few photos SfM can miss a stretch of the orbit that the tag still poses; the
    held-out views there then score several dB better with those photos adopted
    (benchmarks/capture_real.py --photos 30).
    Every photo of the dataset is undistorted with SfM's refined camera, so each pose is
    solved again from the photo's tag corners with that camera, which brings it closer to
    SfM's poses of the same photos than the calibration's camera does. A photo whose fit then
    exceeds its error limit, or whose size or quarter turn differs from SfM's copy of it,
    is left out.

    Args:
        result: the aligned SfM result (tag frame); its ``tag_posed`` is filled.
        tag_posed: the tag path's ``PosedPhoto`` list; records: the photos' ``PhotoRecord``
            list (their detections); layout, cfg: the ``Layout`` and ``PoseConfig`` they
            were posed with.

    Returns:
        The photo names adopted, and name -> why for those left out.
    """
    from ..capture.poses import detection_limit, solve_pose_robust
    from .colmap import colmap_name
    from .dataset import opencv_camera

    rec = result.reconstruction
    registered = {result.photo(rec.images[i].name).name for i in rec.reg_image_ids()}
    camera = opencv_camera(rec.cameras[rec.images[next(iter(rec.reg_image_ids()))].camera_id])
    detections = {r.name: r.detection for r in records}
    adopted, left = [], {}
    for p in tag_posed:
        if p.name in registered or detections.get(p.name) is None:
            continue
        name = colmap_name(Path(p.path))
        if (p.camera.width, p.camera.height) != (camera.width, camera.height):
            left[p.name] = f"{p.camera.width}x{p.camera.height}, SfM's camera {camera.width}x{camera.height}"
            continue
        if result.turns.get(name, 0) != p.turns:  # its corners were found in another frame than SfM's copy
            left[p.name] = f"turned {90 * p.turns} degrees for the tag, {90 * result.turns.get(name, 0)} for SfM"
            continue
        limit, _ = detection_limit(detections[p.name], camera, layout, cfg)
        c2w, err, reason, _ = solve_pose_robust(detections[p.name], camera, layout, limit)
        if c2w is None or err > limit:
            left[p.name] = reason if c2w is None else f"reprojection error {err:.2f} px > {limit:.2f} px"
            continue
        result.tag_posed[name] = (c2w, float(err))
        adopted.append(p.name)
    return adopted, left
