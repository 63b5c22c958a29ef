"""Where a scene's object is, from its cameras and sparse points: a bounding sphere and,
for an object standing on a table, the box around it.

Pure numpy on a scene's arrays: imported by the capture tools (dataset summaries) and by
the models' :class:`~nerfkit.models.base.SceneBounds`, below both.
"""

from __future__ import annotations

import numpy as np


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


def object_points(
    points: np.ndarray, table: np.ndarray, center: np.ndarray, radius: float, lift: float = 0.03
) -> np.ndarray:
    """The sparse points (m, 3) of an object standing on a table: those within ``radius``
    of ``center`` and higher than ``lift x radius`` above the table (``table``: ``(n, d)``;
    points on it are texture, not object). (k, 3) float64."""
    p = np.asarray(points, np.float64)
    n, d = np.asarray(table[:3], np.float64), float(table[3])
    height = p @ n + d
    return p[(np.linalg.norm(p - np.asarray(center, np.float64), axis=1) < radius) & (height > lift * radius)]


# the share of an object's sparse points (with their feet) an object box may leave out on
# each side of each axis: a thin part of the object has few points (a handful of hundreds),
# and 2% cuts it off; 0.5% keeps it (object box row in BENCHMARKS.md)
OBJECT_BOX_QUANTILE = 0.005


def object_box_from_points(
    points: np.ndarray,
    table: np.ndarray,
    center: np.ndarray,
    radius: float,
    min_points: int = MIN_OBJECT_POINTS,
    lift: float = 0.03,
    pad: float = 0.15,
    quantile: float = OBJECT_BOX_QUANTILE,
) -> tuple | None:
    """An axis-aligned box ``(lo, hi)`` around an object standing on a table, from its
    sparse points (:func:`object_points`) with their feet on the table, from the
    ``quantile`` to the ``1 - quantile`` quantile per axis, padded by ``pad`` of its size
    plus 5% of ``radius``; kept inside the sphere's box. None with fewer than
    ``min_points`` object points (the sphere's box is used then).
    """
    obj = object_points(points, table, center, radius, lift)
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


__all__ = ["MIN_OBJECT_POINTS", "OBJECT_BOX_QUANTILE", "object_box_from_points", "object_points", "sphere_radius"]
