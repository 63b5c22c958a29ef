"""Is a fitted lens-distortion model plausible over the whole frame, and does it generalise?

Calibration photos rarely put tag corners near the image corners (on the two real phone
captures we checked, over 90% of the corners lie within 40% of the half-diagonal of the
centre). A polynomial fitted there says little about the frame's edges: a positive k1 with
a negative k2 fits the centre and then turns around,
bending the edges by tens or hundreds of pixels. These checks look at the model where the
photos will be used: out to the image corners.

* :func:`distortion_check`: the radial mapping ``r -> r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` must
  be monotonic out to the radius that lands on the image corners, and the displacement
  there bounded (:data:`MAX_DISPLACEMENT_OF_DIAGONAL`).
* :func:`frame_displacement`: where each of 8 frame points (corners, edge midpoints) moves
  when undistorted; over the folds of a cross-validation its spread tells whether the
  photos determine the model at the edges or the fit there is extrapolation.
* :func:`heldout_errors`: reprojection errors of held-out views, each posed with solvePnP
  using the fold's intrinsics (the intrinsics are what is being validated).
"""

from __future__ import annotations

import numpy as np

# A model moving the image corners by more than this fraction of the image diagonal is
# rejected. 10% of the diagonal is 20% radial distortion at the corners: beyond the
# rectilinear lenses OpenCV's 5-coefficient model is meant for (phone main cameras deliver
# lens-corrected JPEGs with ~1%; uncorrected wide webcams and action cameras in "linear"
# mode reach ~10%), while a polynomial turning around just outside the data exceeds it
# (a 12 MP phone fit with k1 = 0.24, k2 = -0.90 moves the corners by ~13% of the
# diagonal and is not even monotonic there).
MAX_DISPLACEMENT_OF_DIAGONAL = 0.10


def corner_radius(K: np.ndarray, size: tuple[int, int]) -> float:
    """Largest normalised radius ``|((u - cx) / fx, (v - cy) / fy)|`` of the 4 image corners."""
    w, h = size
    u = np.array([0.0, w - 1, w - 1, 0.0])
    v = np.array([0.0, 0.0, h - 1, h - 1])
    return float(np.max(np.hypot((u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1])))


def distortion_check(
    K: np.ndarray, dist: np.ndarray, size: tuple[int, int], max_of_diagonal: float = MAX_DISPLACEMENT_OF_DIAGONAL
) -> dict:
    """Check the radial mapping out to the image corners.

    Samples ``rd(r) = r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` for undistorted radii ``r`` from 0 and
    requires it to keep increasing until it reaches the (distorted) radius of the farthest
    image corner; the displacement of that corner, radial ``fx |r - rd|`` plus the
    tangential terms there, must stay under ``max_of_diagonal`` of the image diagonal.

    Returns:
        ``{"ok", "monotonic", "corner_displacement_px", "limit_px", "reason"}``.
    """
    d = np.zeros(5)
    d[: min(5, len(np.ravel(dist)))] = np.ravel(dist)[:5]
    k1, k2, p1, p2, k3 = d
    rc = corner_radius(K, size)
    limit = max_of_diagonal * float(np.hypot(*size))
    r = np.linspace(0.0, 4.0 * rc, 8001)
    r2 = r * r
    rd = r * (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3)
    slope = 1 + 3 * k1 * r2 + 5 * k2 * r2**2 + 7 * k3 * r2**3
    turn = np.flatnonzero(slope <= 0)
    end = int(turn[0]) if len(turn) else len(r)
    reach = np.flatnonzero(rd[:end] >= rc)
    out = {
        "ok": False,
        "monotonic": bool(len(reach)),
        "corner_displacement_px": None,
        "limit_px": round(limit, 2),
        "reason": "",
    }
    if not len(reach):
        top = float(rd[:end].max()) if end else 0.0
        out["reason"] = (
            f"not monotonic: the radial mapping turns back at radius {top:.2f}, inside the frame "
            f"(corner radius {rc:.2f})"
        )
        return out
    i = int(reach[0])
    ru = float(np.interp(rc, rd[max(i - 1, 0) : i + 1], r[max(i - 1, 0) : i + 1])) if i else 0.0
    f = float(K[0, 0])
    x = y = rc / np.sqrt(2)  # tangential terms at a diagonal corner of that radius, both signs
    tang = max(
        np.hypot(2 * p1 * x * y * s + p2 * (rc**2 + 2 * x * x), p1 * (rc**2 + 2 * y * y) + 2 * p2 * x * y * s)
        for s in (1, -1)
    )
    disp = f * (abs(ru - rc) + tang)
    out["corner_displacement_px"] = round(disp, 2)
    if disp > limit:
        out["reason"] = (
            f"moves the image corners by {disp:.0f} px (> {max_of_diagonal * 100:g}% of the diagonal, {limit:.0f} px)"
        )
        return out
    out["ok"] = True
    return out


