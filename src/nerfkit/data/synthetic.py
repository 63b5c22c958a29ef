"""Small scenes generated analytically, for tests, benchmarks and self-checks.

:func:`sphere_scene` renders a textured opaque sphere (radius 1 at the origin) over a
black background by exact ray-sphere intersection, from cameras on a sphere looking
at the origin, in nerfkit's convention (OpenCV axes, world up +z).
"""

from __future__ import annotations

import numpy as np
import torch

from ..cameras import image_rays, intrinsics_matrix, look_at
from .scene import Scene, Views


def sphere_color(points: np.ndarray) -> np.ndarray:
    """Colour (n, 3) in [0, 1] of the sphere's surface at unit-sphere points (n, 3)."""
    p = points
    return np.stack([
        0.5 + 0.4 * np.sin(3.0 * p[:, 0] + 1.0),
        0.5 + 0.4 * np.sin(3.0 * p[:, 1] + 2.0),
        0.5 + 0.4 * np.sign(np.sin(4.0 * p[:, 2])),
    ], axis=1)


def render_sphere(K: np.ndarray, c2w: np.ndarray, width: int, height: int) -> np.ndarray:
    """Exact render (H, W, 3) uint8 of the textured unit sphere at the origin."""
    rays = image_rays(torch.from_numpy(K), torch.from_numpy(c2w).float(), width, height)
    o, d = rays.origins.double().numpy(), rays.directions.double().numpy()
    b = (o * d).sum(1)
    c = (o * o).sum(1) - 1.0
    disc = b * b - c
    hit = disc > 0
    t = -b - np.sqrt(np.where(hit, disc, 0.0))
    hit &= t > 0
    img = np.zeros((o.shape[0], 3))
    pts = o[hit] + t[hit, None] * d[hit]
    img[hit] = sphere_color(pts)
    return (img.reshape(height, width, 3) * 255 + 0.5).astype(np.uint8)


def sphere_cameras(n: int, distance: float = 4.0, seed: int = 0, elevation: tuple[float, float] = (10.0, 60.0)) -> np.ndarray:
    """n camera-to-world poses (n, 4, 4) on a sphere around the origin, looking at it."""
    rng = np.random.default_rng(seed)
    az = rng.uniform(0, 2 * np.pi, n)
    el = np.deg2rad(rng.uniform(*elevation, n))
    eyes = distance * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
    return np.stack([look_at(e, np.zeros(3), np.array([0.0, 0.0, 1.0])) for e in eyes]).astype(np.float32)


def sphere_scene(n_train: int = 20, n_val: int = 3, size: int = 32, n_test: int = 4, seed: int = 0) -> Scene:
    """A small posed dataset of the textured sphere; near/far 2 and 6 as for lego."""
    focal = 1.2 * size
    K = intrinsics_matrix(focal, focal, size / 2, size / 2)

    def views(n: int, s: int, with_images: bool = True) -> Views:
        c2w = sphere_cameras(n, seed=s)
        Ks = np.repeat(K[None], n, 0)
        images = np.stack([render_sphere(K, c, size, size) for c in c2w]) if with_images and n else None
        return Views(c2w, Ks, size, size, images, [f"sphere_{s}_{i:03d}" for i in range(n)])

    return Scene(views(n_train, seed), views(n_val, seed + 1), views(n_test, seed + 2, with_images=False),
                 near=2.0, far=6.0, center=np.zeros(3, np.float32), up=np.array([0, 0, 1], np.float32),
                 source="synthetic:sphere")
