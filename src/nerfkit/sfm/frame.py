"""The world frame of a structure-from-motion model.

COLMAP's model comes in an arbitrary frame and scale. :func:`align_reconstruction` moves
it into nerfkit's:

* with a tag (``tag_size``) seen in 3 or more registered photos: the tag frame, metric
  and level (origin at the tag centre, +z out of the tag, metres), or a sheet layout's
  frame, fitted to the triangulated corners of every layout tag seen
  (:func:`tag_similarity`);
* otherwise normalised: the cameras centred on the point they look at, up -> +z where
  up is the direction perpendicular to the level-held cameras' x axes (signed by the
  mean camera up), the mean camera distance ``target_distance``; then levelled on the
  table plane found in the sparse points.

Also the similarity tools the rest of nerfkit compares poses with (:func:`umeyama`,
:func:`compare_poses`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..cameras import rotation_angles_deg
from ..data.colmap import write_reconstruction
from ..ground import rotation_between
from .colmap import _say

if TYPE_CHECKING:  # pragma: no cover
    from .colmap import SfmResult


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ~ s * R @ src + t`` (Umeyama 1991).

    Args: src, dst: (n, 3) corresponding points, n >= 3 not collinear.
    Returns: (s, R (3, 3) proper rotation, t (3,)).
    """
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    var_s = (xs**2).sum() / len(src)
    s = float(np.trace(np.diag(S) @ D) / var_s) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return s, R, t