def frame_points(size: tuple[int, int]) -> np.ndarray:
    """(8, 2) image corners and edge midpoints (OpenCV pixels)."""
    w, h = size[0] - 1.0, size[1] - 1.0
    return np.array([[0, 0], [w, 0], [w, h], [0, h], [w / 2, 0], [w, h / 2], [w / 2, h], [0, h / 2]], np.float64)


def frame_displacement(K: np.ndarray, dist: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(8, 2) pixel displacement of :func:`frame_points` when undistorted (same K)."""
    import cv2

    pts = frame_points(size)
    if not np.any(dist):
        return np.zeros_like(pts)
    und = cv2.undistortPoints(
        pts.reshape(-1, 1, 2),
        K,
        np.asarray(dist, np.float64),
        P=K,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12),
    )
    return und.reshape(-1, 2) - pts


def fold_spread(displacements: list[np.ndarray]) -> float:
    """Largest RMS spread (px), over the frame points, of their displacement across folds."""
    D = np.asarray(displacements, np.float64)
    if len(D) < 2 or not np.all(np.isfinite(D)):
        return float("inf") if not np.all(np.isfinite(D)) else 0.0
    return float(np.sqrt(np.mean(np.sum((D - D.mean(0)) ** 2, axis=2), axis=0)).max())


def view_pose(
    obj: np.ndarray, img: np.ndarray, K: np.ndarray, dist: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """(rvec, tvec) of a view: IPPE for one flat square, SQPnP for more points (or a square
    whose corners are not in one plane: a sheet's estimated heights), then LM."""
    import cv2

    obj = np.asarray(obj, np.float64).reshape(-1, 3)
    img = np.asarray(img, np.float64).reshape(-1, 2)
    flat = not np.any(obj[:, 2])
    flag = cv2.SOLVEPNP_IPPE if len(obj) == 4 and flat else cv2.SOLVEPNP_SQPNP
    try:
        ok, rv, tv = cv2.solvePnP(obj, img, K, dist, flags=flag)
        if not ok:
            return None
        return cv2.solvePnPRefineLM(obj, img, K, dist, rv, tv)
    except cv2.error:
        return None


def heldout_errors(views: list, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Squared reprojection errors (px^2) of every point of ``views`` (name, obj, img),
    each view posed on its own with ``K, dist``; a view that cannot be posed counts as
    (100 px)^2 per point."""
    import cv2

    out = []
    for _, obj, img in views:
        pose = view_pose(obj, img, K, dist)
        if pose is None:
            out.append(np.full(len(obj), 1e4))
            continue
        proj, _ = cv2.projectPoints(np.asarray(obj, np.float64).reshape(-1, 1, 3), pose[0], pose[1], K, dist)
        out.append(np.sum((proj.reshape(-1, 2) - np.asarray(img).reshape(-1, 2)) ** 2, axis=1))
    return np.concatenate(out) if out else np.zeros(0)
