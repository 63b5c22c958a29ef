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
    return np.stack(
        [
            0.5 + 0.4 * np.sin(3.0 * p[:, 0] + 1.0),
            0.5 + 0.4 * np.sin(3.0 * p[:, 1] + 2.0),
            0.5 + 0.4 * np.sign(np.sin(4.0 * p[:, 2])),
        ],
        axis=1,
    )


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


def sphere_cameras(
    n: int, distance: float = 4.0, seed: int = 0, elevation: tuple[float, float] = (10.0, 60.0)
) -> np.ndarray:
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

    return Scene(
        views(n_train, seed),
        views(n_val, seed + 1),
        views(n_test, seed + 2, with_images=False),
        near=2.0,
        far=6.0,
        center=np.zeros(3, np.float32),
        up=np.array([0, 0, 1], np.float32),
        source="synthetic:sphere",
    )


def table_color(points: np.ndarray) -> np.ndarray:
    """Colour (n, 3) of the table z = 0 at points (n, 3): a smooth two-tone pattern."""
    x, y = points[:, 0], points[:, 1]
    a = 0.5 + 0.5 * np.sin(2.0 * x) * np.cos(2.0 * y)
    return np.stack([0.25 + 0.5 * a, 0.35 + 0.3 * a, 0.6 - 0.3 * a], axis=1)


