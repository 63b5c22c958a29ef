"""surroundings.table: the pixel footprint on a plane (analytic cases, a numerical Jacobian) and the table's texel."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from nerfkit.cameras import look_at
from nerfkit.surroundings.table import plane_footprint

GROUND = np.array([0.0, 0.0, 1.0, 0.0])  # z = 0, its front facing +z


def views(c2w, f=500.0, size=(64, 48)):
    w, h = size
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    return SimpleNamespace(c2w=np.asarray(c2w)[None], K=K[None], width=w, height=h)


def down_camera(height):
    """OpenCV axes (x right, y down, z forward) looking straight down from ``height``."""
    c2w = np.eye(4)
    c2w[:3, :3] = np.diag([1.0, -1.0, -1.0])
    c2w[2, 3] = height
    return c2w


def test_a_camera_straight_above_a_plane_sees_height_over_focal_length_in_every_pixel():
    # off the optical axis a ray goes farther and meets the plane more obliquely, and the
    # pixel's solid angle shrinks by cos^3: the three cancel exactly
    got = plane_footprint(views(down_camera(2.0), f=500.0), GROUND, np.zeros(3), radius=10.0, stride=1)
    assert got is not None and abs(got - 2.0 / 500.0) < 1e-12


def test_only_pixels_meeting_the_plane_within_the_radius_count_and_none_when_no_ray_meets_it():
    up = down_camera(2.0)
    up[:3, :3] = np.diag([1.0, 1.0, 1.0])  # looking up, away from the plane
    assert plane_footprint(views(up), GROUND, np.zeros(3), radius=10.0) is None
    # the frame covers the plane within 0.13 m of the camera's foot: nothing of it lies within 0.1 of x = 5
    assert plane_footprint(views(down_camera(2.0)), GROUND, np.array([5.0, 0.0, 0.0]), radius=0.1) is None


def test_an_oblique_view_matches_the_area_of_the_projected_pixel():
    c2w = look_at(np.array([0.6, -0.8, 0.5]), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    v = views(c2w, f=400.0, size=(40, 30))
    got = plane_footprint(v, GROUND, np.zeros(3), radius=5.0, stride=1)
    # each pixel's corners cast onto the plane: the area of that quadrilateral
    K_inv = np.linalg.inv(v.K[0])
    sides = []
    for row in range(v.height):
        for col in range(v.width):
            corners = []
            for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                d = c2w[:3, :3] @ (K_inv @ np.array([col + du, row + dv, 1.0]))
                t = -c2w[2, 3] / d[2]
                corners.append((c2w[:3, 3] + t * d)[:2])
            x, y = np.array(corners).T
            sides.append(np.sqrt(0.5 * abs(x @ np.roll(y, 1) - y @ np.roll(x, 1))))
    assert got is not None and abs(got - np.median(sides)) < 2e-3 * got


def test_a_texel_side_is_one_texel_of_the_table_texture_inside_its_disc():
    import torch

    from nerfkit.surroundings.table import TablePlane, texel_side

    table = TablePlane(GROUND, np.zeros(3), radius=0.2, resolution=64)
    step = texel_side(0.2, 64)
    points = torch.as_tensor(table.origin)[None] + torch.arange(4.0)[:, None] * step * table.axes[:, 0][None]
    uv = table.texture_coords(points)
    # texture coordinates span [-1, 1] over 64 texels: one texel is 2 / 64
    assert torch.allclose(uv[1:, 0] - uv[:-1, 0], torch.full((3,), 2.0 / 64), atol=1e-6)
    assert torch.allclose(uv[:, 1], torch.zeros(4), atol=1e-6)