def apply_similarity(c2w: np.ndarray, s: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Camera-to-world poses (N, 4, 4) after the world moves by ``x -> s R x + t``
    (rotations turn by R, centres move; the cameras stay rigid)."""
    out = np.array(c2w, np.float64, copy=True)
    out[:, :3, :3] = R @ out[:, :3, :3]
    out[:, :3, 3] = s * out[:, :3, 3] @ R.T + t
    return out


def compare_poses(c2w_est: np.ndarray, c2w_ref: np.ndarray, with_scale: bool = True) -> dict:
    """Pose errors after the best similarity alignment of the camera centres.

    Returns a dict: rotation error (degrees, median/max), centre error (in the reference's
    units, median/max, and relative to the reference cameras' spread), scale s.
    """
    s, R, t = umeyama(c2w_est[:, :3, 3], c2w_ref[:, :3, 3], with_scale)
    aligned = apply_similarity(c2w_est, s, R, t)
    rot = rotation_angles_deg(aligned, c2w_ref)
    pos = np.linalg.norm(aligned[:, :3, 3] - c2w_ref[:, :3, 3], axis=1)
    spread = float(np.sqrt(((c2w_ref[:, :3, 3] - c2w_ref[:, :3, 3].mean(0)) ** 2).sum(1).mean()))
    return {
        "n": int(len(rot)),
        "scale": s,
        "rot_err_deg_median": float(np.median(rot)),
        "rot_err_deg_max": float(rot.max()),
        "pos_err_median": float(np.median(pos)),
        "pos_err_max": float(pos.max()),
        "pos_err_rel_median": float(np.median(pos) / spread),
        "spread": spread,
    }


def estimate_vertical(c2w: np.ndarray) -> np.ndarray:
    """World up (3,) from camera poses (N, 4, 4), robust to cameras looking down.

    People hold cameras level (little roll), so every camera's x axis is horizontal and
    up is the direction most perpendicular to all of them (nerfstudio's "vertical"
    orientation); its sign follows the mean camera up (-y). When the x axes span too
    little (all nearly parallel: a forward-facing capture), the mean camera up, made
    perpendicular to the common x axis, is used instead.
    """
    from ..data.scene import estimate_up

    mean_up = estimate_up(c2w).astype(np.float64)
    x_axes = c2w[:, :3, 0].astype(np.float64)
    _, S, Vt = np.linalg.svd(x_axes, full_matrices=False)
    if len(S) == 3 and S[1] > 0.17 * np.sqrt(len(c2w)):
        up = Vt[2]
    else:
        up = mean_up - Vt[0] * (Vt[0] @ mean_up)
    up = up / np.linalg.norm(up)
    return up if up @ mean_up >= 0 else -up


def normalising_similarity(c2w: np.ndarray, target_distance: float = 4.0) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R, t) moving the cameras' look-at point to the origin, up (see
    :func:`estimate_vertical`) to +z, and the cameras' mean distance from that point to
    ``target_distance`` (lego-like units)."""
    from ..data.scene import estimate_center

    center = estimate_center(c2w).astype(np.float64)
    up = estimate_vertical(c2w)
    R = rotation_between(up, np.array([0.0, 0.0, 1.0]))
    dist = float(np.mean(np.linalg.norm(c2w[:, :3, 3] - center, axis=1)))
    s = target_distance / max(dist, 1e-12)
    return s, R, -s * R @ center


def transform_reconstruction(rec, s: float, R: np.ndarray, t: np.ndarray) -> None:
    """Apply ``x -> s R x + t`` to a pycolmap reconstruction in place (cameras and points)."""
    import pycolmap

    rec.transform(pycolmap.Sim3d(float(s), pycolmap.Rotation3d(np.asarray(R, np.float64)), np.asarray(t, np.float64)))


def reconstruction_c2w(rec) -> tuple[list[str], np.ndarray]:
    """Names and camera-to-world poses (N, 4, 4) of the registered images, sorted by name."""
    from ..data.colmap import image_c2w

    ims = sorted((rec.images[i] for i in rec.reg_image_ids()), key=lambda im: im.name)
    return [im.name for im in ims], np.stack([image_c2w(im) for im in ims])


def _level_on_ground(result: SfmResult, progress: bool) -> str:
    """Find the table plane among the (normalised) reconstruction's points and make it
    z = 0; what was done, for the frame description."""
    from ..data.colmap import reconstruction_points
    from ..ground import find_ground_plane, ground_similarity

    rec = result.reconstruction
    _, c2w = reconstruction_c2w(rec)
    origin, up = np.zeros(3), np.array([0.0, 0.0, 1.0])  # the normalised frame's look-at point and up
    plane, why = find_ground_plane(reconstruction_points(rec).xyz, c2w[:, :3, 3], origin, up)
    if plane is None:
        _say(progress, f"sfm: no table plane found ({why}); the scene keeps the cameras' up and no table")
        return f"no table plane found ({why})"
    R, t = ground_similarity(plane, origin)
    transform_reconstruction(rec, 1.0, R, t)
    result.on_ground = True
    result.report.ground = plane.to_dict()
    note = (
        f"z = 0 on the table plane found in the sparse points ({plane.inliers} of {plane.candidates} "
        f"points near the centre within {plane.tolerance:.3g}; {plane.tilt_deg:.1f} degrees from the cameras' up)"
    )
    _say(progress, f"sfm: {note}")
    return note


# --------------------------------------------------------------------------- tags


def detect_tags(image: np.ndarray, detector, bits: int) -> dict[int, np.ndarray]:
    """Corners (4, 2) of every ArUco tag in an (H, W, 3) uint8 photo, by id.

    Uses the capture package's detection (``detector`` from
    :func:`~nerfkit.capture.aruco.make_detector`, tags of ``bits`` x ``bits`` cells;
    sub-pixel corners, found where the tag's edges meet); corners come in OpenCV's order
    (top-left, top-right, bottom-right, bottom-left of the printed tag) and in COLMAP's /
    nerfkit's pixel convention (pixel centres at +0.5).
    """
    from ..capture.aruco import detect

    det = detect(image, detector, marker_bits=bits)
    found: dict[int, np.ndarray] = {}
    for i, tag in enumerate(det.ids):
        found.setdefault(int(tag), det.corners[i].astype(np.float64) + 0.5)  # OpenCV centres at integers -> +0.5
    return found


def triangulate(w2c: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Least-squares (DLT) point (3,) from normalised image points ``rays`` (n, 2) seen by
    cameras ``w2c`` (n, 3, 4)."""
    A = []
    for P, (x, y) in zip(w2c, rays):
        A.append(x * P[2] - P[0])
        A.append(y * P[2] - P[1])
    _, _, Vt = np.linalg.svd(np.asarray(A))
    X = Vt[-1]
    return X[:3] / X[3]


def triangulate_robust(w2c: np.ndarray, rays: np.ndarray, floor: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """:func:`triangulate` without the views that disagree: ``(X (3,), kept (n,) bool)``.

    A view whose ray misses the point by more than 3 times the median miss (normalised
    image units, at least ``floor``) is left out and the point triangulated again: a tag
    corner under the object, found on the object's outline in a few photos, must not pull
    the point off the tag.
    """
    kept = np.ones(len(rays), bool)
    X = triangulate(w2c, rays)
    for _ in range(3):
        cam = w2c[:, :, :3] @ X + w2c[:, :, 3]  # (n, 3)
        miss = np.linalg.norm(cam[:, :2] / np.maximum(cam[:, 2:], 1e-12) - rays, axis=1)
        new = miss <= max(3.0 * float(np.median(miss)), floor)
        if new.sum() < 2 or np.array_equal(new, kept):
            break
        kept = new
        X = triangulate(w2c[kept], rays[kept])
    return X, kept


def tag_similarity(
    rec,
    image_dir: Path,
    tag_size: float,
    tag_id: int = 0,
    dictionary: str = "DICT_4X4_50",
    min_views: int = 3,
    tag_corners: np.ndarray | None = None,
    layout_tags: dict[int, np.ndarray] | None = None,
) -> tuple[tuple[float, np.ndarray, np.ndarray], dict] | None:
    """(s, R, t) taking the reconstruction into the tag frame (metres, +z out of the tag),
    and facts about the fit; None when tag ``tag_id`` is seen in fewer than ``min_views``
    photos.

    The tags' corners are detected in every registered photo, undistorted with the
    photo's camera model, and triangulated (:func:`triangulate_robust`); the triangulated
    corners fix scale (``tag_size`` = printed side length in metres), orientation and
    origin. ``tag_corners``: (4, 3) where the tag's corners are in the wanted frame (OpenCV
    corner order; a sheet layout's frame), instead of the tag's own frame.
    ``layout_tags``: every tag of that layout by id ((4, 3) corners each): each one seen in
    ``min_views`` photos joins the fit, which a sheet's width holds level far better than
    one tag's side (the tags of a sheet span several times one tag's width; BENCHMARKS.md).
    """
    from ..capture.aruco import make_detector, marker_bits, square_corners
    from ..images import load_image_uint8

    targets = {
        tag_id: square_corners(tag_size) if tag_corners is None else np.asarray(tag_corners, np.float64).reshape(4, 3)
    }
    for tag, corners in (layout_tags or {}).items():
        targets.setdefault(int(tag), np.asarray(corners, np.float64).reshape(4, 3))
    obs: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {t: [] for t in targets}  # (w2c 3x4, corners 4x2)
    detector, bits = make_detector(dictionary), marker_bits(dictionary)
    for i in rec.reg_image_ids():
        im = rec.images[i]
        found = detect_tags(load_image_uint8(image_dir / im.name), detector, bits)
        cam = rec.cameras[im.camera_id]
        for tag in set(found) & set(targets):
            obs[tag].append(
                (np.asarray(im.cam_from_world().matrix(), np.float64), np.asarray(cam.cam_from_img(found[tag])))
            )
    return similarity_from_sightings(obs, targets, tag_id, min_views)


def similarity_from_sightings(
    sightings: dict[int, list[tuple[np.ndarray, np.ndarray]]],
    targets: dict[int, np.ndarray],
    tag_id: int,
    min_views: int = 3,
) -> tuple[tuple[float, np.ndarray, np.ndarray], dict] | None:
    """The similarity of :func:`tag_similarity` from the tags' sightings.

    Args:
        sightings: per tag id, ``(w2c (3, 4), corners (4, 2))`` of each photo that shows it,
            corners in normalised image coordinates.
        targets: per tag id, its (4, 3) corners in the wanted frame.
        tag_id: the tag that must be seen in ``min_views`` photos; other tags join when
            they are too, and leave again when their corners fit more than 3 times the
            median tag's miss and 2% of a side away from the layout's (a tag moved since).
    """
    if len(sightings.get(tag_id, [])) < min_views:
        return None
    X, used, kept = {}, [], []
    for tag in sorted(targets, key=lambda t: (t != tag_id, t)):
        seen = sightings.get(tag, [])
        if len(seen) < min_views:
            continue
        w2c = np.stack([o[0] for o in seen])
        for k in range(4):
            X[tag, k], ok = triangulate_robust(w2c, np.stack([o[1][k] for o in seen]))
            kept.append(ok)
        used.append(tag)

    def corners(tags: list[int]) -> tuple[np.ndarray, np.ndarray]:  # triangulated, and where the layout puts them
        return np.stack([X[t, k] for t in tags for k in range(4)]), np.concatenate([targets[t] for t in tags])

    src, dst = corners(used)
    s, R, t = umeyama(src, dst)
    # a tag that is not where the layout says (moved, or another print) leaves the fit
    off = np.linalg.norm((s * src @ R.T + t) - dst, axis=1).reshape(-1, 4).max(1)
    side = float(np.linalg.norm(targets[tag_id] - np.roll(targets[tag_id], -1, axis=0), axis=1).mean())
    stray = (off > max(3.0 * float(np.median(off)), 0.02 * side)) & (np.array(used) != tag_id)
    moved = [u for u, x in zip(used, stray) if x]
    if moved:
        used = [u for u in used if u not in moved]
        src, dst = corners(used)
        s, R, t = umeyama(src, dst)
    ref = corners([tag_id])[0]
    sides = np.linalg.norm(ref - np.roll(ref, -1, axis=0), axis=1) * s
    residual = float(np.linalg.norm((s * src @ R.T + t) - dst, axis=1).max())
    info = {
        "views": len(sightings[tag_id]),
        "tags": used,
        "tags_off_layout": moved,
        "side_lengths_m": [float(x) for x in sides],
        "fit_residual_m": residual,
        "corner_sightings": int(sum(len(k) for k in kept)),
        "corner_sightings_left_out": int(sum((~k).sum() for k in kept)),
    }
    return (s, R, t), info


def align_reconstruction(
    result: SfmResult,
    tag_size: float | None = None,
    tag_id: int = 0,
    tag_dict: str = "DICT_4X4_50",
    target_distance: float = 4.0,
    progress: bool = True,
    ground: bool = True,
    tag_corners: np.ndarray | None = None,
    layout_tags: dict[int, np.ndarray] | None = None,
) -> str:
    """Move the reconstruction into nerfkit's world frame (in place; rewrites the model).

    With ``tag_size`` (metres) and the tag visible in >= 3 registered photos: the tag
    frame (metric, +z up out of the tag). Otherwise normalised (see
    :func:`normalising_similarity`) and, with ``ground``, levelled on the table plane
    found in the sparse points (:mod:`nerfkit.ground`: z = 0 on the table, the origin
    under the look-at point; ``result.on_ground``). ``tag_corners``: the tag's corners in a
    sheet layout's frame, which then becomes the world, and ``layout_tags`` all of that
    layout's tags, which join the fit (see :func:`tag_similarity`).
    Returns a one-line description, also stored in ``result.report.frame``.
    """
    rec = result.reconstruction
    frame = None
    if tag_size is not None:
        fit = tag_similarity(
            rec, result.image_dir, tag_size, tag_id, tag_dict, tag_corners=tag_corners, layout_tags=layout_tags
        )
        if fit is None:
            _say(progress, f"sfm: tag {tag_id} seen in fewer than 3 registered photos; normalising the scene instead")
        else:
            (s, R, t), info = fit
            transform_reconstruction(rec, s, R, t)
            result.tag_size = tag_size
            where = (
                "origin at the tag centre, +z up out of the tag"
                if tag_corners is None
                else "the sheet layout's frame, +z up out of the sheet"
            )
            others = len(info["tags"]) - 1
            also = f" and {others} more tag{'s' * (others > 1)} of the sheet" if others else ""
            if info["tags_off_layout"]:
                also += (
                    f" (left out, not where the layout puts them: tag {', '.join(map(str, info['tags_off_layout']))})"
                )
            frame = (
                f"metric, from ArUco tag {tag_id} ({tag_size * 100:g} cm) seen in {info['views']} photos{also}: "
                f"{where}, metres "
                f"(triangulated sides {', '.join(f'{x * 100:.2f}' for x in info['side_lengths_m'])} cm)"
            )
    if frame is None:
        _, c2w = reconstruction_c2w(rec)
        s, R, t = normalising_similarity(c2w, target_distance)
        transform_reconstruction(rec, s, R, t)
        frame = (
            f"normalised (no tag{'' if tag_size is None else ' found'}): "
            f"cameras centred on the point they look at, "
            f"up (perpendicular to the cameras' x axes) -> +z, mean camera distance {target_distance:g} "
            f"(arbitrary units, not metric)"
        )
        if ground:
            frame += "; " + _level_on_ground(result, progress)
    write_reconstruction(rec, result.model_dir)
    result.report.frame = frame
    return frame
