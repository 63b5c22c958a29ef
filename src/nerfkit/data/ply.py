"""Point cloud PLY files: ``x y z`` float32 and ``red green blue`` uchar, what nerfstudio
(``sparse_pc.ply``) and 3DGS read. Datasets carry their sparse points in one;
:mod:`nerfkit.export` writes reconstructed points in the same format.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import fail
from ..io.atomic import atomic_path
from ..io.ply import read_vertices


def write_points_ply(path: str | Path, points: np.ndarray, colors: np.ndarray | None = None) -> None:
    """Write a point cloud (points (P, 3), colours (P, 3) uint8) as binary PLY with
    ``x y z`` float32 and ``red green blue`` uchar (what nerfstudio and 3DGS read), atomically."""
    from plyfile import PlyData, PlyElement

    pts = np.asarray(points, np.float32).reshape(-1, 3)
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4")] + (
        [("red", "u1"), ("green", "u1"), ("blue", "u1")] if colors is not None else []
    )
    rows = np.empty(len(pts), dtype=fields)
    for i, k in enumerate("xyz"):
        rows[k] = pts[:, i]
    if colors is not None:
        for i, k in enumerate(("red", "green", "blue")):
            rows[k] = np.asarray(colors, np.uint8)[:, i]
    with atomic_path(path) as tmp:
        PlyData([PlyElement.describe(rows, "vertex")]).write(str(tmp))


def read_points_ply(path: str | Path, where: object = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a point cloud PLY's ``x, y, z`` (P, 3) float32 and, when present, its
    ``red, green, blue`` (P, 3) uint8 (e.g. nerfstudio's ``sparse_pc.ply``)."""
    what = "a readable PLY point cloud with x, y, z"
    v = read_vertices(path, what, where)
    try:
        xyz = np.stack([np.asarray(v[k], np.float32) for k in ("x", "y", "z")], 1)
        names = {p.name for p in v.properties}
        rgb = (
            np.stack([np.asarray(v[k]) for k in ("red", "green", "blue")], 1).astype(np.uint8)
            if {"red", "green", "blue"} <= names
            else None
        )
    except (KeyError, ValueError, IndexError) as e:
        raise fail(where or path, f"not {what} ({type(e).__name__})") from None
    return xyz, rgb
