"""The table plane found in sparse SfM points (nerfkit.ground)."""

import numpy as np
import pytest

from nerfkit.ground import find_ground_plane, ground_similarity


def _rot_x(deg):
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def _scene(rng, tilt_deg=0.0, n_table=400, n_object=300, n_wall=0, noise=0.002):
    """A table (z = 0, radius 0.5), an object on it, an optional wall at x = 0.6, cameras
    on a ring 0.4 above the table, all turned by ``tilt_deg`` about x. Returns
    (points, cameras, center, R)."""
    r = 0.5 * np.sqrt(rng.random(n_table))
    a = rng.random(n_table) * 2 * np.pi
    table = np.stack([r * np.cos(a), r * np.sin(a), rng.normal(0, noise, n_table)], 1)
    obj = rng.normal([0, 0, 0.1], [0.04, 0.04, 0.05], (n_object, 3))
    obj[:, 2] = np.abs(obj[:, 2]) + 0.01
    wall = np.stack([np.full(n_wall, 0.6), rng.uniform(-0.5, 0.5, n_wall), rng.uniform(0, 0.8, n_wall)], 1)
    az = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    cams = np.stack([0.5 * np.cos(az), 0.5 * np.sin(az), np.full(24, 0.4)], 1)
    R = _rot_x(tilt_deg)
    pts = np.concatenate([table, obj, wall]) @ R.T
    return pts, cams @ R.T, np.array([0, 0, 0.05]) @ R.T, R


def test_finds_a_tilted_table_among_object_points():
    rng = np.random.default_rng(0)
    pts, cams, center, R = _scene(rng, tilt_deg=12.0)
    plane, why = find_ground_plane(pts, cams, center, up=np.array([0, 0, 1.0]))
    assert plane is not None, why
    true_n = R @ np.array([0, 0, 1.0])
    assert np.degrees(np.arccos(plane.normal @ true_n)) < 0.5
    assert plane.tilt_deg == pytest.approx(12.0, abs=0.5)
    assert abs(plane.offset) < 0.002  # the true plane passes through the origin
    assert 380 <= plane.inliers <= 400 + 20  # the table's points (and maybe a few object feet)
    np.testing.assert_allclose(plane.height(cams), 0.4, atol=0.005)


def test_a_slanted_plane_is_not_the_table():
    """A plane tilted 30 degrees from the cameras' up (a slope of the object, a roof) is
    rejected even with more points than the table; a level table with fewer wins."""
    rng = np.random.default_rng(4)
    pts, cams, center, _ = _scene(rng, n_table=150, n_object=50)
    u, v = rng.uniform(-0.3, 0.3, (2, 400))
    slope = np.stack([u, v, 0.05 + np.tan(np.radians(30)) * u], 1)  # through the look-at point
    plane, why = find_ground_plane(np.concatenate([pts, slope]), cams, center, up=np.array([0, 0, 1.0]))
    assert plane is not None, why
    assert plane.tilt_deg < 0.5 and abs(plane.offset) < 0.003


def test_a_wall_with_more_points_is_not_the_table():
    rng = np.random.default_rng(1)
    pts, cams, center, _ = _scene(rng, n_table=200, n_object=100, n_wall=600)
    plane, why = find_ground_plane(pts, cams, center, up=np.array([0, 0, 1.0]))
    assert plane is not None, why
    assert plane.tilt_deg < 0.5 and plane.inliers < 260


def test_no_plane_in_a_cloud_and_none_above_the_cameras():
    rng = np.random.default_rng(2)
    cams = np.stack([np.cos(np.arange(12)), np.sin(np.arange(12)), np.full(12, 0.5)], 1)
    cloud = rng.normal(0, 1.0, (3000, 3))
    cloud = 0.8 * cloud / np.linalg.norm(cloud, axis=1, keepdims=True) * rng.random((3000, 1)) ** (1 / 3)  # a ball
    plane, why = find_ground_plane(cloud, cams, np.zeros(3), up=np.array([0, 0, 1.0]))
    assert plane is None and "holds" in why
    ceiling = np.stack([rng.uniform(-1, 1, 300), rng.uniform(-1, 1, 300), np.full(300, 1.0)], 1)
    plane, why = find_ground_plane(ceiling, cams, np.zeros(3), up=np.array([0, 0, 1.0]))
    assert plane is None and "cameras above" in why
    floor = ceiling - [0, 0, 2.0]  # 1 below the look-at point, cameras ~1.1 away: not what the object stands on
    plane, why = find_ground_plane(floor, cams, np.zeros(3), up=np.array([0, 0, 1.0]))
    assert plane is None and "under the point" in why
    found = find_ground_plane(floor, cams, np.zeros(3), up=np.array([0, 0, 1.0]), max_drop=1.0)[0]
    np.testing.assert_allclose(found.normal, [0, 0, 1], atol=1e-6)  # the plane z = -1: n.x + d = 0
    assert found.offset == pytest.approx(1.0, abs=1e-6)
    plane, why = find_ground_plane(cloud[:10], cams, np.zeros(3), up=np.array([0, 0, 1.0]))
    assert plane is None and "only 10" in why


