"""Gaussian splats on disk: the standard 3DGS PLY, and the 32-byte ``.splat`` of web viewers.

PLY (what the INRIA code, gsplat, SuperSplat and Brush read): one binary little-endian
``vertex`` element with float32 properties ``x y z nx ny nz f_dc_0..2 f_rest_0..(3K-1)
opacity scale_0..2 rot_0..3``. Values are stored raw, before activation: log-scales,
opacity logits, quaternions ``(w, x, y, z)`` (any length), SH coefficients with
``f_dc = (rgb - 0.5) / 0.28209``; ``f_rest`` is channel-major (all red coefficients of
degree >= 1, then green, then blue), as INRIA flattens ``features_rest.transpose(1, 2)``.
Normals are written as zeros.

``.splat`` (antimatter15's viewer and its descendants): per Gaussian, position 3 x float32,
scale 3 x float32 (activated), RGBA 4 x uint8 (DC colour, sigmoid opacity), rotation
4 x uint8 ``(w, x, y, z)`` normalised, mapped ``q * 128 + 128``; sorted by size x opacity,
largest first. View-dependent colour is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import fail
from .io.atomic import atomic_path
from .splat_constants import SH_C0


def dc_to_rgb(sh_dc: np.ndarray) -> np.ndarray:
    """The colour (n, 3) that DC coefficients (n, 1, 3) show: ``0.5 + C0 * dc`` (not clipped)."""
    return 0.5 + SH_C0 * sh_dc.reshape(-1, 3)


def rgb_to_dc(rgb: np.ndarray) -> np.ndarray:
    """The DC coefficients (n, 1, 3) that show colour ``rgb`` (n, 3): ``(rgb - 0.5) / C0``."""
    return ((rgb - 0.5) / SH_C0).reshape(-1, 1, 3)


@dataclass
class Gaussians:
    """Raw Gaussian parameters (numpy float32).

    Attributes:
        means (n, 3), log_scales (n, 3), quats (n, 4) ``(w, x, y, z)``, opacity_logits (n,),
        sh_dc (n, 1, 3), sh_rest (n, K - 1, 3) with K = (degree + 1)^2.
    """

    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    opacity_logits: np.ndarray
    sh_dc: np.ndarray
    sh_rest: np.ndarray

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.sh_rest.shape[1] + 1))) - 1

    @staticmethod
    def from_model(model) -> Gaussians:
        """A splat model's Gaussians, with the higher SH coefficients of its ``sh_degree`` only
        (the model keeps degree 3's 15; a degree-0 run's file then holds none)."""

        def a(t):
            return t.detach().cpu().float().numpy()

        n_rest = (model.config.sh_degree + 1) ** 2 - 1

        return Gaussians(
            a(model.means),
            a(model.log_scales),
            a(model.quats),
            a(model.opacity_logits),
            a(model.sh_dc),
            a(model.sh_rest[:, :n_rest]),
        )


def rotation_quats(quats: np.ndarray) -> np.ndarray:
    """(n, 4) wxyz quaternions as read -> a float copy with each zero one (a Gaussian without
    rotation, as some tools write it) made the identity (1, 0, 0, 0)."""
    q = np.array(quats, dtype=np.float64)
    q[~(np.abs(q) > 0).any(axis=1)] = (1.0, 0.0, 0.0, 0.0)
    return q


def ply_property_names(n_rest: int) -> list[str]:
    """The 3DGS PLY vertex properties, in order, for ``n_rest`` higher SH coefficients per channel."""
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(3 * n_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2"]
        + ["rot_0", "rot_1", "rot_2", "rot_3"]
    )


def write_splat_ply(path: str | Path, g: Gaussians) -> None:
    """Write ``g`` as a standard 3DGS PLY (binary), atomically."""
    from plyfile import PlyData, PlyElement

    n, n_rest = len(g), g.sh_rest.shape[1]
    names = ply_property_names(n_rest)
    data = np.concatenate(
        [
            g.means,
            np.zeros((n, 3), np.float32),
            g.sh_dc.reshape(n, 3),
            g.sh_rest.transpose(0, 2, 1).reshape(n, 3 * n_rest),  # channel-major, as INRIA
            g.opacity_logits.reshape(n, 1),
            g.log_scales,
            g.quats,
        ],
        axis=1,
    ).astype(np.float32)
    vertex = np.empty(n, dtype=[(name, "f4") for name in names])
    for i, name in enumerate(names):
        vertex[name] = data[:, i]
    with atomic_path(path) as tmp:
        PlyData([PlyElement.describe(vertex, "vertex")]).write(str(tmp))


def read_splat_ply(path: str | Path) -> Gaussians:
    """Read a 3DGS PLY (any SH degree up to 3); a clear error for anything else."""
    from .io.ply import read_vertices

    v = read_vertices(path, "a readable PLY with a 'vertex' element")
    names = [p.name for p in v.properties]
    n_rest3 = len([p for p in names if p.startswith("f_rest_")])
    if n_rest3 % 3 or n_rest3 // 3 not in (0, 3, 8, 15):
        raise fail(path, f"has {n_rest3} f_rest properties, expected 0, 9, 24 or 45")
    want = ply_property_names(n_rest3 // 3)
    missing = [p for p in want if p not in names and p not in ("nx", "ny", "nz")]
    if missing:
        raise fail(path, f"is not a Gaussian-splat PLY (missing {', '.join(missing[:4])})")

    def col(*keys):
        return np.stack([np.asarray(v[k], np.float32) for k in keys], 1)

    n = len(v.data)
    rest = n_rest3 // 3
    f_rest = col(*[f"f_rest_{i}" for i in range(n_rest3)]) if rest else np.zeros((n, 0), np.float32)
    return Gaussians(
        col("x", "y", "z"),
        col("scale_0", "scale_1", "scale_2"),
        col("rot_0", "rot_1", "rot_2", "rot_3"),
        np.asarray(v["opacity"], np.float32),
        col("f_dc_0", "f_dc_1", "f_dc_2").reshape(n, 1, 3),
        f_rest.reshape(n, 3, rest).transpose(0, 2, 1).copy(),
    )


def write_dot_splat(path: str | Path, g: Gaussians) -> None:
    """Write ``g`` in the 32-byte-per-Gaussian ``.splat`` layout (see the module docstring)."""
    scales = np.exp(g.log_scales.astype(np.float64))
    alpha = 1 / (1 + np.exp(-g.opacity_logits.astype(np.float64)))
    order = np.argsort(-np.exp(g.log_scales.sum(1)) * alpha, kind="stable")
    rgb = dc_to_rgb(g.sh_dc)
    rgba = np.clip(np.concatenate([rgb, alpha[:, None]], 1) * 255, 0, 255).round().astype(np.uint8)
    q = g.quats / np.linalg.norm(g.quats, axis=1, keepdims=True).clip(1e-12)
    rot = np.clip(q * 128 + 128, 0, 255).round().astype(np.uint8)
    rec = np.empty(len(g), dtype=[("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
    rec["pos"], rec["scale"], rec["rgba"], rec["rot"] = g.means, scales, rgba, rot
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(rec[order].tobytes())
