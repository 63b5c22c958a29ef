"""The object a capture's model holds, apart from its table.

A capture's object stands on a table that the model draws as a textured plane; training
also paints some of the table (a tag's black squares, the sheet's edge) into the density
just above it, and leaves specks of density floating apart from the object. Meshes
(``nerfkit export --mesh``) and object-only videos (``nerfkit render --object``) clear
both. NumPy and SciPy only: the CLI reads the defaults at start-up.
"""

from __future__ import annotations

import numpy as np

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


# how high above a capture's table its paint is cleared, as a fraction of the object's height
TABLE_CUT = 0.05
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


def cleared_note(height: float, tags) -> str:
    """What clearing the table's paint up to ``height`` does, for messages (``tags``: the
    printed tags' corners, (n, 4, 3), or None)."""
    which = "the printed tag" if tags is None or len(tags) == 1 else f"the {len(tags)} printed tags"
    over = "" if tags is None or height <= 0 else f", {3 * height:.3g} over {which}"
    return f"table paint cleared up to {height:.3g} above the table{over}, and specks apart from the object"


def table_paint(grid: np.ndarray, axes, plane, height: float, threshold: float, tags=None) -> np.ndarray:
    """Where a density grid holds a capture's table paint: (X, Y, Z) bool.

    Training paints some of the table (a tag's black squares, the sheet's edge) into the
    density just above it, where the photos disagree by a pixel or two. Counted as paint:
    everything under the plane (rays stop at the table, so it was never seen) and what lies
    within ``height`` above it in the columns (along the grid axis nearest the plane's
    normal, widened by two cells) where no density over ``threshold`` rises between
    ``height`` and ``2 * height``. What stands on the table keeps its base, as wide as the
    object is just above the slab. A capture's table is level (z = const), so its columns
    are the grid's; under a tilted plane they would lean by its tilt. Paint that stands up
    off the table counts too: pieces (over ``threshold``) apart from the object that never
    rise ``3 * height`` above the table (:func:`_low_pieces`). Over a printed tag, which is
    flat paper, the columns' test goes three times higher: what stays under ``3 * height``
    in the columns over a tag where nothing rises between ``3 * height`` and ``6 * height``
    is paint too, even when the fur's haze joins it to the object beside the tag. (An
    object standing on a tag keeps its feet: their columns rise; a shoe wider than its leg
    would lose what sticks out over the tag, up to ``3 * height``.)

    Args:
        grid: (X, Y, Z) density at the points ``axes[0][i], axes[1][j], axes[2][k]``.
        axes: the grid's x, y and z positions, (X,), (Y,) and (Z,).
        plane: (4,) ``(n, d)``, unit normal ``n`` toward the cameras: height is ``n . x + d``.
        height: world units; 0 counts only what is under the plane.
        threshold: the density that counts as rising out of the slab, and as part of a piece.
        tags: (n, 4, 3) corners of the printed tags lying on the plane, or None.
    """
    n = np.asarray(plane, np.float64)[:3]
    above = heights(axes, plane)
    paint = above < 0
    if height > 0:
        axis = int(np.argmax(np.abs(n)))
        paint |= (above < height) & ~_rising(grid > threshold, above, height, axis)
        if tags is not None:
            over = np.expand_dims(_over_tags(tags, axes, axis), axis)
            paint |= over & (above < 3 * height) & ~_rising(grid > threshold, above, 3 * height, axis)
        paint |= _low_pieces(grid > threshold, paint, above, 3 * height, axis)
    return paint


def heights(axes, plane) -> np.ndarray:
    """(X, Y, Z) float32 height above ``plane`` (``(n, d)``: ``n . x + d``) of the grid
    points ``axes[0][i], axes[1][j], axes[2][k]``."""
    n, d = np.asarray(plane, np.float64)[:3], float(np.asarray(plane)[3])
    xs, ys, zs = (np.asarray(a, np.float64) for a in axes)
    return (n[0] * xs[:, None, None] + n[1] * ys[None, :, None] + n[2] * zs[None, None, :] + d).astype(np.float32)


def _rising(solid: np.ndarray, above: np.ndarray, height: float, axis: int) -> np.ndarray:
    """The columns along ``axis`` (widened by two cells) with something ``solid`` between
    ``height`` and ``2 * height`` above the table: (X, Y, Z) bool, 1 along ``axis``."""
    from scipy import ndimage

    band = (above >= height) & (above < 2 * height) & solid
    return ndimage.binary_dilation(band.any(axis=axis, keepdims=True), iterations=2)


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


def _over_tags(tags, axes, axis: int) -> np.ndarray:
    """Which grid columns along ``axis`` stand over a printed tag: the tags' corners (n,
    4, 3), seen down ``axis``, each a convex quadrilateral. Bool over the other two axes."""
    u, v = (np.asarray(axes[a], np.float64) for a in range(3) if a != axis)
    U, V = np.meshgrid(u, v, indexing="ij")
    quads = np.delete(np.asarray(tags, np.float64), axis, axis=2)  # (n, 4, 2)
    return inside_quads(np.stack([U.ravel(), V.ravel()], -1), quads).reshape(U.shape)


def _pieces(solid: np.ndarray) -> tuple[np.ndarray, int, int]:
    """The 26-connected pieces of ``solid``: their labels (0: not solid), their count, and
    the label of the largest (0 when there is none)."""
    from scipy import ndimage

    labels, count = ndimage.label(solid, structure=np.ones((3, 3, 3), bool))
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels, count, int(np.argmax(sizes))


def _low_pieces(solid: np.ndarray, paint: np.ndarray, above: np.ndarray, top: float, axis: int) -> np.ndarray:
    """Paint that stands up off the table: the pieces of ``solid & ~paint`` (26-connected)
    apart from the largest one (the object) that never rise ``top`` above the table,
    widened by two cells (their haze) short of a cell from the object. (X, Y, Z) bool.

    Only the slab of layers along ``axis`` (the table's normal) that reach below ``top``,
    and one layer more on either side, is labelled: what reaches those layers rises higher."""
    from scipy import ndimage

    out = np.zeros_like(solid)
    reach = np.nonzero((above < top).any(axis=tuple(a for a in range(3) if a != axis)))[0]
    if len(reach) == 0:
        return out
    cut = [slice(None)] * 3
    cut[axis] = slice(max(int(reach[0]) - 1, 0), min(int(reach[-1]) + 2, solid.shape[axis]))
    slab = tuple(cut)
    labels, count, main = _pieces(solid[slab] & ~paint[slab])
    if count < 2:
        return out
    low = np.asarray(ndimage.maximum(above[slab], labels, np.arange(count + 1))) < top
    low[0] = low[main] = False
    pieces = ndimage.binary_dilation(low[labels], iterations=2)
    out[slab] = pieces & ~ndimage.binary_dilation(labels == main)
    return out


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


def around_object(grid: np.ndarray, axes, plane, height: float, threshold: float, tags=None) -> np.ndarray:
    """What a density grid holds around a capture's object: its table's paint
    (:func:`table_paint`, with the same arguments) and, past that, the :func:`specks`
    floating apart from it (pieces at a fifth of the surface's ``threshold``).
    (X, Y, Z) bool."""
    paint = table_paint(grid, axes, plane, height, threshold, tags)
    return paint | specks(np.where(paint, 0.0, grid), threshold / 5)


def clear_around_object(grid: np.ndarray, axes, plane, height: float, threshold: float, tags=None) -> np.ndarray:
    """``grid`` with what lies :func:`around_object` set to zero density (in place; returned)."""
    grid[around_object(grid, axes, plane, height, threshold, tags)] = 0.0
    return grid