def test_ground_similarity_levels_the_plane_under_the_centre():
    rng = np.random.default_rng(3)
    pts, cams, center, _ = _scene(rng, tilt_deg=-15.0)
    shift = np.array([0.3, -0.2, 0.7])
    plane, _ = find_ground_plane(pts + shift, cams + shift, center + shift, up=np.array([0, 0, 1.0]))
    R, t = ground_similarity(plane, center + shift)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R @ plane.normal, [0, 0, 1], atol=1e-12)
    moved = (pts[:400] + shift) @ R.T + t  # the table's points
    assert np.abs(moved[:, 2]).max() < 0.01
    foot = R @ (center + shift) + t
    np.testing.assert_allclose(foot[:2], 0, atol=1e-9)
    assert foot[2] == pytest.approx(0.05, abs=0.003)  # the centre stays 5 cm above the table
    np.testing.assert_allclose(((cams + shift) @ R.T + t)[:, 2], 0.4, atol=0.005)


def _with_floor(rng, drop=0.45, n_floor=600, tilt_deg=0.0, noise=0.01):
    """The table scene (tilted by ``tilt_deg``) over a floor ``drop`` below it, which
    stretches 2 m out in every direction (a carpet: rougher than the table)."""
    pts, cams, center, R = _scene(rng, tilt_deg=tilt_deg, n_wall=100)
    xy = rng.uniform(-2.0, 2.0, (n_floor, 2))
    floor = np.concatenate([xy, rng.normal(-drop, noise, (n_floor, 1))], 1) @ R.T
    return np.concatenate([pts, floor]), cams, center, R


def test_finds_the_floor_under_a_table_and_none_without_one():
    from nerfkit.ground import find_floor

    rng = np.random.default_rng(3)
    pts, cams, center, R = _with_floor(rng, tilt_deg=8.0)
    table = np.array([*(R @ [0, 0, 1.0]), 0.0])
    floor = find_floor(pts, table, cams, center)
    assert floor is not None
    assert np.degrees(np.arccos(floor.normal @ table[:3])) < 1.0
    foot = center - (center @ table[:3]) * table[:3]
    assert floor.height(foot) == pytest.approx(0.45, abs=0.01)  # the table's foot is 0.45 above it
    assert floor.inliers >= 0.9 * 600
    points_only_on_table, *_ = _scene(rng, n_wall=100)
    assert find_floor(points_only_on_table, np.array([0, 0, 1.0, 0]), cams, center) is None


def test_a_slope_or_a_shelf_just_under_the_table_is_not_the_floor():
    from nerfkit.ground import find_floor

    rng = np.random.default_rng(4)
    pts, cams, center, _ = _scene(rng, n_wall=100)
    table = np.array([0, 0, 1.0, 0])
    xy = rng.uniform(-2.0, 2.0, (600, 2))
    slope = np.concatenate([xy, (-0.6 + 0.4 * xy[:, :1])], 1)  # 22 degrees off the table's plane
    assert find_floor(np.concatenate([pts, slope]), table, cams, center) is None
    shelf = np.concatenate([xy, np.full((600, 1), -0.03)], 1)  # 3 cm under: the table's own thickness
    assert find_floor(np.concatenate([pts, shelf]), table, cams, center) is None


def test_a_scene_finds_its_floor_once(monkeypatch):
    """``Scene.floor`` is find_floor under the training cameras, searched once however often
    it is asked (the model's bounds and the cover prior's default both ask)."""
    import nerfkit.data.scene as scene_module
    from nerfkit.data.scene import Scene, Views

    rng = np.random.default_rng(5)
    pts, cams, center, _ = _with_floor(rng)
    c2w = np.repeat(np.eye(4, dtype=np.float32)[None], len(cams), 0)
    c2w[:, :3, 3] = cams
    views = Views(c2w, np.repeat(np.eye(3, dtype=np.float32)[None], len(cams), 0), 8, 8)
    table = np.array([0, 0, 1.0, 0], np.float32)
    scene = Scene(
        views, Views.empty(8, 8), Views.empty(8, 8), 0.1, 3.0, center=center, table=table, points=pts.astype(np.float32)
    )
    calls = []
    find_floor = scene_module.find_floor
    monkeypatch.setattr(scene_module, "find_floor", lambda *a, **k: calls.append(1) or find_floor(*a, **k))
    floor = scene.floor()
    assert floor is not None and floor.height(center - center[2] * table[:3]) == pytest.approx(0.45, abs=0.01)
    assert scene.floor() is floor and len(calls) == 1
    assert Scene(views, views, views, 0.1, 3.0, center=center, table=table).floor() is None  # no points
    assert Scene(views, views, views, 0.1, 3.0, center=center, points=pts).floor() is None  # no table
    assert len(calls) == 1
