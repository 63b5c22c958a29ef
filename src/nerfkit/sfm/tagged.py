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


@dataclass
class PoseChoice:
    """Which poses a tag capture's dataset gets.

    Attributes:
        result: the aligned SfM result to build the dataset from, or None: use the tag poses.
        why: one line saying which and why.
        agreement: tag poses against SfM poses over the photos both posed (median and max
            rotation difference in degrees and centre distance in metres), or None.
        adopted: the photos SfM missed that keep their tag poses (:func:`adopt_tag_poses`).
    """

    result: object | None
    why: str
    agreement: dict | None = None
    adopted: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "poses": "sfm" if self.result is not None else "tags",
            "why": self.why,
            "agreement": self.agreement,
            "tag_posed": self.adopted,
        }


def pose_agreement(tag_c2w: dict[str, np.ndarray], sfm_c2w: dict[str, np.ndarray]) -> dict | None:
    """How far apart two sets of poses in one world frame are, over the photos in both.

    Args:
        tag_c2w, sfm_c2w: photo name -> (4, 4) camera-to-world.

    Returns:
        ``{"photos", "rot_deg_median", "rot_deg_max", "shift_median", "shift_max",
        "distance_median"}`` (shifts: camera-centre distances; distance: cameras from the
        origin), or None when no photo is in both.
    """
    names = sorted(set(tag_c2w) & set(sfm_c2w))
    if not names:
        return None
    a = np.stack([tag_c2w[n] for n in names]).astype(np.float64)
    b = np.stack([sfm_c2w[n] for n in names]).astype(np.float64)
    rot = rotation_angles_deg(a, b)
    shift = np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1)
    return {
        "photos": len(names),
        "rot_deg_median": float(np.median(rot)),
        "rot_deg_max": float(rot.max()),
        "shift_median": float(np.median(shift)),
        "shift_max": float(shift.max()),
        "distance_median": float(np.median(np.linalg.norm(a[:, :3, 3], axis=1))),
    }


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
    from .colmap import colmap_name, run_sfm
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
    agreement = pose_agreement({p.name: p.c2w for p in tag_posed}, dict(zip(names, c2w)))
    reason = judge(len(tag_posed), len(names), result.tag_size is not None, agreement)
    if reason is not None:
        return PoseChoice(None, f"tag poses: {reason}", agreement)
    assert agreement is not None  # judge() passes no SfM result without an agreement
    why = (
        f"SfM poses in the tag's frame: {len(names)} photos registered (the tags posed {len(tag_posed)}); "
        f"the tag poses differ from them by a median {agreement['rot_deg_median']:.2f} degrees and "
        f"{agreement['shift_median'] * 1000:.1f} mm"
    )
    adopted: list[str] = []
    if records is not None:
        adopted, left = adopt_tag_poses(result, tag_posed, records, layout, pose_cfg)
        if adopted:
            why += (
                f"; the tag poses are kept for {len(adopted)} photo{'s' * (len(adopted) != 1)} SfM did not "
                f"register (solved again with SfM's camera): {', '.join(adopted)}"
            )
        if left:
            why += "; not adopted: " + "; ".join(f"{n} ({r})" for n, r in left.items())
    return PoseChoice(result, why, agreement, adopted)


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
