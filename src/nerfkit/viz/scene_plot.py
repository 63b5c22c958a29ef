"""A static picture of a dataset: cameras, world axes, tag plane, rays and their samples.

The geometry helpers here are shared with the interactive viewer (:mod:`.viewer`). Rays
come from :func:`nerfkit.cameras.pixel_to_ray` and their samples from
:func:`nerfkit.render.sampling.sample_along_rays`, exactly as training sees them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..cameras import axes_across
from ..data.scene import Scene, Views
from ..io.atomic import atomic_path

SPLIT_COLORS = {"train": (0.12, 0.47, 0.71), "val": (1.0, 0.5, 0.05), "test": (0.17, 0.63, 0.17)}


def scene_scale(scene: Scene) -> float:
    """Median distance from the cameras to the scene centre (a length for drawing sizes)."""
    pos = np.concatenate([v.c2w[:, :3, 3] for v in scene.splits.values() if len(v)])
    d = np.linalg.norm(pos - scene.center, axis=1)
    return float(np.median(d)) if len(d) and np.median(d) > 0 else 1.0


def printed_tags(scene: Scene, tag_size: float | None) -> np.ndarray | None:
    """(n, 4, 3) the printed tags to draw: those the dataset records (every tag of a
    sheet), else one of ``tag_size`` at the origin in the plane across ``up``, else None."""
    if scene.tags is not None:
        return np.asarray(scene.tags, np.float64)
    if not tag_size:
        return None
    a, b = axes_across(scene.up)
    return (np.array([-a - b, a - b, a + b, -a + b]) * tag_size / 2)[None]


def frustum_points(K: np.ndarray, c2w: np.ndarray, width: int, height: int, depth: float) -> np.ndarray:
    """(5, 3) world points: the camera centre, then the image corners (top-left, top-right,
    bottom-right, bottom-left) on the plane ``depth`` in front of it (nerfkit pixels)."""
    uv = np.array([[0, 0], [width, 0], [width, height], [0, height]], np.float64)
    x = (uv[:, 0] - K[0, 2]) / K[0, 0]
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    pc = np.column_stack([x, y, np.ones(4)]) * depth
    pw = pc @ c2w[:3, :3].T + c2w[:3, 3]
    return np.vstack([c2w[:3, 3], pw])


@dataclass
class RaySamples:
    """Rays as training samples them.

    Attributes:
        origins, directions: (n, 3).
        segments: (n, 2, 3) the points at near and far.
        points: (n, s, 3) stratified samples between near and far.
    """

    origins: np.ndarray
    directions: np.ndarray
    segments: np.ndarray
    points: np.ndarray


def sample_rays(
    views: Views, near: float, far: float, n_rays: int, n_samples: int = 64, seed: int = 0, view: int | None = None
) -> RaySamples:
    """``n_rays`` random pixels of random views (of view ``view`` only, when given: the
    course's check that u and v are not swapped), their rays and stratified samples."""
    import torch

    from ..cameras import pixel_to_ray
    from ..render.sampling import sample_along_rays

    g = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(views), n_rays) if view is None else np.full(n_rays, view)
    uv = np.column_stack([rng.integers(0, views.width, n_rays), rng.integers(0, views.height, n_rays)]) + 0.5
    o, d = pixel_to_ray(
        torch.from_numpy(views.K[idx]).float(), torch.from_numpy(views.c2w[idx]).float(), torch.from_numpy(uv).float()
    )
    pts, _ = sample_along_rays(o, d, near, far, n_samples, perturb=True, generator=g)
    origins, dirs = o.numpy().astype(np.float64), d.numpy().astype(np.float64)
    seg = np.stack([origins + near * dirs, origins + far * dirs], axis=1)
    return RaySamples(origins, dirs, seg, pts.numpy().astype(np.float64))


def _to_plot(up: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) taking the scene's up to +z (matplotlib's vertical), and world x, levelled
    across up, to +x (world y when x is nearly up)."""
    n = np.asarray(up, np.float64) / np.linalg.norm(up)
    for axis in np.eye(3)[:2]:
        a = axis - (axis @ n) * n
        if np.linalg.norm(a) > 0.1:
            break
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(n, a), n])


def _axis_label(direction: np.ndarray) -> str:
    """A plot axis's name: the world axis it shows, or "across up" when it shows none."""
    for name, axis in zip("xyz", np.eye(3)):
        for sign, mark in ((1, ""), (-1, "-")):
            if sign * direction @ axis > 0.9998:  # within about a degree
                return mark + name
    return "across up"


