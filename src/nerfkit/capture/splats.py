"""The object alone out of a capture's Gaussian splat: the Gaussians whose centres lie in the
object's box (the box the dataset's sparse points give the object standing on its table,
:func:`~nerfkit.scene_extent.object_box_from_points`), written as another splat file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

# viewers that open the files `nerfkit capture --model splat` writes
PLY_VIEWERS = "SuperSplat (superspl.at/editor), Brush, Polycam, Postshot, nerfstudio"
DOT_SPLAT_VIEWERS = "antimatter15's splat viewer and its descendants"


def in_box(means: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n,) bool: which of the points ``means`` (n, 3) lie in the box ``lo``..``hi`` ((3,) each, edges in)."""
    m = np.asarray(means, np.float64)
    return np.all((m >= np.asarray(lo, np.float64)) & (m <= np.asarray(hi, np.float64)), axis=1)


def crop_gaussians(g, lo: np.ndarray, hi: np.ndarray):
    """The :class:`~nerfkit.splat_files.Gaussians` of ``g`` whose centres lie in the box ``lo``..``hi``."""
    from ..splat_files import Gaussians

    keep = in_box(g.means, lo, hi)
    return Gaussians(
        g.means[keep], g.log_scales[keep], g.quats[keep], g.opacity_logits[keep], g.sh_dc[keep], g.sh_rest[keep]
    )


def write_object_splat(src: str | Path, dst: str | Path, box: tuple[np.ndarray, np.ndarray]) -> tuple[int, int]:
    """Write to ``dst`` (3DGS PLY, or ``.splat``) the Gaussians of the PLY ``src`` inside
    ``box`` ``(lo, hi)``; (Gaussians kept, Gaussians in ``src``)."""
    from ..splat_files import read_splat_ply, write_dot_splat, write_splat_ply

    g = read_splat_ply(src)
    alone = crop_gaussians(g, *box)
    (write_dot_splat if str(dst).lower().endswith(".splat") else write_splat_ply)(dst, alone)
    return len(alone), len(g)


def object_box(bounds) -> tuple[np.ndarray, np.ndarray, str]:
    """The box ``(lo, hi, what it is)`` the object's Gaussians are taken from, for a run's
    :class:`~nerfkit.models.base.SceneBounds`: the object's box from the sparse points when
    the dataset gave one, else the cube around the object's sphere, cut at the table when
    there is one (a capture's table faces +z)."""
    if bounds.object_box is not None:
        lo, hi = (np.asarray(b, np.float64) for b in bounds.object_box)
        return lo, hi, "the object's box (from the sparse points standing on the table)"
    c, r = np.asarray(bounds.center, np.float64), float(bounds.radius)
    lo, hi = c - r, c + r
    table = None if bounds.table is None else np.asarray(bounds.table, np.float64)
    if table is not None and table[2] > 0.9 * np.linalg.norm(table[:3]):  # n . x + d = 0, n about +z
        lo[2] = max(lo[2], -table[3] / table[2])
        return lo, hi, "the cube around the object's sphere, above the table"
    return lo, hi, "the cube around the object's sphere (no table found)"
