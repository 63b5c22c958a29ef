"""Mesh and point-cloud export on analytic fields, read back with trimesh."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

trimesh = pytest.importorskip("trimesh")
pytest.importorskip("skimage")

from nerfkit import export as ex  # noqa: E402
from nerfkit import scene_extent, surroundings  # noqa: E402
from nerfkit.cameras import Rays, image_rays  # noqa: E402
from nerfkit.data.synthetic import sphere_color, sphere_scene  # noqa: E402
from nerfkit.errors import NerfkitError  # noqa: E402
from nerfkit.models.base import NerfModel, RenderOutput, SceneBounds  # noqa: E402
from nerfkit.surroundings import clearing  # noqa: E402

CENTER = np.array([0.1, -0.2, 0.3])
R = 0.7


def sphere_density(p: torch.Tensor) -> torch.Tensor:
    """Density 50 + 500 (R - |p - c|), clamped at 0: exactly 50 on the sphere of radius R."""
    d = torch.linalg.norm(p - torch.tensor(CENTER, dtype=p.dtype), dim=1)
    return torch.clamp(50.0 + 500.0 * (R - d), min=0.0)


def direction_field(p: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The sphere's density, with a colour that reveals the view direction: (d + 1) / 2."""
    return sphere_density(p), (d + 1) / 2


def test_sphere_mesh_is_closed_and_round(tmp_path):
    mesh = ex.extract_mesh(sphere_density, CENTER, 1.0, resolution=64, threshold=50.0, query_fn=direction_field)
    r = np.linalg.norm(mesh.vertices - CENTER, axis=1)
    assert abs(r.mean() - R) < 0.002 and r.std() < 0.002  # voxel = 2/63 = 0.032
    # normals point outward, colours saw the field from outside along -normal
    outward = (mesh.vertices - CENTER) / r[:, None]
    assert (np.sum(mesh.normals * outward, 1) > 0.99).all()
    np.testing.assert_allclose(mesh.colors / 255.0, (1 - outward) / 2, atol=0.02)
    path = tmp_path / "sphere.ply"
    ex.write_mesh_ply(path, mesh)
    back = trimesh.load(path, process=False)
    assert back.is_watertight and back.is_winding_consistent
    assert back.volume == pytest.approx(4 / 3 * np.pi * R**3, rel=0.01)  # positive: faces wind outward
    assert len(back.vertices) == len(mesh.vertices) and len(back.faces) == len(mesh.faces)
    np.testing.assert_array_equal(np.asarray(back.visual.vertex_colors)[:, :3], mesh.colors)


def test_the_default_surface_is_scale_free():
    """The same fuzzy ball in units ten times smaller (its density ten times higher): the
    default iso-level gives the same mesh ten times smaller, at the density that makes
    1/256 of the cube 7% opaque. A fixed level (25) meshes one of them only."""

    def ball(scale):
        def density(p):
            d = torch.linalg.norm(p / scale - torch.tensor(CENTER, dtype=p.dtype), dim=1)
            return 20.0 * torch.sigmoid((R - d) / 0.05) / scale  # a soft edge 5 cm deep, in metres

        return density

    level = ex.surface_threshold(1.0)
    assert 1 - np.exp(-level * 2.0 / scene_extent.MESH_OPACITY_CELLS) == pytest.approx(scene_extent.MESH_OPACITY)
    assert ex.surface_threshold(0.1) == pytest.approx(10 * level)
    big = ex.extract_mesh(ball(1.0), CENTER, 1.0, resolution=48, threshold=ex.surface_threshold(1.0))
    small = ex.extract_mesh(ball(0.1), 0.1 * CENTER, 0.1, resolution=48, threshold=ex.surface_threshold(0.1))
    assert len(big.faces) == len(small.faces) > 1000
    np.testing.assert_allclose(small.vertices, 0.1 * big.vertices, atol=1e-5)
    r = np.linalg.norm(big.vertices - CENTER, axis=1)
    assert r.mean() == pytest.approx(R - 0.05 * np.log(level / (20.0 - level)), abs=0.003)  # where the density is 9.3
    assert len(
        ex.extract_mesh(ball(0.1), 0.1 * CENTER, 0.1, resolution=16, threshold=scene_extent.SURFACE_DENSITY).faces
    )
    with pytest.raises(NerfkitError, match="does not cut the density"):  # 25: above the ball's 20
        ex.extract_mesh(ball(1.0), CENTER, 1.0, resolution=16, threshold=scene_extent.SURFACE_DENSITY)


