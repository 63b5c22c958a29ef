"""The table (and the floor) under the object, found in structure-from-motion points.

Pure NumPy geometry, below the datasets (:meth:`nerfkit.data.Scene.floor` asks it) and
structure from motion (:mod:`nerfkit.sfm.frame` levels a reconstruction with it).

A tag gives a capture its table plane for free (level in the tag frame). Without a tag,
the object still stands on something, and SfM triangulates that surface well: a table
is textured, flat and in every photo. :func:`find_ground_plane` fits it by RANSAC among
the sparse points near the point the cameras look at, keeping only planes that:

* face the cameras' up within ``max_tilt_deg`` (people hold phones level, so the up
  from the cameras' x axes is good to a few degrees; walls and the object's sides fail),
* have the cameras on their upper side (a ceiling does not),
* pass close under the look-at point: at most ``max_drop`` camera distances below it (the
  object stands on it: a floor seen beyond a table's edge is too far down), and at most
  0.1 above it (the cameras may aim at the object's foot, a little under the surface),
* hold at least ``min_inlier_fraction`` of those points.

The winning plane is refitted to its inliers (least squares). :func:`ground_similarity`
then moves the world so that the plane is z = 0 with +z up and the origin under the
look-at point, as the tag frame would: training then treats the scene as a tag capture
(a textured table plane, a box from the points above it, the room around).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

POOL = 10_000


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking unit vector ``a`` to unit vector ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if c < -1 + 1e-9:  # opposite: turn 180 degrees about any axis perpendicular to a
        axis = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


@dataclass
class GroundPlane:
    """A plane ``normal . x + offset = 0``, unit ``normal`` toward the cameras.

    Attributes:
        inliers: points within the tolerance of the plane; candidates: points considered
            (near the look-at point); tolerance: that distance, in world units.
        tilt_deg: angle between ``normal`` and the cameras' up.
    """

    normal: np.ndarray
    offset: float
    inliers: int
    candidates: int
    tolerance: float
    tilt_deg: float

    def height(self, x: np.ndarray) -> np.ndarray:
        """Signed distance of (..., 3) points above the plane."""
        return np.asarray(x, np.float64) @ self.normal + self.offset

    def to_dict(self) -> dict:
        return {
            "normal": [round(float(v), 6) for v in self.normal],
            "offset": round(float(self.offset), 6),
            "inliers": int(self.inliers),
            "candidates": int(self.candidates),
            "tolerance": round(float(self.tolerance), 6),
            "tilt_deg": round(float(self.tilt_deg), 3),
        }


def _refit(points: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane through ``points`` (m, 3), its normal on the side of ``normal``."""
    mean = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - mean, full_matrices=False)
    n = vt[2] if vt[2] @ normal >= 0 else -vt[2]
    return n, float(-n @ mean)