def render_tabletop(K: np.ndarray, c2w: np.ndarray, width: int, height: int, gain: float = 1.0) -> np.ndarray:
    """Exact render (H, W, 3) uint8 of the unit sphere standing on the table z = 0 (its
    centre at (0, 0, 1)), a sky of constant colour above the horizon, times ``gain``."""
    rays = image_rays(torch.from_numpy(K), torch.from_numpy(c2w).float(), width, height)
    o, d = rays.origins.double().numpy(), rays.directions.double().numpy()
    oc = o - np.array([0.0, 0.0, 1.0])
    b = (oc * d).sum(1)
    disc = b * b - ((oc * oc).sum(1) - 1.0)
    t_sphere = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
    t_sphere = np.where(t_sphere > 0, t_sphere, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_table = np.where(d[:, 2] < -1e-9, -o[:, 2] / d[:, 2], np.inf)
    img = np.tile(np.array([0.7, 0.8, 0.9]), (o.shape[0], 1))
    on_table = np.isfinite(t_table) & (t_table < t_sphere)
    on_sphere = np.isfinite(t_sphere) & ~on_table
    img[on_table] = table_color(o[on_table] + t_table[on_table, None] * d[on_table])
    img[on_sphere] = sphere_color(o[on_sphere] + t_sphere[on_sphere, None] * d[on_sphere] - np.array([0, 0, 1.0]))
    return (np.clip(img * gain, 0, 1).reshape(height, width, 3) * 255 + 0.5).astype(np.uint8)


def tabletop_scene(
    n_train: int = 16, n_val: int = 2, size: int = 32, seed: int = 0, gains: np.ndarray | None = None
) -> Scene:
    """A small real-capture-like dataset: a textured sphere on a textured table, cameras
    circling it from above, photos with per-view exposure ``gains`` (n_train,) if given.
    Marked a capture with the table plane z = 0."""
    focal = 1.2 * size
    K = intrinsics_matrix(focal, focal, size / 2, size / 2)
    target = np.array([0.0, 0.0, 1.0])

    def views(n: int, s: int, g) -> Views:
        if n == 0:
            return Views.empty(size, size)
        rng = np.random.default_rng(s)
        az = rng.uniform(0, 2 * np.pi, n)
        el = np.deg2rad(rng.uniform(20.0, 50.0, n))
        eyes = target + 4.0 * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
        c2w = np.stack([look_at(e, target, np.array([0.0, 0.0, 1.0])) for e in eyes]).astype(np.float32)
        images = np.stack(
            [render_tabletop(K, c, size, size, 1.0 if g is None else float(g[i])) for i, c in enumerate(c2w)]
        )
        return Views(c2w, np.repeat(K[None], n, 0), size, size, images, [f"tabletop_{s}_{i:03d}" for i in range(n)])

    return Scene(
        views(n_train, seed, gains),
        views(n_val, seed + 1, None),
        Views.empty(size, size),
        near=1.0,
        far=8.0,
        center=target.astype(np.float32),
        up=np.array([0, 0, 1], np.float32),
        source="synthetic:tabletop",
        capture=True,
        table=np.array([0, 0, 1, 0], np.float32),
    )


# forward_facing_scene's content: two spheres (centre, radius) and a backdrop plane y = BACKDROP_Y
FORWARD_SPHERES = ((np.array([0.3, 3.0, 0.1]), 0.6), (np.array([-0.9, 6.0, 0.6]), 1.2))
BACKDROP_Y = 15.0


def render_forward(K: np.ndarray, c2w: np.ndarray, width: int, height: int) -> np.ndarray:
    """Exact render (H, W, 3) uint8 of :func:`forward_facing_scene`'s content: two textured
    spheres in front of a textured backdrop plane far behind them."""
    rays = image_rays(torch.from_numpy(K), torch.from_numpy(c2w).float(), width, height)
    o, d = rays.origins.double().numpy(), rays.directions.double().numpy()
    with np.errstate(divide="ignore", invalid="ignore"):
        t_best = np.where(d[:, 1] > 1e-9, (BACKDROP_Y - o[:, 1]) / d[:, 1], np.inf)
    p = o + np.where(np.isfinite(t_best), t_best, 0.0)[:, None] * d
    img = np.stack(
        [
            0.5 + 0.35 * np.sin(1.3 * p[:, 0]) * np.cos(1.1 * p[:, 2]),
            0.45 + 0.3 * np.sign(np.sin(0.9 * p[:, 0] + 0.7 * p[:, 2])),
            0.5 + 0.3 * np.cos(0.8 * p[:, 2]),
        ],
        axis=1,
    )
    img[~np.isfinite(t_best)] = 0.0
    for centre, radius in FORWARD_SPHERES:
        oc = o - centre
        b = (oc * d).sum(1)
        disc = b * b - ((oc * oc).sum(1) - radius**2)
        t = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
        hit = (t > 0) & (t < t_best)
        img[hit] = sphere_color((o[hit] + t[hit, None] * d[hit] - centre) / radius)
        t_best = np.where(hit, t, t_best)
    return (np.clip(img, 0, 1).reshape(height, width, 3) * 255 + 0.5).astype(np.uint8)


def forward_facing_scene(n_train: int = 16, n_val: int = 2, size: int = 32, seed: int = 0) -> Scene:
    """A small forward-facing dataset (as LLFF captures): cameras within +-0.4 of the
    origin across the view, all looking along +y (world up +z) at two textured spheres 3
    and 6 units away in front of a textured backdrop 15 units away."""
    focal = 1.1 * size
    K = intrinsics_matrix(focal, focal, size / 2, size / 2)

    def views(n: int, s: int) -> Views:
        if n == 0:
            return Views.empty(size, size)
        rng = np.random.default_rng(s)
        eyes = np.stack([rng.uniform(-0.4, 0.4, n), np.zeros(n), rng.uniform(-0.4, 0.4, n)], 1)
        targets = eyes + np.array([0.0, 10.0, 0.0]) + np.c_[rng.normal(0, 0.3, n), np.zeros(n), rng.normal(0, 0.3, n)]
        c2w = np.stack([look_at(e, t, np.array([0.0, 0.0, 1.0])) for e, t in zip(eyes, targets)]).astype(np.float32)
        images = np.stack([render_forward(K, c, size, size) for c in c2w])
        return Views(c2w, np.repeat(K[None], n, 0), size, size, images, [f"forward_{s}_{i:03d}" for i in range(n)])

    return Scene(
        views(n_train, seed),
        views(n_val, seed + 1),
        Views.empty(size, size),
        near=2.0,
        far=20.0,
        center=np.array([0.0, 6.0, 0.0], np.float32),
        up=np.array([0, 0, 1], np.float32),
        source="synthetic:forward",
    )
