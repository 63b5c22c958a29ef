"""Export a radiance field as a coloured mesh or a coloured point cloud (PLY files).

The core works on plain callables so it can be tested with analytic fields:

* ``density_fn(points (n, 3) float32 tensor) -> (n,) density``
* ``query_fn(points (n, 3), directions (n, 3)) -> ((n,) density, (n, 3) colour in [0, 1])``

Mesh: the density is sampled on a grid over a cube (of half-size ``radius`` about
``center``: for a trained model, around its own box, :func:`mesh_region`), a capture's
table paint and the specks apart from its object are cleared (:func:`clear_around_object`),
the box border is padded with empty space so the surface closes where it meets the box
(the mesh is cropped to the box and watertight), and marching cubes (scikit-image) extracts
the ``threshold`` iso-surface. A trained model's vertices take the mean of its renders at
the training views that see them (:func:`view_colors`); a vertex no view sees (or any
vertex, with no views) is coloured by what a ray looking at it along the inward normal
sees (optionally averaged over a small cone of directions): the field volume-rendered
along a short segment through the surface (:func:`vertex_colors`).
The colour *at* the iso-surface would be the field's least constrained colour: training
fits colours where rays stop, at higher density, so a learned field's colour at its thin
edge is noise.

Points: each training view's expected depth (depth / acc, the depth of what the ray hit)
is back-projected where the opacity exceeds ``acc_min``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from . import surroundings
from .data.ply import read_points_ply as read_points_ply  # re-exported: the point cloud's file format
from .data.ply import write_points_ply as write_points_ply
from .errors import fail
from .io.atomic import atomic_path
from .scene_extent import SURFACE_DENSITY, box_radius, surface_threshold
from .surroundings.clearing import clear_around_object

DensityFn = Callable[[torch.Tensor], torch.Tensor]
QueryFn = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]


# how far outside a vertex its colour ray starts, as a fraction of the scene's radius: the
# depth of a trained field's fuzzy surface (benchmarks/mesh_colours.py: within 0.1-0.5 dB of
# each scene's best reach, which spans 1.6-3.4% of the radius)
COLOUR_REACH = 0.02

# a mesh's vertices are coloured from some of the training views, evenly spread (how many:
# `nerfkit export --color-views`, nerfkit.commands.options.ExportOptions) ...
# ... rendered with the longest side at most this many pixels ...
COLOUR_VIEW_SIDE = 1024
# ... where the vertex lies within this fraction of the scene's radius of the rendered depth
# (a trained field's iso-surface lies 1-2.5% of it in front of the rendered depth;
# benchmarks/mesh_colours.py)
COLOUR_VIEW_TOL = 0.05


@dataclass
class Mesh:
    """A triangle mesh: vertices (V, 3) float32 world units, faces (F, 3) int64,
    normals (V, 3) unit outward, colors (V, 3) uint8 or None."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    colors: np.ndarray | None = None


def grid_axis(center: float, radius: float, resolution: int) -> np.ndarray:
    """``resolution`` sample positions spanning [center - radius, center + radius]."""
    return np.linspace(center - radius, center + radius, resolution, dtype=np.float64)