def test_surface_cut_by_the_box_is_closed_there():
    """A sphere larger than the box: the mesh is cropped to the box and still watertight."""
    mesh = ex.extract_mesh(sphere_density, CENTER, 0.5, resolution=40, threshold=50.0)
    tm = ex.to_trimesh(mesh)
    assert tm.is_watertight
    assert np.abs(mesh.vertices - CENTER).max() <= 0.5 + 1e-6
    # the box corners (distance 0.866 > R) are cut off by the sphere: volume < box volume
    assert 0.85 < tm.volume < 1.0


def test_color_cone_average():
    dirs = ex.cone_directions(np.array([[0.0, 0.0, 1.0]]), 5, half_angle_deg=30)
    assert dirs.shape == (5, 1, 3)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0)
    np.testing.assert_allclose(dirs[0, 0], [0, 0, -1])
    np.testing.assert_allclose(dirs[1:, 0] @ [0, 0, -1], np.cos(np.radians(30)))
    # the centre plus 4 symmetric tilts: a direction-linear colour averages to mean z = -(1 + 4 cos 30) / 5
    c = ex.vertex_colors(
        sphere_density, direction_field, np.zeros((1, 3), np.float32), np.array([[0, 0, 1.0]]), 0.0, n_dirs=5
    )
    assert abs(c[0, 2] / 255 - (1 - (1 + 4 * np.cos(np.radians(30))) / 5) / 2) < 0.003
    assert abs(c[0, 0] / 255 - 0.5) < 0.003 and abs(c[0, 1] / 255 - 0.5) < 0.003


def test_vertex_colours_are_what_a_ray_sees_not_the_noise_at_the_surface_edge():
    """A learned field's colour is fitted where rays stop, not in the thin low-density
    edge where the iso-surface lies: there it is noise. A ray looking at the vertex sees
    the surface's colour."""

    def hard_ball(p):
        return torch.clamp(1e5 * (R - torch.linalg.norm(p - torch.tensor(CENTER, dtype=p.dtype), dim=1)), min=0.0)

    def field(p, d):
        inside = (R - torch.linalg.norm(p - torch.tensor(CENTER, dtype=p.dtype), dim=1)) > 1e-3
        noise = torch.frac(
            torch.sin(p @ torch.tensor([12.9898, 78.233, 37.719]))[:, None] * torch.tensor([43758.5, 22578.1, 19642.3])
        ).abs()  # a colour per point, any chunk
        return hard_ball(p), torch.where(inside[:, None], torch.tensor([1.0, 0.0, 0.0]), noise)

    mesh = ex.extract_mesh(hard_ball, CENTER, 1.0, resolution=48, threshold=50.0, query_fn=field)
    red = np.array([255, 0, 0])
    off = np.abs(mesh.colors.astype(int) - red).max(axis=1)
    # the few rays whose sample lands in the 1e-3 thick edge see some of its noise
    assert np.mean(off <= 3) > 0.8 and np.median(off) == 0 and np.quantile(off, 0.9) < 64
    at_vertex = ex.vertex_colors(hard_ball, field, mesh.vertices, mesh.normals, reach=0.0)  # the colour where it is
    assert np.mean(np.abs(at_vertex.astype(int) - red).max(axis=1) > 50) > 0.9
    # chunks of any size give the same colours
    again = ex.vertex_colors(hard_ball, field, mesh.vertices[:50], mesh.normals[:50], reach=0.1, chunk=60)
    np.testing.assert_array_equal(
        again, ex.vertex_colors(hard_ball, field, mesh.vertices[:50], mesh.normals[:50], reach=0.1)
    )


