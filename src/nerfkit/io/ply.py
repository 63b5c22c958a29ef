"""Reading a PLY file's vertices with a clear error: point clouds and 3DGS splat files alike."""

from __future__ import annotations

from pathlib import Path

from ..errors import fail


def read_vertices(path: str | Path, what: str, where: object = None):
    """The ``vertex`` element of the PLY file ``path`` (plyfile's ``PlyElement``); a clear error
    naming ``where`` (else ``path``) when the file is missing, cut short, not a PLY or has no
    vertices, saying it is not ``what``."""
    try:
        from plyfile import PlyData, PlyParseError
    except ImportError:
        raise fail(where or path, "reading a PLY file needs plyfile", "pip install plyfile") from None
    try:
        return PlyData.read(str(path))["vertex"]
    except (OSError, KeyError, ValueError, IndexError, PlyParseError) as e:
        raise fail(where or path, f"not {what} ({type(e).__name__})") from None