@torch.no_grad()
def sample_density_grid(
    density_fn: DensityFn,
    center,
    radius: float,
    resolution: int,
    chunk: int = 65536,
    device: str | torch.device = "cpu",
    progress: bool = False,
) -> np.ndarray:
    """Density on a ``resolution``^3 grid over the cube ``center +- radius``.

    Returns (R, R, R) float32 indexed [i, j, k] <-> (x_i, y_j, z_k). Points are evaluated
    ``chunk`` at a time (one z-slab per call when possible) so memory stays bounded.
    """
    if resolution < 2:
        raise fail("--resolution", f"{resolution} is too small", "Use at least 2 (typically 128-512)")
    center = np.asarray(center, np.float64).reshape(3)
    xs, ys, zs = (grid_axis(center[a], radius, resolution) for a in range(3))
    grid = np.empty((resolution,) * 3, np.float32)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    plane = np.stack([X.ravel(), Y.ravel()], 1)  # (R*R, 2) for one z value
    slabs = max(1, chunk // plane.shape[0])
    it = range(0, resolution, slabs)
    if progress:
        from tqdm import tqdm

        # disable=None: no bar when the output is not a terminal (a log)
        it = tqdm(it, desc="density grid", unit="slab", total=(resolution + slabs - 1) // slabs, disable=None)
    for k0 in it:
        kz = zs[k0 : k0 + slabs]
        pts = np.concatenate([np.column_stack([plane, np.full(len(plane), z)]) for z in kz])
        out = []
        for s in range(0, len(pts), chunk):
            p = torch.as_tensor(pts[s : s + chunk], dtype=torch.float32, device=device)
            out.append(torch.as_tensor(density_fn(p)).float().reshape(-1).cpu())
        vals = torch.cat(out).numpy().reshape(len(kz), resolution, resolution)
        grid[:, :, k0 : k0 + len(kz)] = np.moveaxis(vals, 0, -1)
    return np.nan_to_num(grid, nan=0.0, posinf=float(np.finfo(np.float32).max), neginf=0.0)


def marching_cubes(grid: np.ndarray, center, radius: float, threshold: float) -> Mesh:
    """The ``threshold`` iso-surface of a density grid over the cube ``center +- radius``.

    The grid is padded with zero density so surfaces cut by the box are closed there.
    Raises NerfkitError when no surface crosses the threshold.
    """
    from skimage.measure import marching_cubes as sk_marching_cubes

    lo, hi = float(grid.min()), float(grid.max())
    if not lo < threshold < hi or threshold <= 0:
        raise fail(
            "--threshold",
            f"{threshold:g} does not cut the density field (it spans {lo:.3g} to {hi:.3g})",
            f"Pick a value between those (e.g. --threshold {0.5 * (max(lo, 0) + hi):.3g})",
        )
    res = grid.shape[0]
    step = 2.0 * radius / (res - 1)
    padded = np.pad(grid, 1, mode="constant", constant_values=0.0)
    # 'descent': density is higher inside, so triangles face outward.
    verts, faces, normals, _ = sk_marching_cubes(
        padded, level=threshold, spacing=(step,) * 3, gradient_direction="descent", allow_degenerate=False
    )
    origin = np.asarray(center, np.float64).reshape(3) - radius - step  # the pad adds one cell
    verts = verts + origin
    # Padding can put vertices just outside the box; crop them onto it.
    verts = np.clip(verts, np.asarray(center) - radius, np.asarray(center) + radius)
    n = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    if signed_volume(verts, faces) < 0:  # make the winding counter-clockwise seen from outside
        faces = faces[:, ::-1]
    return Mesh(verts.astype(np.float32), faces.astype(np.int64), n.astype(np.float32))


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Volume enclosed by a closed triangle mesh; positive when faces wind counter-clockwise
    seen from outside (outward face normals)."""
    v = vertices.astype(np.float64)[faces]  # (F, 3, 3)
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def cone_directions(normals: np.ndarray, n_dirs: int, half_angle_deg: float = 30.0) -> np.ndarray:
    """View directions (n_dirs, V, 3) looking at vertices from outside: the first is the
    inward normal ``-normal``, the rest are tilted by ``half_angle_deg`` around it."""
    d0 = -normals.astype(np.float64)
    if n_dirs <= 1:
        return d0[None]
    helper = np.where(np.abs(d0[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    a = np.cross(d0, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(d0, a)
    t = np.deg2rad(half_angle_deg)
    dirs = [d0]
    for phi in np.linspace(0, 2 * np.pi, n_dirs - 1, endpoint=False):
        dirs.append(np.cos(t) * d0 + np.sin(t) * (np.cos(phi) * a + np.sin(phi) * b))
    return np.stack(dirs)


@torch.no_grad()
def vertex_colors(
    density_fn: DensityFn,
    query_fn: QueryFn,
    vertices: np.ndarray,
    normals: np.ndarray,
    reach: float,
    n_dirs: int = 1,
    n_samples: int = 8,
    chunk: int = 65536,
    device: str | torch.device = "cpu",
    min_weight: float = 1e-4,
    progress: bool = False,
) -> np.ndarray:
    """(V, 3) uint8 colours: what a ray looking at each vertex along each of
    :func:`cone_directions` sees, averaged over them.

    Each ray is volume-rendered (:func:`~nerfkit.render.volrend.render_weights`,
    ``n_samples`` samples) from ``reach`` outside the vertex to ``2 * reach`` inside, and
    its colour is divided by its opacity; the colour is queried only at samples weighing
    at least ``min_weight``. A ray that meets no density, or ``reach`` 0, takes the
    field's colour at the vertex itself. ``reach`` is in the units ``density_fn``'s
    density is per. ``progress``: a progress bar over the chunks.
    """
    from tqdm import tqdm

    from .render.volrend import accumulate, regular_ray_indices, render_weights

    dirs = cone_directions(normals, n_dirs)
    t = torch.linspace(-reach, 2.0 * reach, n_samples, dtype=torch.float32, device=device)
    step = 3.0 * reach / max(n_samples - 1, 1)
    per = max(1, chunk // n_samples)
    total = np.zeros((len(vertices), 3), np.float64)
    bar = tqdm(
        total=len(dirs) * len(vertices), desc="vertex colours", unit="vertex", disable=None if progress else True
    )
    for d in dirs:
        for s in range(0, len(vertices), per):
            p = torch.as_tensor(vertices[s : s + per], dtype=torch.float32, device=device)
            v = torch.as_tensor(d[s : s + per], dtype=torch.float32, device=device)
            n = len(p)
            colour, acc = torch.zeros(n, 3, device=device), torch.zeros(n, 1, device=device)
            if reach > 0:
                pts = (p[:, None] + t[None, :, None] * v[:, None]).reshape(-1, 3)  # outside to inside
                ray = regular_ray_indices(n, n_samples, device)
                weights = render_weights(density_fn(pts).float(), step, ray)[0]
                used = (weights >= min_weight).nonzero()[:, 0]
                rgb = query_fn(pts[used], v[ray[used]])[1].float()
                colour = accumulate(weights[used, None] * rgb, ray[used], n)
                acc = accumulate(weights[used, None], ray[used], n)
            missed = (acc[:, 0] < min_weight).nonzero()[:, 0]
            colour = colour / acc.clamp_min(min_weight)
            if len(missed):  # the field's own colour where the vertex is
                colour[missed] = query_fn(p[missed], v[missed])[1].float()
            total[s : s + per] += colour.clamp(0, 1).cpu().numpy()
            bar.update(n)
    bar.close()
    return (np.clip(total / len(dirs), 0, 1) * 255 + 0.5).astype(np.uint8)


@dataclass
class ColourViews:
    """The cameras a mesh's vertices are coloured from: intrinsics K (N, 3, 3),
    camera-to-world c2w (N, 4, 4), and the image size they render at."""

    K: np.ndarray
    c2w: np.ndarray
    width: int
    height: int

    @classmethod
    def pick(cls, views, n: int, longest_side: int = COLOUR_VIEW_SIDE) -> ColourViews:
        """Up to ``n`` of ``views`` (a :class:`~nerfkit.data.scene.Views`), evenly spread over
        them, at a resolution whose longest side is at most ``longest_side`` (every k-th pixel)."""
        from .cameras import strided_camera

        idx = np.unique(np.linspace(0, len(views) - 1, min(n, len(views))).round().astype(int))
        stride = max(1, -(-max(views.width, views.height) // longest_side))
        Ks = [strided_camera(np.asarray(views.K[i], np.float64), views.width, views.height, stride) for i in idx]
        return cls(np.stack([k[0] for k in Ks]), np.asarray(views.c2w, np.float64)[idx], Ks[0][1], Ks[0][2])

    def __len__(self) -> int:
        return len(self.K)


def view_colors(
    render_fn: Callable,
    views: ColourViews,
    vertices: np.ndarray,
    normals: np.ndarray,
    tol: float,
    background=(0.0, 0.0, 0.0),
    progress: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Vertex colours from rendered views: each vertex takes the mean, over the views
    that see it, of the rendered colour of the pixel it falls in (the background removed
    again, as in :func:`depth_to_points`).

    A view sees a vertex when the vertex is in front of the camera and inside the image,
    its outward normal faces the camera, the render is more than 90% opaque there, and
    the vertex's distance from the camera is within ``tol`` of the rendered depth (a
    mesh's iso-surface lies a little in front of where a fuzzy surface's colour is).

    Args:
        render_fn: ``(K, c2w, width, height) -> (rgb (H, W, 3), depth (H, W), acc (H, W))``,
            ``depth`` along unit rays, divided by ``acc``.
        vertices, normals: (V, 3) world points and their unit outward normals.
    Returns:
        colours (V, 3) uint8 (0 where no view sees the vertex) and seen (V,) bool.
    """
    from tqdm import tqdm

    from .cameras import project_points

    v = np.asarray(vertices, np.float64)
    n = np.asarray(normals, np.float64)
    total, count = np.zeros((len(v), 3)), np.zeros(len(v))
    bg = np.asarray(background, np.float64).reshape(3)
    for i in tqdm(range(len(views)), desc="vertex colours", unit="view", disable=None if progress else True):
        rgb, depth, acc = (np.asarray(a) for a in render_fn(views.K[i], views.c2w[i], views.width, views.height))
        uv, z = project_points(views.K[i], views.c2w[i], v)
        idx = np.nonzero(
            (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < views.width) & (uv[:, 1] >= 0) & (uv[:, 1] < views.height)
        )[0]
        col, row = uv[idx, 0].astype(int), uv[idx, 1].astype(int)
        to_camera = views.c2w[i][:3, 3] - v[idx]
        dist = np.linalg.norm(to_camera, axis=1)
        a = acc[row, col]
        seen = ((n[idx] * to_camera).sum(1) > 0) & (a > 0.9) & (np.abs(dist - depth[row, col]) < tol)
        idx, row, col, a = idx[seen], row[seen], col[seen], a[seen, None]
        total[idx] += (rgb[row, col] - (1.0 - a) * bg) / a
        count[idx] += 1
    seen = count > 0
    colours = total / np.maximum(count, 1)[:, None]
    return (np.clip(colours, 0, 1) * 255 + 0.5).astype(np.uint8), seen


def extract_mesh(
    density_fn: DensityFn,
    center,
    radius: float,
    resolution: int = 256,
    threshold: float = SURFACE_DENSITY,
    query_fn: QueryFn | None = None,
    n_dirs: int = 1,
    chunk: int = 65536,
    device: str | torch.device = "cpu",
    progress: bool = False,
    reach: float | None = None,
    table=None,
    table_cut: float = 0.0,
    tags=None,
) -> Mesh:
    """Density grid -> (with a ``table`` plane: :func:`clear_around_object`, the paint up to
    ``table_cut`` above it, over the printed ``tags`` on it higher) -> marching cubes ->
    (optional) vertex colours, seen along rays that start ``reach`` outside the surface and
    end twice as far inside (None: two grid spacings; 0: the field's colour at the vertex).
    See the module docstring."""
    grid = sample_density_grid(density_fn, center, radius, resolution, chunk, device, progress)
    if table is not None:
        axes = [grid_axis(c, radius, resolution) for c in np.asarray(center, np.float64).reshape(3)]
        grid = clear_around_object(grid, axes, table, table_cut, threshold, tags)
    mesh = marching_cubes(grid, center, radius, threshold)
    if query_fn is not None:
        if reach is None:
            reach = 2.0 * 2.0 * radius / (resolution - 1)
        mesh.colors = vertex_colors(
            density_fn,
            query_fn,
            mesh.vertices,
            mesh.normals,
            reach,
            n_dirs,
            chunk=chunk,
            device=device,
            progress=progress,
        )
    return mesh


def to_trimesh(mesh: Mesh):
    """The mesh as a ``trimesh.Trimesh`` (vertex colours RGBA when present)."""
    import trimesh

    colors = None
    if mesh.colors is not None:
        colors = np.concatenate([mesh.colors, np.full((len(mesh.colors), 1), 255, np.uint8)], 1)
    return trimesh.Trimesh(
        vertices=mesh.vertices, faces=mesh.faces, vertex_normals=mesh.normals, vertex_colors=colors, process=False
    )


def write_mesh_ply(path: str | Path, mesh: Mesh) -> None:
    """Write a binary PLY (vertices, faces, normals, vertex colours), atomically."""
    with atomic_path(path) as tmp:
        to_trimesh(mesh).export(tmp, file_type="ply")


def depth_to_points(
    rgb: np.ndarray,
    depth: np.ndarray,
    acc: np.ndarray,
    K: np.ndarray,
    c2w: np.ndarray,
    acc_min: float = 0.5,
    background=(0.0, 0.0, 0.0),
    stride: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Back-project one rendered view into world points.

    Args:
        rgb: (H, W, 3) float rendered colour (composited on ``background``).
        depth: (H, W) depth along each unit ray (expected depth / acc).
        acc: (H, W) opacity; only pixels with ``acc > acc_min`` are kept.
        K, c2w: the view's intrinsics (3, 3) and camera-to-world (4, 4).
        stride: keep every ``stride``-th pixel in each direction.
    Returns:
        points (P, 3) float32 and colours (P, 3) uint8 (the background removed again:
        ``(rgb - (1 - acc) * background) / acc``).
    """
    H, W = depth.shape
    rows, cols = np.mgrid[0:H:stride, 0:W:stride]
    keep = acc[rows, cols] > acc_min
    r, c = rows[keep], cols[keep]
    uv1 = np.stack([c + 0.5, r + 0.5, np.ones_like(r, dtype=np.float64)], 1)
    d_cam = uv1 @ np.linalg.inv(K.astype(np.float64)).T
    d_world = d_cam @ c2w[:3, :3].astype(np.float64).T
    d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
    pts = c2w[:3, 3].astype(np.float64) + d_world * depth[r, c, None]
    a = acc[r, c, None]
    col = (rgb[r, c] - (1.0 - a) * np.asarray(background, np.float64)) / a
    return pts.astype(np.float32), (np.clip(col, 0, 1) * 255 + 0.5).astype(np.uint8)


def crop_to_box(points: np.ndarray, colors: np.ndarray, center, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Keep points inside the cube ``center +- radius``."""
    inside = np.all(np.abs(points - np.asarray(center, np.float32).reshape(1, 3)) <= radius, axis=1)
    return points[inside], colors[inside]


# --------------------------------------------------------------------------- trained models


def mesh_threshold(model, radius: float) -> float:
    """The default iso-level of ``model``'s mesh over a cube of half-size ``radius``:
    :func:`surface_threshold`, or for a forward-facing model in NDC (its density per NDC
    unit, its cube in world units) :data:`~nerfkit.scene_extent.SURFACE_DENSITY`."""
    return SURFACE_DENSITY if getattr(model, "ndc", None) is not None else surface_threshold(radius)


def mesh_region(model, center, radius: float, scale: float = 1.0) -> tuple[np.ndarray, float]:
    """The cube to mesh, ``(center (3,), half-size)``: around the model's density box when
    it has one (a capture's object: the grid's cells then fall on the object, not on the
    room around it), else the scene's cube ``center +- radius``; the half-size times ``scale``."""
    box = model.density_box()
    if box is not None:
        center, radius = (np.asarray(box[0], np.float64) + np.asarray(box[1], np.float64)) / 2, box_radius(box)
    return np.asarray(center, np.float64).reshape(3), radius * scale


def mesh_from_model(
    model,
    center,
    radius: float,
    scene_radius: float,
    resolution: int = 256,
    threshold: float | None = None,
    n_dirs: int = 1,
    chunk: int = 65536,
    device: str | torch.device = "cpu",
    progress: bool = True,
    table_cut: float = 0.0,
    views: ColourViews | None = None,
    render_fn: Callable | None = None,
    background=(0.0, 0.0, 0.0),
) -> Mesh:
    """A coloured mesh of a trained model (its ``density(points)`` and ``query(points,
    dirs)``) over the cube ``center +- radius``.

    Colours: with ``views`` and ``render_fn`` (:func:`view_colors`'s; a capture's object
    alone, composited on ``background``), each vertex takes the mean of the renders at the
    views that see it, within :data:`COLOUR_VIEW_TOL` of ``scene_radius`` of the rendered
    depth. A vertex no view sees, or every vertex without ``views``, is coloured along a
    ray from :data:`COLOUR_REACH` of ``scene_radius`` outside it (:func:`vertex_colors`,
    whatever the grid). A forward-facing model's density is per NDC unit, not per world
    unit, so its vertices take the field's colour where they are.

    A model with a table plane has its table paint (up to ``table_cut`` above it, in world
    units; ``export`` passes :func:`~nerfkit.surroundings.table_cut_height` of a fraction of
    the object's height) and the specks apart from its object cleared
    (:func:`clear_around_object`). ``threshold``: the surface's density (None:
    :func:`mesh_threshold`). ``chunk``: points evaluated at once."""
    if threshold is None:
        threshold = mesh_threshold(model, radius)
    ndc = getattr(model, "ndc", None) is not None
    mesh = extract_mesh(
        model.density,
        center,
        radius,
        resolution,
        threshold,
        chunk=chunk,
        device=device,
        progress=progress,
        table=surroundings.table_plane(model),
        table_cut=table_cut,
        tags=surroundings.table_tags(model),
    )
    colours, seen = np.zeros((len(mesh.vertices), 3), np.uint8), np.zeros(len(mesh.vertices), bool)
    if views is not None and render_fn is not None and not ndc:
        colours, seen = view_colors(
            render_fn, views, mesh.vertices, mesh.normals, COLOUR_VIEW_TOL * scene_radius, background, progress
        )
    if not seen.all():
        rest = np.nonzero(~seen)[0]
        colours[rest] = vertex_colors(
            model.density,
            model.query,
            mesh.vertices[rest],
            mesh.normals[rest],
            0.0 if ndc else COLOUR_REACH * scene_radius,
            n_dirs,
            chunk=chunk,
            device=device,
            progress=progress,
        )
    mesh.colors = colours
    return mesh


def points_from_views(
    render_fn: Callable, views, acc_min: float = 0.5, background=(0.0, 0.0, 0.0), stride: int = 1, progress: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """A coloured point cloud from rendered views.

    Args:
        render_fn: ``(K, c2w, width, height) -> (rgb (H, W, 3), depth (H, W), acc (H, W))``
            with ``depth`` the expected depth divided by acc (e.g. the renderer's output).
        views: a :class:`~nerfkit.data.scene.Views`.
    Returns: points (P, 3) float32 and colours (P, 3) uint8 of every view, concatenated.
    """
    it = range(len(views))
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="points", unit="view", disable=None)  # (none in a log)
    pts, cols = [], []
    for i in it:
        rgb, depth, acc = render_fn(views.K[i], views.c2w[i], views.width, views.height)
        p, c = depth_to_points(
            np.asarray(rgb), np.asarray(depth), np.asarray(acc), views.K[i], views.c2w[i], acc_min, background, stride
        )
        pts.append(p)
        cols.append(c)
    if not pts:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8)
    return np.concatenate(pts), np.concatenate(cols)