def _triples(points: np.ndarray, k: int, radius: float, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``k`` random point triples (three (k, 3) arrays): half drawn from all points, half
    a random point and two of its neighbours within ``radius``. A table may hold only a
    few percent of the points (walls and the object have the rest); three points drawn
    at random then rarely all lie on it, while three neighbours often do."""
    m = len(points)
    idx = rng.integers(0, m, size=(k, 3))
    local = np.arange(k // 2, k)
    for j0 in range(0, len(local), 128):
        rows = local[j0 : j0 + 128]
        first = points[idx[rows, 0]]
        close = np.linalg.norm(points[None, :, :] - first[:, None, :], axis=2) < radius  # (r, m)
        keys = np.where(close, rng.random(close.shape), -1.0)
        two = np.argsort(-keys, axis=1)[:, :2]  # two random neighbours (or any point if too few)
        idx[rows, 1:] = two
    return points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]


def find_ground_plane(
    points: np.ndarray,
    cameras: np.ndarray,
    center: np.ndarray,
    up: np.ndarray,
    iterations: int = 2000,
    tolerance_fraction: float = 0.01,
    max_tilt_deg: float = 20.0,
    max_drop: float = 0.5,
    min_inlier_fraction: float = 0.05,
    min_points: int = 30,
    seed: int = 0,
    min_drop: float = -0.1,
    within: float = 1.5,
) -> tuple[GroundPlane | None, str]:
    """RANSAC for the surface the object stands on.

    Args:
        points: (m, 3) sparse points; cameras: (n, 3) camera centres; center: (3,) the
            point the cameras look at; up: (3,) the cameras' up (unit).
        tolerance_fraction: inlier distance as a fraction of the cameras' median distance
            from ``center`` (1 cm for cameras 1 m away).
        min_drop, max_drop: how far below ``center`` the plane must pass, in camera
            distances (negative: above).
        min_inlier_fraction: of the points within ``within`` camera distances of ``center``.

    Returns:
        ``(plane, "")``, or ``(None, why not)`` when no plane qualifies.
        Example: points on z = 0 with cameras above give normal (0, 0, 1), offset 0.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    cameras = np.asarray(cameras, np.float64).reshape(-1, 3)
    center = np.asarray(center, np.float64).reshape(3)
    up = np.asarray(up, np.float64).reshape(3)
    up = up / np.linalg.norm(up)
    reach = float(np.median(np.linalg.norm(cameras - center, axis=1)))
    near = points[np.linalg.norm(points - center, axis=1) < within * reach]
    if len(near) < min_points:
        return None, f"only {len(near)} sparse points near the centre (need {min_points})"
    tol = tolerance_fraction * reach
    cos_tilt = np.cos(np.radians(max_tilt_deg))
    rng = np.random.default_rng(seed)
    # candidates are drawn and scored on at most POOL points (memory: a (chunk, pool) block)
    pool = near if len(near) <= POOL else near[rng.choice(len(near), POOL, replace=False)]
    a, b, c = _triples(pool, iterations, 0.25 * reach, rng)
    n = np.cross(b - a, c - a)  # (k, 3) candidate normals
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(n @ up[:, None] >= 0, 1.0, -1.0) * n / np.maximum(norm, 1e-300)
    d = -np.einsum("kj,kj->k", n, a)
    drop = n @ center + d  # height of the look-at point above each plane
    ok = (norm[:, 0] > 1e-12) & (n @ up >= cos_tilt) & (min_drop * reach < drop) & (drop < max_drop * reach)
    ok &= ((cameras @ n.T + d) > tol).mean(axis=0) >= 0.9
    if not ok.any():
        return None, (
            f"no plane within {max_tilt_deg:g} degrees of the cameras' up has the cameras above it "
            f"and passes under the point they look at"
        )
    n, d = n[ok], d[ok]
    counts = np.concatenate(
        [(np.abs(pool @ n[i : i + 128].T + d[i : i + 128]) < tol).sum(axis=0) for i in range(0, len(n), 128)]
    )
    n, d = n[counts.argmax()], float(d[counts.argmax()])
    for _ in range(2):  # refit to the inliers, then take the inliers of the refit
        inl = np.abs(near @ n + d) < tol
        if np.count_nonzero(inl) < 3:  # too few to fit a plane to: keep the one we have
            break
        n, d = _refit(near[inl], n)
    count = int(np.count_nonzero(np.abs(near @ n + d) < tol))
    if count < min_inlier_fraction * len(near):
        return None, (
            f"the best plane holds {count} of {len(near)} sparse points near the centre "
            f"(need {min_inlier_fraction:.0%})"
        )
    tilt = float(np.degrees(np.arccos(np.clip(n @ up, -1.0, 1.0))))
    return GroundPlane(n, d, count, len(near), tol, tilt), ""


def ground_similarity(plane: GroundPlane, center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` of ``x -> R x + t`` putting the plane at z = 0 (normal -> +z) and the
    foot of ``center`` on it at the origin."""
    center = np.asarray(center, np.float64).reshape(3)
    R = rotation_between(plane.normal, np.array([0.0, 0.0, 1.0]))
    foot = center - plane.height(center) * plane.normal
    return R, -R @ foot


def find_floor(
    points: np.ndarray,
    table: np.ndarray,
    cameras: np.ndarray,
    center: np.ndarray,
    min_drop: float = 0.25,
    max_drop: float = 5.0,
    max_tilt_deg: float = 10.0,
    min_fraction: float = 0.2,
    min_points: int = 50,
    tolerance_fraction: float = 0.03,
    seed: int = 0,
) -> GroundPlane | None:
    """The floor seen beyond a table's edge, in the sparse points: a plane within
    ``max_tilt_deg`` of parallel to ``table`` (``(n, d)``, normal toward the cameras),
    ``min_drop`` to ``max_drop`` camera distances under it, holding at least
    ``min_fraction`` of the points more than ``min_drop / 2`` camera distances under
    the table (and ``min_points``). None when there is no such plane (a table that
    fills the photos, a capture on the floor itself).

    Example: points on z = 0 (table) and z = -0.4 (floor), cameras 0.4 above: the floor
    plane ``(0, 0, 1), 0.4``.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    n, d = np.asarray(table[:3], np.float64), float(table[3])
    n_len = float(np.linalg.norm(n))
    n, d = n / n_len, d / n_len
    center = np.asarray(center, np.float64).reshape(3)
    reach = float(np.median(np.linalg.norm(np.asarray(cameras, np.float64).reshape(-1, 3) - center, axis=1)))
    below = points[points @ n + d < -0.5 * min_drop * reach]
    if len(below) < min_points:
        return None
    foot = center - (center @ n + d) * n  # the look-at point's foot on the table
    plane, _ = find_ground_plane(
        below,
        cameras,
        foot,
        n,
        tolerance_fraction=tolerance_fraction,
        max_tilt_deg=max_tilt_deg,
        min_drop=min_drop,
        max_drop=max_drop,
        min_inlier_fraction=min_fraction,
        min_points=min_points,
        seed=seed,
        within=np.inf,
    )
    return plane
