"""Where a scene's object is, from its cameras and sparse points: a bounding sphere and,
for an object standing on a table, the box around it.

Pure numpy on a scene's arrays: imported by the capture tools (dataset summaries) and by
the models' :class:`~nerfkit.models.base.SceneBounds`, below both.
"""

from __future__ import annotations

import numpy as np

from .cameras import project_points


def sphere_radius(scene) -> float:
    """Radius of a sphere about the scene's centre that holds the object: the object lies
    between near and far of every camera, so it is at most half that depth range, and no
    larger than the mean camera distance minus near."""
    dist = float(np.mean(np.linalg.norm(scene.train.c2w[:, :3, 3] - scene.center, axis=1)))
    return max(min(0.5 * (scene.far - scene.near), dist - scene.near), 1e-3)


# fewer sparse points than this standing on a capture's table give no object box
MIN_OBJECT_POINTS = 30

# below this many training photos a capture's held-out views suffer markedly (benchmarks/capture_real.py
# --photos N); the capture summary warns, and the fast model's table cover prior applies
FEW_TRAIN_VIEWS = 30


# an object point lies inside the frames of at least this share of the training photos: the
# photographer keeps the object in every photo, while the room's clutter that also stands
# above the table (a chair leg, a bag at the floor's edge) shows in a few of them only
OBJECT_SEEN_SHARE = 0.5


def seen_share(points: np.ndarray, views) -> np.ndarray:
    """(m,) the share of the photos ``views`` (``c2w`` (n, 4, 4), ``K`` (n, 3, 3), ``width``,
    ``height``) whose frame holds each of ``points`` (m, 3), in front of the camera."""
    p = np.asarray(points, np.float64)
    seen = np.zeros(len(p))
    for K, c2w in zip(views.K, views.c2w, strict=True):
        uv, z = project_points(K, c2w, p)
        seen += (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= views.width) & (uv[:, 1] >= 0) & (uv[:, 1] <= views.height)
    return seen / max(len(views.c2w), 1)


def object_points(
    points: np.ndarray,
    table: np.ndarray,
    center: np.ndarray,
    radius: float,
    lift: float = 0.03,
    views=None,
    min_seen: float = OBJECT_SEEN_SHARE,
) -> np.ndarray:
    """The sparse points (m, 3) of an object standing on a table: those within ``radius``
    of ``center``, higher than ``lift x radius`` above the table (``table``: ``(n, d)``;
    points on it are texture, not object) and, given the training photos ``views``, inside
    the frames of at least ``min_seen`` of them (:func:`seen_share`). (k, 3) float64."""
    p = np.asarray(points, np.float64)
    n, d = np.asarray(table[:3], np.float64), float(table[3])
    height = p @ n + d
    p = p[(np.linalg.norm(p - np.asarray(center, np.float64), axis=1) < radius) & (height > lift * radius)]
    return p if views is None or len(p) == 0 else p[seen_share(p, views) >= min_seen]


# the share of an object's sparse points (with their feet) an object box may leave out on
# each side of each axis: a thin part of the object has few points (a handful of hundreds),
# and 2% cuts it off; 0.5% keeps it (object box row in BENCHMARKS.md)
OBJECT_BOX_QUANTILE = 0.005


def object_box_from_points(
    points: np.ndarray, table: np.ndarray, center: np.ndarray, radius: float, views=None, lift: float = 0.03, **box
) -> tuple | None:
    """:func:`object_box` around the object's sparse points among ``points``
    (:func:`object_points`, those in the frames of most photos ``views`` when given);
    ``box``: :func:`object_box`'s options."""
    return object_box(object_points(points, table, center, radius, lift, views), table, center, radius, **box)


def object_box(
    obj: np.ndarray,
    table: np.ndarray,
    center: np.ndarray,
    radius: float,
    min_points: int = MIN_OBJECT_POINTS,
    pad: float = 0.15,
    quantile: float = OBJECT_BOX_QUANTILE,
) -> tuple | None:
    """An axis-aligned box ``(lo, hi)`` around the object points ``obj`` (k, 3) with their
    feet on the table, from the ``quantile`` to the ``1 - quantile`` quantile per axis,
    padded by ``pad`` of its size plus 5% of ``radius``; kept inside the sphere's box. None
    with fewer than ``min_points`` object points (the sphere's box is used then)."""
    if len(obj) < min_points:
        return None
    n, d = np.asarray(table[:3], np.float64), float(table[3])
    c = np.asarray(center, np.float64)
    feet = obj - np.outer(obj @ n + d, n)
    both = np.concatenate([obj, feet])
    lo, hi = np.quantile(both, quantile, axis=0), np.quantile(both, 1 - quantile, axis=0)
    margin = pad * (hi - lo) + 0.05 * radius
    lo, hi = np.maximum(lo - margin, c - radius), np.minimum(hi + margin, c + radius)
    return lo.astype(np.float32), hi.astype(np.float32)


__all__ = [
    "MIN_OBJECT_POINTS",
    "OBJECT_BOX_QUANTILE",
    "OBJECT_SEEN_SHARE",
    "object_box",
    "object_box_from_points",
    "object_points",
    "seen_share",
    "sphere_radius",
]
