"""The object a capture's model holds, apart from its table.

A capture's object stands on a table that the model draws as a textured plane; training
also paints some of the table (a tag's black squares, the sheet's edge) into the density
just above it, and leaves specks of density floating apart from the object. Meshes
(``nerfkit export --mesh``) and object-only videos (``nerfkit render --object``) clear
both. NumPy and SciPy only: the CLI reads the defaults at start-up.
"""

from __future__ import annotations

import numpy as np

from ..scene_extent import _pieces, inside_quads, specks
from ..table_cut import TABLE_CUT as TABLE_CUT  # re-exported: how high the table's paint is cleared


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


def _over_tags(tags, axes, axis: int) -> np.ndarray:
    """Which grid columns along ``axis`` stand over a printed tag: the tags' corners (n,
    4, 3), seen down ``axis``, each a convex quadrilateral. Bool over the other two axes."""
    u, v = (np.asarray(axes[a], np.float64) for a in range(3) if a != axis)
    U, V = np.meshgrid(u, v, indexing="ij")
    quads = np.delete(np.asarray(tags, np.float64), axis, axis=2)  # (n, 4, 2)
    return inside_quads(np.stack([U.ravel(), V.ravel()], -1), quads).reshape(U.shape)


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