def test_grid_orientation_and_chunking():
    """grid[i, j, k] is the field at (x_i, y_j, z_k), whatever the chunk size."""

    def fn(p):
        return p[:, 0] + 10 * p[:, 1] + 100 * p[:, 2]

    g1 = ex.sample_density_grid(fn, [0, 0, 0], 1.0, 7, chunk=10)
    g2 = ex.sample_density_grid(fn, [0, 0, 0], 1.0, 7, chunk=1 << 16)
    ax = ex.grid_axis(0.0, 1.0, 7)
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    np.testing.assert_allclose(g1, X + 10 * Y + 100 * Z, atol=1e-4)
    np.testing.assert_array_equal(g1, g2)


def test_threshold_outside_the_field_is_a_clear_error():
    with pytest.raises(NerfkitError, match="--threshold"):
        ex.extract_mesh(sphere_density, CENTER, 1.0, resolution=16, threshold=1e6)
    with pytest.raises(NerfkitError, match="--threshold"):
        ex.extract_mesh(sphere_density, CENTER, 1.0, resolution=16, threshold=0.0)


# ----------------------------------------------------------------------------- a capture's table


def figure_on_table(p: torch.Tensor) -> torch.Tensor:
    """Density 100 inside: a post (radius 0.2 about the z axis) standing on the table z = 0
    up to z = 0.6 and going on under it to z = -0.3 (never seen there), and a flat square
    of paint 0.02 thick on the table at x, y in [0.5, 0.8]."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    post = (x * x + y * y < 0.04) & (z > -0.3) & (z < 0.6)
    paint = (x > 0.5) & (x < 0.8) & (y > 0.5) & (y < 0.8) & (z > -0.05) & (z < 0.02)
    return 100.0 * (post | paint).float()


def test_table_paint_is_cleared_and_what_stands_on_the_table_keeps_its_base():
    table = np.array([0.0, 0.0, 1.0, 0.0])
    kept = ex.extract_mesh(figure_on_table, [0, 0, 0], 1.0, resolution=101, threshold=50.0)
    assert (kept.vertices[:, 0] > 0.45).any() and kept.vertices[:, 2].min() < -0.25  # paint and the hidden part
    mesh = ex.extract_mesh(figure_on_table, [0, 0, 0], 1.0, resolution=101, threshold=50.0, table=table, table_cut=0.05)
    v = mesh.vertices
    assert not (v[:, 0] > 0.3).any()  # the paint is gone ...
    assert v[:, 2].min() > -0.02  # ... and so is everything under the table
    base = v[v[:, 2] < 0.04]  # the post keeps its foot on the table, at its full radius
    assert len(base) > 50
    np.testing.assert_allclose(np.hypot(base[:, 0], base[:, 1]).max(), 0.2, atol=0.03)
    assert ex.to_trimesh(mesh).is_watertight  # closed where it was cut
    # with no height, only what is under the table goes
    zs = ex.grid_axis(0.0, 1.0, 41)
    under = clearing.clear_around_object(
        ex.sample_density_grid(figure_on_table, [0, 0, 0], 1.0, 41), [zs] * 3, table, 0.0, 50.0
    )
    assert under[:, :, zs < 0].max() == 0 and under[:, :, zs >= 0].max() == 100


def test_paint_standing_up_off_the_table_apart_from_the_object_is_paint_a_second_object_is_not():
    """A flake of paint up to 0.12 above the table (its column rises out of the 0.05 slab) is
    cleared; the post keeps its base, and a thin stick 0.4 tall standing apart is kept,
    whichever way the grid's axis runs against the table's normal."""

    def scene(p):
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        flake = (x > 0.5) & (x < 0.7) & (y > 0.5) & (y < 0.7) & (z > -0.02) & (z < 0.12)
        stick = ((x + 0.6) ** 2 + (y + 0.6) ** 2 < 0.01) & (z > -0.02) & (z < 0.4)
        return figure_on_table(p) + 100.0 * (flake | stick).float()

    axis = ex.grid_axis(0.0, 1.0, 81)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    grid = ex.sample_density_grid(scene, [0, 0, 0], 1.0, 81)
    paint = clearing.table_paint(grid, [axis] * 3, np.array([0.0, 0.0, 1.0, 0.0]), 0.05, 50.0)
    # the same scene upside down (z -> -z), its table's normal toward -z
    flipped = clearing.table_paint(
        grid[:, :, ::-1].copy(), [axis, axis, -axis[::-1]], np.array([0.0, 0.0, -1.0, 0.0]), 0.05, 50.0
    )
    np.testing.assert_array_equal(flipped[:, :, ::-1], paint)
    kept = (grid > 50) & ~paint
    assert not kept[(x > 0.45) & (y > 0.45)].any()  # the flake and the flat paint: gone
    assert kept[(np.hypot(x, y) < 0.15) & (z >= 0) & (z < 0.03)].any()  # the post's foot: kept
    assert kept[(np.hypot(x + 0.6, y + 0.6) < 0.05) & (z > 0.1) & (z < 0.38)].all()  # the stick rises above 0.15: kept
    assert not kept[z < 0].any()


def test_paint_on_a_printed_tag_joined_to_the_object_by_haze_is_cleared_a_foot_on_a_tag_is_not():
    """A strip standing 0.12 up on a tag's edge, joined to the post by a low bridge of haze,
    is the object's piece for the slab's test; over the printed tag it is paint. A second
    post standing on a second tag (a diamond: turned 45 degrees) keeps its foot."""

    def scene(p):
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        strip = (x > 0.3) & (x < 0.7) & (y > 0.3) & (y < 0.36) & (z > -0.02) & (z < 0.12)
        along = (x - y).abs() < 0.06
        bridge = along & (x + y > 0.2) & (x + y < 0.7) & (z > -0.02) & (z < 0.09)
        post2 = ((x + 0.6) ** 2 + (y + 0.6) ** 2 < 0.01) & (z > -0.02) & (z < 0.5)
        return figure_on_table(p) * ((x < 0.45) | (y < 0.45)).float() + 100.0 * (strip | bridge | post2).float()

    square = np.array([[0.3, 0.3, 0.0], [0.7, 0.3, 0.0], [0.7, 0.7, 0.0], [0.3, 0.7, 0.0]])
    diamond = np.array([[-0.6, -0.85, 0.0], [-0.35, -0.6, 0.0], [-0.6, -0.35, 0.0], [-0.85, -0.6, 0.0]])
    axis = ex.grid_axis(0.0, 1.0, 81)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    grid = ex.sample_density_grid(scene, [0, 0, 0], 1.0, 81)
    table = np.array([0.0, 0.0, 1.0, 0.0])
    strip = (x > 0.32) & (x < 0.68) & (y > 0.31) & (y < 0.35) & (z > 0.06) & (z < 0.11)
    without = (grid > 50) & ~clearing.table_paint(grid, [axis] * 3, table, 0.05, 50.0)
    assert without[strip].all()  # joined to the post, it was kept
    kept = (grid > 50) & ~clearing.table_paint(grid, [axis] * 3, table, 0.05, 50.0, np.stack([square, diamond]))
    assert not kept[strip].any()
    assert kept[(np.hypot(x, y) < 0.15) & (z >= 0) & (z < 0.03)].any()  # the post's foot, beside the tag
    foot = kept & (np.hypot(x + 0.6, y + 0.6) < 0.12) & (z >= 0) & (z < 0.1)
    np.testing.assert_allclose(np.hypot(x[foot] + 0.6, y[foot] + 0.6).max(), 0.1, atol=0.03)  # at its full radius
    assert kept[(np.hypot(x + 0.6, y + 0.6) < 0.08) & (z > 0.2) & (z < 0.48)].all()


def test_the_mesh_covers_the_models_own_box_and_the_cut_is_a_fraction_of_its_height():
    from types import SimpleNamespace

    boxed = SimpleNamespace(
        density_box=lambda: (np.array([0.0, -1.0, -0.1]), np.array([0.2, 0.0, 0.5])),
        surroundings=SimpleNamespace(plane=np.array([0.0, 0.0, 1.0, 0.0])),
    )
    center, half = ex.mesh_region(boxed, np.zeros(3), 5.0, scale=1.5)
    np.testing.assert_allclose(center, [0.1, -0.5, 0.2])
    assert half == pytest.approx(0.75)  # the longest side, 1.0, over 2, times 1.5
    assert surroundings.table_cut_height(boxed, 0.05) == pytest.approx(0.025)  # the box's top is 0.5 above the table
    plain = SimpleNamespace(density_box=lambda: None, surroundings=None)
    center, half = ex.mesh_region(plain, np.ones(3), 5.0)
    np.testing.assert_allclose(center, 1.0)
    assert half == 5.0 and surroundings.table_cut_height(plain, 0.05) == 0.0


# ----------------------------------------------------------------------------- points


def sphere_hits(K, c2w, w, h):
    """Exact render of the unit sphere: rgb (H, W, 3) on black, depth along rays, acc in {0, 1}."""
    rays = image_rays(torch.from_numpy(K), torch.from_numpy(c2w).float(), w, h)
    o, d = rays.origins.double().numpy(), rays.directions.double().numpy()
    b = (o * d).sum(1)
    disc = b * b - ((o * o).sum(1) - 1.0)
    hit = disc > 0
    t = np.where(hit, -b - np.sqrt(np.where(hit, disc, 0)), 0.0)
    rgb = np.zeros((len(o), 3))
    rgb[hit] = sphere_color(o[hit] + t[hit, None] * d[hit])
    return rgb.reshape(h, w, 3), t.reshape(h, w), hit.reshape(h, w).astype(np.float64)


def test_points_from_expected_depth_lie_on_the_surface(tmp_path):
    views = sphere_scene(n_train=3, n_val=1, size=24).train
    pts, cols = ex.points_from_views(sphere_hits, views, progress=False)
    assert len(pts) > 3 * 100
    np.testing.assert_allclose(np.linalg.norm(pts, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(cols / 255.0, sphere_color(pts.astype(np.float64)), atol=0.01)
    path = tmp_path / "points.ply"
    ex.write_points_ply(path, pts, cols)
    back = trimesh.load(path)
    assert isinstance(back, trimesh.PointCloud) and len(back.vertices) == len(pts)
    np.testing.assert_array_equal(np.asarray(back.colors)[:, :3], cols)


def test_depth_to_points_keeps_opaque_pixels_and_unmixes_background():
    K = np.array([[10.0, 0, 2], [0, 10, 2], [0, 0, 1]])
    c2w = np.eye(4)
    acc = np.array([[0.2, 0.6], [0.9, 1.0]]).repeat(2, 0).repeat(2, 1)
    rgb = np.zeros((4, 4, 3))
    rgb[:] = 0.4 * acc[..., None] + (1 - acc[..., None]) * 1.0  # colour 0.4 over a white background
    depth = np.full((4, 4), 2.0)
    pts, cols = ex.depth_to_points(rgb, depth, acc, K, c2w, acc_min=0.5, background=(1, 1, 1))
    assert len(pts) == 12  # the 0.2 quarter is dropped
    np.testing.assert_allclose(cols, round(0.4 * 255), atol=1)
    np.testing.assert_allclose(np.linalg.norm(pts, axis=1), 2.0, atol=1e-6)  # depth along unit rays


def test_crop_to_box_keeps_the_cube_around_its_centre_with_each_points_colour():
    center = np.array([1.0, -2.0, 0.5])
    offsets = np.array(
        [
            [0.0, 0.0, 0.0],  # the centre: kept
            [0.9, 0.9, -0.9],  # the cube's corner, 1.56 from the centre (outside the ball): kept
            [1.1, 0.0, 0.0],  # past the +x face: dropped
            [0.0, -1.05, 0.0],  # past the -y face: dropped
            [-1.0, 2.0, -0.5],  # the origin, inside a cube around the origin: dropped
            [0.0, 0.0, -1.0],  # on the -z face (exact in float32): kept
            [0.5, 1.5, 0.2],  # one coordinate out: dropped
        ]
    )
    pts = (center + offsets).astype(np.float32)
    colors = np.array([[10 * i, 255 - i, 3 * i] for i in range(len(pts))], np.uint8)
    p, c = ex.crop_to_box(pts, colors, center.tolist(), 1.0)
    np.testing.assert_array_equal(p, pts[[0, 1, 5]])
    np.testing.assert_array_equal(c, colors[[0, 1, 5]])


def two_spheres_render(K, c2w, width, height):
    """Exact render of a red ball (radius 0.5 at x = -1) and a blue one (at x = +1): rgb
    (H, W, 3), depth along unit rays (H, W) and acc (H, W), on black."""
    rays = image_rays(torch.from_numpy(np.asarray(K)), torch.from_numpy(np.asarray(c2w)).float(), width, height)
    o, d = rays.origins.double().numpy(), rays.directions.double().numpy()
    depth, rgb = np.full(len(o), np.inf), np.zeros((len(o), 3))
    for centre, colour in (((-1.0, 0, 0), (1.0, 0, 0)), ((1.0, 0, 0), (0, 0, 1.0))):
        oc = o - np.asarray(centre)
        b = (oc * d).sum(1)
        disc = b * b - ((oc * oc).sum(1) - 0.25)
        t = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
        nearer = t < depth
        depth[nearer], rgb[nearer] = t[nearer], colour
    hit = np.isfinite(depth)
    shape = (height, width)
    return rgb.reshape(shape + (3,)), np.where(hit, depth, 0).reshape(shape), hit.astype(float).reshape(shape)


def looking_at(eye) -> np.ndarray:
    from nerfkit.cameras import look_at

    return look_at(np.asarray(eye, np.float64), np.zeros(3), np.array([0.0, 0.0, 1.0]))


def test_project_points_inverts_pixel_rays():
    from nerfkit.cameras import pixel_to_ray, project_points

    K = np.array([[50.0, 0.3, 31.5], [0, 55.0, 24.0], [0, 0, 1]])
    c2w = looking_at([1.0, -4.0, 2.0])
    uv = np.array([[0.5, 0.5], [10.25, 40.75], [63.9, 47.1]])
    o, d = pixel_to_ray(torch.from_numpy(K).float(), torch.from_numpy(c2w).float(), torch.from_numpy(uv).float())
    points = o.double().numpy() + np.array([1.0, 2.5, 7.0])[:, None] * d.double().numpy()
    back, z = project_points(K, c2w, points)
    np.testing.assert_allclose(back, uv, atol=1e-3)
    assert (z > 0).all()
    _, z_behind = project_points(K, c2w, 2 * c2w[:3, 3] - points)  # mirrored through the camera
    assert (z_behind < 0).all()


def test_view_colours_come_from_the_views_that_see_each_vertex():
    """Ball vertices take their own ball's colour: the red ball hides the blue one from the
    camera on the x axis (depth test), back faces take nothing from a view, and vertices
    no camera sees are reported unseen."""
    K = np.array([[120.0, 0, 64.0], [0, 120.0, 64.0], [0, 0, 1]])
    eyes = [[-6.0, 0, 0], [0.0, -6.0, 0.5], [0.0, 0.5, 6.0]]  # along the balls' axis, beside, above
    views = ex.ColourViews(np.stack([K] * 3), np.stack([looking_at(e) for e in eyes]), 128, 128)
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(4000, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    centres = np.where(np.arange(4000)[:, None] < 2000, [[-1.0, 0, 0]], [[1.0, 0, 0]])
    vertices = centres + 0.5 * normals
    colours, seen = ex.view_colors(two_spheres_render, views, vertices, normals, tol=0.05)
    red = np.arange(4000) < 2000
    np.testing.assert_array_equal(colours[seen & red], [[255, 0, 0]] * int((seen & red).sum()))
    np.testing.assert_array_equal(colours[seen & ~red], [[0, 0, 255]] * int((seen & ~red).sum()))
    assert 0.4 < seen.mean() < 0.9
    # facing down, away from the camera beside (-y) and from the one on the axis (-x): no view
    assert not seen[(normals[:, 2] < -0.3) & (normals[:, 1] > 0.3) & (normals[:, 0] > 0)].any()
    # from the axis alone: the red ball's near side, and nothing of the blue ball behind it
    axis = ex.ColourViews(views.K[:1], views.c2w[:1], 128, 128)
    _, seen = ex.view_colors(two_spheres_render, axis, vertices, normals, tol=0.05)
    assert not seen[~red].any()
    assert seen[red & (normals[:, 0] < -0.5)].mean() > 0.95 and not seen[red & (normals[:, 0] > 0)].any()


def test_colour_views_are_spread_and_at_most_the_longest_side():
    from nerfkit.data.scene import Views

    n = 10
    K = np.tile(np.array([[3000.0, 0, 2016.0], [0, 3000.0, 1512.0], [0, 0, 1]]), (n, 1, 1))
    c2w = np.tile(np.eye(4), (n, 1, 1))
    c2w[:, 0, 3] = np.arange(n)
    views = Views(c2w, K, 4032, 3024)
    picked = ex.ColourViews.pick(views, 4)
    assert len(picked) == 4 and picked.c2w[:, 0, 3].tolist() == [0, 3, 6, 9]
    assert (picked.width, picked.height) == (1008, 756)
    assert picked.K[0, 0, 0] == pytest.approx(750.0)
    assert len(ex.ColourViews.pick(views, 50)) == n


# ----------------------------------------------------------------------------- the command


class SphereModel(NerfModel):
    """An analytic 'trained model': the textured unit sphere as a density field."""

    def query(self, points, directions):
        r = torch.linalg.norm(points, dim=1)
        sigma = torch.clamp(50.0 + 500.0 * (1.0 - r), min=0.0)
        rgb = torch.from_numpy(sphere_color(points.double().numpy() / np.maximum(r.double().numpy(), 1e-9)[:, None]))
        return sigma, rgb.float()

    def render_rays(self, rays: Rays, background, perturb):
        o, d = rays.origins.double(), rays.directions.double()
        b = (o * d).sum(1)
        disc = b * b - ((o * o).sum(1) - 1.0)
        hit = disc > 0
        t = torch.where(hit, -b - torch.sqrt(torch.clamp(disc, min=0)), torch.zeros_like(b))
        p = (o + t[:, None] * d).numpy()
        rgb = torch.from_numpy(sphere_color(p)).float() * hit[:, None] + background * (~hit[:, None])
        return RenderOutput(rgb, (t * hit).float(), hit.float())


def open_sphere_run(tmp_path, monkeypatch, model=None, step: int = 7) -> SceneBounds:
    """A stand-in run in ``tmp_path`` on a saved sphere scene (4 training views, 16 px), whose
    model is ``model`` (a class taking the bounds; default :class:`SphereModel`), for commands
    that open a run; returns its bounds."""
    from types import SimpleNamespace

    from nerfkit.commands import _common
    from nerfkit.data.npz import save_npz

    save_npz(sphere_scene(n_train=4, n_val=1, size=16), tmp_path / "s.npz")
    bounds = SceneBounds(2.0, 6.0, np.zeros(3, np.float32), 1.3, np.array([0, 0, 1.0], np.float32))
    train = SimpleNamespace(data=str(tmp_path / "s.npz"), background="black")
    info = SimpleNamespace(bounds=bounds, run_dir=tmp_path, scene={}, train=train)
    opened = _common.OpenRun((model or SphereModel)(bounds), info, step, torch.device("cpu"), 8192, None)
    monkeypatch.setattr(_common, "open_run", lambda args: opened)
    return bounds


def test_export_command_writes_both_files(tmp_path, monkeypatch, capsys):
    from nerfkit.cli import main

    bounds = open_sphere_run(tmp_path, monkeypatch)
    rc = main(
        [
            "export",
            str(tmp_path),
            "--mesh",
            str(tmp_path / "m.ply"),
            "--points",
            str(tmp_path / "p.ply"),
            "--resolution",
            "48",
            "--threshold",
            "50",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    mesh = trimesh.load(tmp_path / "m.ply", process=False)
    assert mesh.is_watertight
    assert np.linalg.norm(mesh.vertices, axis=1).mean() == pytest.approx(1.0, abs=0.01)
    # coloured from the 4 training views (16 pixels wide) where they see the sphere, along the normal elsewhere
    unit = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    error = np.abs(mesh.visual.vertex_colors[:, :3] / 255.0 - sphere_color(unit)).max(1)
    assert np.median(error) < 0.01 and np.percentile(error, 90) < 0.1  # (the blue stripes' edges step)
    cloud = trimesh.load(tmp_path / "p.ply")
    assert len(cloud.vertices) > 100
    np.testing.assert_allclose(np.linalg.norm(cloud.vertices, axis=1), 1.0, atol=1e-4)
    out = capsys.readouterr().out
    assert "step 7" in out and "coloured from 4 training views" in out
    (tmp_path / "s.npz").rename(tmp_path / "moved.npz")  # the dataset gone: say so, and how to do without it
    assert main(["export", str(tmp_path), "--mesh", str(tmp_path / "m2.ply"), "--resolution", "16"]) == 2
    assert "--color-views 0" in capsys.readouterr().err and not (tmp_path / "m2.ply").exists()
    assert (
        main(
            [
                "export",
                str(tmp_path),
                "--mesh",
                str(tmp_path / "m2.ply"),
                "--resolution",
                "16",
                "--threshold",
                "50",
                "--color-views",
                "0",
            ]
        )
        == 0
    )
    assert "coloured along the normals" in capsys.readouterr().out
    assert main(["export", str(tmp_path)]) == 2  # nothing asked for
    assert main(["export", str(tmp_path), "--mesh", str(tmp_path / "m.obj")]) == 2
    assert SceneBounds.from_dict(json.loads(json.dumps(bounds.to_dict()))).to_dict() == bounds.to_dict()


def test_points_of_a_run_that_holds_no_surface_yet_are_an_error_not_an_empty_file(tmp_path, monkeypatch, capsys):
    """A run trained a few steps renders nothing opaque: no point passes --acc-min, and export
    says so (train longer, or lower --acc-min) instead of writing a PLY of 0 points."""
    from nerfkit.cli import main

    class Empty(SphereModel):
        def render_rays(self, rays: Rays, background, perturb):
            out = super().render_rays(rays, background, perturb)
            return RenderOutput(out.rgb * 0 + background, out.depth, out.acc * 0)

    open_sphere_run(tmp_path, monkeypatch, Empty, step=5)
    assert main(["export", str(tmp_path), "--points", str(tmp_path / "p.ply")]) == 2
    err = capsys.readouterr().err
    assert "at step 5 no pixel of the 4 views rendered is more than 0.5 opaque" in err and "--acc-min" in err
    assert not (tmp_path / "p.ply").exists()
    # asked for a mesh too, written before the points fail: neither is left, nor a temporary
    (tmp_path / "m.ply").write_bytes(b"an earlier mesh")
    mesh = ["--mesh", str(tmp_path / "m.ply"), "--resolution", "16", "--threshold", "50", "--color-views", "0"]
    assert main(["export", str(tmp_path), *mesh, "--points", str(tmp_path / "p.ply"), "--force"]) == 2
    assert "no pixel of the 4 views rendered" in capsys.readouterr().err  # (the points', after the mesh)
    assert (tmp_path / "m.ply").read_bytes() == b"an earlier mesh" and not (tmp_path / "p.ply").exists()
    assert not [p for p in tmp_path.iterdir() if ".tmp." in p.name]


def test_a_mesh_of_a_run_without_a_surface_says_to_train_longer(tmp_path, monkeypatch, capsys):
    """The automatic threshold cuts no density of a run that holds no surface: besides a threshold
    that would mesh the noise, the error says the run is young and how to train it on."""
    from nerfkit.cli import main

    class Faint(SphereModel):
        def query(self, points, directions):
            sigma, rgb = super().query(points, directions)
            return sigma * 1e-6, rgb

    open_sphere_run(tmp_path, monkeypatch, Faint, step=3)
    argv = ["export", str(tmp_path), "--mesh", str(tmp_path / "m.ply"), "--resolution", "16", "--color-views", "0"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert (
        "does not cut the density field" in err
        and f"train it longer (nerfkit train --resume {tmp_path} --minutes 3)" in err
    )
    assert main([*argv, "--threshold", "5"]) == 2
    assert "train it longer" not in capsys.readouterr().err  # a threshold the user chose: theirs to change
    assert not (tmp_path / "m.ply").exists()
