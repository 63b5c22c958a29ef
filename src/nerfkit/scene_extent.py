"""Where a scene's object is, from its cameras and sparse points: a bounding sphere and,
for an object standing on a table, the box around it; in a density grid, the mesh's surface
level (:func:`surface_threshold`), the faces of the grid's box the object reaches
(:func:`faces_reached`) and the specks floating apart from it (:func:`specks`); and plain
box geometry (:func:`box_corners`, :func:`box_radius`, :func:`inside_quads`).

Pure numpy on a scene's arrays (SciPy inside the grid functions): imported by the capture
tools (dataset summaries) and by the models' :class:`~nerfkit.models.base.SceneBounds`,
below both.
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


# a fixed surface density (per unit): the mesh of a forward-facing model in NDC, and the
# object alone of a model without a box; captures take surroundings.box_surface_threshold,
# scale-free
SURFACE_DENSITY = 25.0
# The mesh's surface by default (surface_threshold): the density at which one 256th of the
# meshed cube's width is this opaque. A density threshold in world units is not scale-free:
# a fixed 25 cut lego's base plate (its surfaces render at a median density of 24) and meshed
# captures in metres in a haze around them. At 7% the mesh's silhouette in the val views
# matches the NeRF's best of the levels tried (benchmarks/mesh_colours.py's silhouette IoU;
# BENCHMARKS.md).
MESH_OPACITY = 0.07
MESH_OPACITY_CELLS = 256


def surface_threshold(radius: float) -> float:
    """The default iso-level of a mesh over a cube of half-size ``radius`` (in the units the
    density is per): the density at which a cell of ``2 radius / MESH_OPACITY_CELLS`` is
    :data:`MESH_OPACITY` opaque. Scale-free: a scene ten times larger, with a tenth of the
    density, gives the same mesh ten times larger. Example: lego's cube (half-size 1.64)
    gives 5.7; a tabletop object's cube of half-size 7.6 cm about 120."""
    return -float(np.log1p(-MESH_OPACITY)) * MESH_OPACITY_CELLS / (2.0 * radius)


# Specks around the object alone (specks): a piece apart from the object holding less than
# this share of the box's density is cleared, with what lies SPECK_MARGIN cells beyond the
# pieces kept (stray pieces apart from the object each hold well under this share:
# benchmarks/capture_real.py --photos 30 renders the object alone)
SPECK_SHARE = 0.01
SPECK_MARGIN = 3


def box_radius(box) -> float:
    """Half the largest side of an axis-aligned box ``(lo (3,), hi (3,))``."""
    lo, hi = (np.asarray(v, np.float64) for v in box)
    return float((hi - lo).max()) / 2


def box_corners(box) -> np.ndarray:
    """(8, 3) float64 corners of an axis-aligned box ``(lo (3,), hi (3,))``."""
    lo, hi = (np.asarray(v, np.float64) for v in box)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def inside_quads(xy: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """(m,) bool: which of the points ``xy`` (m, 2) lie inside any of the convex
    quadrilaterals ``quads`` (n, 4, 2) (corners in order, either winding; the edges count
    as inside)."""
    xy = np.asarray(xy, np.float64)
    inside = np.zeros(len(xy), bool)
    for q in np.asarray(quads, np.float64):
        edge, rel = np.roll(q, -1, axis=0) - q, xy[:, None, :] - q  # (4, 2), (m, 4, 2) each edge a -> b
        cross = edge[:, 0] * rel[..., 1] - edge[:, 1] * rel[..., 0]  # (m, 4)
        inside |= (cross >= 0).all(-1) | (cross <= 0).all(-1)
    return inside


def _pieces(solid: np.ndarray) -> tuple[np.ndarray, int, int]:
    """The 26-connected pieces of ``solid``: their labels (0: not solid), their count, and
    the label of the largest (0 when there is none)."""
    from scipy import ndimage

    labels, count = ndimage.label(solid, structure=np.ones((3, 3, 3), bool))
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels, count, int(np.argmax(sizes))


def faces_reached(solid: np.ndarray, min_columns: int = 3) -> list[tuple[int, int]]:
    """The faces of a grid's box that the object reaches: where its largest solid piece
    (26-connected) fills at least ``min_columns`` vertices of the face's outer two layers,
    seen along the face's axis. Other pieces (floaters, paint) do not count.

    Args:
        solid: (X, Y, Z) bool, the grid's solid vertices (the table's paint left out).

    Returns:
        ``(axis, side)`` pairs, ``side`` 0 for the face at the low end of ``axis``, 1 for
        the high end, in axis order.
    """
    labels, count, largest = _pieces(solid)
    if count == 0:
        return []
    main = labels == largest
    faces = []
    for axis in range(3):
        n = main.shape[axis]
        for side, layers in ((0, [0, 1]), (1, [n - 1, n - 2])):
            if int(np.take(main, layers, axis=axis).any(axis=axis).sum()) >= min_columns:
                faces.append((axis, side))
    return faces


def specks(
    grid: np.ndarray, threshold: float, keep_share: float = SPECK_SHARE, margin: int = SPECK_MARGIN
) -> np.ndarray:
    """What floats apart from the object: (X, Y, Z) bool.

    The pieces of ``grid > threshold`` (26-connected) are the object (the one holding the
    most density), a second object (any piece holding at least ``keep_share`` of the
    grid's density) or specks. Everything more than ``margin`` cells (along any axis) from
    the object and the second objects is returned: the specks and the faint haze around them.

    Args:
        grid: (X, Y, Z) density, the table's paint already cleared.
        threshold: the density that counts as part of a piece (a haze level, below the
            surface's: a speck's haze joins it).
        keep_share: a piece holding at least this share of the grid's density is kept.
        margin: cells kept around the pieces kept.
    """
    from scipy import ndimage

    labels, count, _ = _pieces(grid > threshold)
    if count == 0:
        return np.zeros(grid.shape, bool)
    mass = np.asarray(ndimage.sum(grid, labels, np.arange(count + 1)))
    kept = mass >= keep_share * float(grid.sum())
    kept[int(np.argmax(mass[1:])) + 1] = True
    kept[0] = False
    # (a cube's dilation: 10x faster than the Euclidean distance on a mesh's 256^3 grid)
    return ~ndimage.binary_dilation(kept[labels], structure=np.ones((3, 3, 3), bool), iterations=margin)


__all__ = [
    "MESH_OPACITY",
    "MESH_OPACITY_CELLS",
    "MIN_OBJECT_POINTS",
    "OBJECT_BOX_QUANTILE",
    "OBJECT_SEEN_SHARE",
    "SPECK_MARGIN",
    "SPECK_SHARE",
    "SURFACE_DENSITY",
    "box_corners",
    "box_radius",
    "faces_reached",
    "inside_quads",
    "object_box",
    "object_box_from_points",
    "object_points",
    "seen_share",
    "specks",
    "sphere_radius",
    "surface_threshold",
]