def plot_scene(
    scene: Scene,
    path: str | Path,
    n_rays: int = 0,
    n_samples: int = 64,
    tag_size: float | None = None,
    max_cameras: int = 80,
    thumbnails: bool = True,
    seed: int = 0,
    title: str = "",
    rays_from: int | None = None,
) -> None:
    """Write a PNG of the scene's cameras (frustums with thumbnails of their images), the world
    axes, the tag plane (z = 0 of the world, perpendicular to up) and ``n_rays`` training rays
    (of training view ``rays_from`` only, when given) with their samples."""
    from .plots import _pyplot

    plt = _pyplot()
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    R = _to_plot(scene.up)
    T = lambda p: np.asarray(p, np.float64) @ R.T  # noqa: E731 - world -> plot axes
    scale = scene_scale(scene)
    depth = 0.12 * scale
    fig = plt.figure(figsize=(9, 8), dpi=110)
    ax = fig.add_subplot(projection="3d")
    everything = [T(scene.center)[None]]

    # Tag plane (through the world origin, perpendicular to up) and the tag itself.
    a, b = axes_across(scene.up)
    half = 0.5 * scale
    quad = np.array([-a - b, a - b, a + b, -a + b]) * half
    ax.add_collection3d(Poly3DCollection([T(quad)], facecolor=(0.6, 0.6, 0.6, 0.18), edgecolor=(0.5, 0.5, 0.5, 0.4)))
    tags = printed_tags(scene, tag_size)
    if tags is not None:
        ax.add_collection3d(Poly3DCollection([T(q) for q in tags], facecolor=(0, 0, 0, 0.85), edgecolor="k"))
    axis_len = 1.5 * tag_size if tag_size else 0.25 * scale
    for k, c in enumerate("rgb"):
        e = np.zeros(3)
        e[k] = axis_len
        seg = T(np.stack([np.zeros(3), e]))
        ax.plot(*seg.T, color=c, linewidth=2.5)
    everything.append(T(quad))

    # Cameras.
    rng = np.random.default_rng(seed)
    for split, v in scene.splits.items():
        if len(v) == 0:
            continue
        keep = np.arange(len(v)) if len(v) <= max_cameras else np.sort(rng.choice(len(v), max_cameras, replace=False))
        lines = []
        for i in keep:
            f = frustum_points(v.K[i].astype(np.float64), v.c2w[i].astype(np.float64), v.width, v.height, depth)
            f = T(f)
            everything.append(f)
            lines += [[f[0], f[j]] for j in range(1, 5)] + [[f[j], f[j % 4 + 1]] for j in range(1, 5)]
            if thumbnails and v.images is not None:
                th = v.images[i][:: max(1, v.height // 12), :: max(1, v.width // 16)].astype(np.float64) / 255.0
                gh, gw = th.shape[:2]
                s_ = np.linspace(0, 1, gw + 1)[None, :, None]
                t_ = np.linspace(0, 1, gh + 1)[:, None, None]
                grid = (1 - t_) * ((1 - s_) * f[1] + s_ * f[2]) + t_ * ((1 - s_) * f[4] + s_ * f[3])
                ax.plot_surface(
                    grid[..., 0],
                    grid[..., 1],
                    grid[..., 2],
                    facecolors=th,
                    shade=False,
                    rstride=1,
                    cstride=1,
                    linewidth=0,
                    antialiased=False,
                )
        ax.add_collection3d(
            Line3DCollection(lines, colors=[SPLIT_COLORS.get(split, "k")], linewidths=0.8, label=f"{split} ({len(v)})")
        )

    # Rays and their samples.
    if n_rays > 0 and len(scene.train):
        rs = sample_rays(scene.train, scene.near, scene.far, n_rays, n_samples, seed, rays_from)
        cols = plt.get_cmap("tab10")(np.arange(n_rays) % 10)
        ax.add_collection3d(Line3DCollection([T(s) for s in rs.segments], colors=cols, linewidths=0.7, alpha=0.8))
        pts = T(rs.points.reshape(-1, 3))
        ax.scatter(*pts.T, s=3, c=np.repeat(cols, rs.points.shape[1], axis=0), depthshade=False)
        everything.append(T(rs.segments.reshape(-1, 3)))
    ax.scatter(*T(scene.center), marker="*", s=120, c="m", label="centre", depthshade=False)

    pts = np.concatenate(everything)
    lo, hi = pts.min(0), pts.max(0)
    mid, r = (lo + hi) / 2, (hi - lo).max() / 2 * 1.05
    ax.set_xlim(mid[0] - r, mid[0] + r)
    ax.set_ylim(mid[1] - r, mid[1] + r)
    ax.set_zlim(mid[2] - r, mid[2] + r)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=28, azim=-60)
    ax.set_xlabel(_axis_label(R[0]))
    ax.set_ylabel(_axis_label(R[1]))
    ax.set_zlabel("up")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(
        title
        or f"{Path(scene.source).name or 'scene'}: near {scene.near:.3g}, far {scene.far:.3g}"
        + (f", {n_rays} rays x {n_samples} samples" if n_rays else ""),
        fontsize=10,
    )
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
