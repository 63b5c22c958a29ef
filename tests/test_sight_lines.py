"""Sparse points as sight lines: who saw each point is kept in the dataset, and training
makes the space in front of a point empty and a point on the object solid."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nerfkit.cameras import Rays
from nerfkit.data.npz import load_npz, save_npz
from nerfkit.data.scene import Scene, point_views
from nerfkit.data.synthetic import tabletop_scene
from nerfkit.errors import NerfkitError
from nerfkit.kernels import numba_kernels
from nerfkit.models.base import SceneBounds
from nerfkit.models.fast import FastConfig, FastNeRF
from nerfkit.render.volrend import sight_line_loss
from nerfkit.train.optim import build_optimizer
from nerfkit.train.sight_lines import SightLines, spread_lines

KERNELS = ["torch", pytest.param("numba", marks=pytest.mark.skipif(numba_kernels() is None, reason="no numba"))]


@pytest.fixture(scope="module")
def tabletop():
    return tabletop_scene(n_train=8, n_val=1, size=24)


def seen_sphere_points(scene: Scene, n: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points on the tabletop's sphere (radius 1, centre (0, 0, 1)) above z = 0.3 and on its
    table, with the train views that see each one: a sphere point faces the camera (the
    sphere is convex), a table point is not hidden by the sphere."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    sphere = v[v[:, 2] > -0.7][: n // 2] + np.array([0.0, 0.0, 1.0])
    table = np.c_[rng.uniform(-2.0, 2.0, (n // 2, 2)), np.zeros(n // 2)]
    table = table[np.hypot(table[:, 0], table[:, 1]) > 1.2]  # off the sphere's foot
    points = np.concatenate([sphere, table])
    rows = []
    for j, c2w in enumerate(scene.train.c2w.astype(np.float64)):
        eye = c2w[:3, 3]
        for i, p in enumerate(points):
            to_eye = (eye - p) / np.linalg.norm(eye - p)
            if i < len(sphere):  # facing the camera, not at a grazing angle
                visible = (p - np.array([0.0, 0.0, 1.0])) @ to_eye > 0.3
            else:  # the line from the eye to the table point passes the sphere
                oc = p - np.array([0.0, 0.0, 1.0])
                b = oc @ to_eye
                visible = b * b - (oc @ oc - 1.0) < 0 or b > 0
            if visible:
                rows.append((i, j))
    return points.astype(np.float32), np.array(rows, np.int32)


def test_the_loss_is_the_opacity_in_front_plus_the_opacity_missing_past_the_point():
    empty = torch.tensor([0.0, 0.5, 1.0, 0.0])
    stopped = torch.tensor([1.0, 0.25])
    assert float(sight_line_loss(empty, stopped)) == pytest.approx((1.5 + 0.75) / 4)
    assert float(sight_line_loss(torch.zeros(3), torch.ones(2))) == 0.0
    assert float(sight_line_loss(torch.ones(2), torch.zeros(0))) == 1.0


def test_only_the_train_photos_that_saw_a_point_are_kept():
    seen = [("a", "val_1"), ("b",), ("val_2",), ("c", "a", "b")]
    assert point_views(seen, ["a", "b", "c"]).tolist() == [[0, 0], [1, 1], [3, 2], [3, 0], [3, 1]]
    assert point_views(None, ["a"]) is None
    assert point_views([("x",)], ["a"]).shape == (0, 2)


def test_npz_round_trip_keeps_who_saw_each_point(tmp_path, tabletop):
    points, rows = seen_sphere_points(tabletop)
    scene = Scene(**{**tabletop.__dict__, "points": points, "point_views": rows})
    save_npz(scene, tmp_path / "s.npz")
    back = load_npz(tmp_path / "s.npz")
    np.testing.assert_array_equal(back.point_views, rows)
    assert back.point_views.dtype == np.int32


@pytest.mark.parametrize(
    "bad, why",
    [
        (np.array([[0, 99]]), "train views the dataset does not have"),
        (np.array([[10**6, 0]]), "points or train views the dataset does not have"),
        (np.array([[-1, 0]]), "does not have"),
        (np.array([[0.0, 1.0]]), "must be (k, 2) integers"),
        (np.array([0, 1, 2]), "must be (k, 2) integers"),
    ],
)
def test_bad_point_views_get_a_clear_error(tmp_path, tabletop, bad, why):
    points, rows = seen_sphere_points(tabletop)
    save_npz(Scene(**{**tabletop.__dict__, "points": points, "point_views": rows}), tmp_path / "s.npz")
    arrays = dict(np.load(tmp_path / "s.npz"))
    arrays["points_train_views"] = bad
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(NerfkitError) as e:
        load_npz(tmp_path / "bad.npz")
    assert "bad.npz" in str(e.value) and why in str(e.value)
    arrays.pop("points_xyz")
    arrays.pop("points_rgb")
    arrays["points_train_views"] = rows
    np.savez(tmp_path / "nopoints.npz", **arrays)
    with pytest.raises(NerfkitError, match="'points_xyz' is missing"):
        load_npz(tmp_path / "nopoints.npz")


def test_each_line_runs_from_its_camera_to_its_point(tabletop):
    points, rows = seen_sphere_points(tabletop)
    lines = SightLines.from_scene(Scene(**{**tabletop.__dict__, "points": points, "point_views": rows}))
    assert len(lines) == len(rows)
    eyes = tabletop.train.c2w[rows[:, 1], :3, 3]
    torch.testing.assert_close(lines.origins, torch.as_tensor(eyes))
    torch.testing.assert_close(lines.directions.norm(dim=1), torch.ones(len(rows)))
    ends = lines.origins + lines.directions * lines.distances[:, None]
    torch.testing.assert_close(ends, torch.as_tensor(points[rows[:, 0]]), atol=1e-5, rtol=0)
    assert torch.equal(lines.views, torch.as_tensor(rows[:, 1], dtype=torch.long))
    assert SightLines.from_scene(tabletop) is None  # no points: no lines


def test_spread_lines_aim_uniformly_over_a_disc_across_each_line_at_its_point():
    g = torch.Generator().manual_seed(3)
    n, radius = 20000, 0.05
    origins = torch.randn(n, 3, generator=g, dtype=torch.float64)
    directions = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=1)
    distances = 0.5 + torch.rand(n, generator=g, dtype=torch.float64)
    points = origins + directions * distances[:, None]
    turned, reach = spread_lines(origins, directions, distances, radius, torch.Generator().manual_seed(4))
    torch.testing.assert_close(turned.norm(dim=1), torch.ones(n, dtype=torch.float64))
    offset = origins + turned * reach[:, None] - points
    assert torch.all(offset.norm(dim=1) <= radius * (1 + 1e-9))  # within the disc
    assert torch.allclose((offset * directions).sum(1), torch.zeros(n, dtype=torch.float64), atol=1e-12)  # across
    # uniform over the disc: the share within r is (r / radius)^2; the sides have no favourite
    for r in (0.3, 0.6, 0.9):
        assert abs(float((offset.norm(dim=1) <= r * radius).double().mean()) - r * r) < 0.015
    assert float(offset.mean(0).norm()) < 0.03 * radius
    again, _ = spread_lines(origins, directions, distances, radius, torch.Generator().manual_seed(4))
    assert torch.equal(again, turned)  # the generator alone decides the spots
    same, length = spread_lines(origins, directions, distances, 0.0, torch.Generator())
    torch.testing.assert_close(same, directions)
    torch.testing.assert_close(length, distances)


def test_drawn_lines_spread_about_their_points_from_their_cameras(tabletop):
    points, rows = seen_sphere_points(tabletop)
    lines = SightLines.from_scene(Scene(**{**tabletop.__dict__, "points": points, "point_views": rows}))
    g = torch.Generator().manual_seed(0)
    state = g.get_state()
    rays, dist, views = lines.sample(500, g, spread=0.01)
    g.set_state(state)
    plain, plain_dist, plain_views = lines.sample(500, g)  # the same lines, aimed at their points
    assert torch.equal(views, plain_views) and torch.equal(rays.origins, plain.origins)
    aimed = plain.origins + plain.directions * plain_dist[:, None]
    spots = rays.origins + rays.directions * dist[:, None]
    apart = (spots - aimed).norm(dim=1)
    assert float(apart.max()) <= 0.01 + 1e-6 and float(apart.mean()) > 0.004  # beside the point, within reach


@pytest.mark.parametrize("kernels", KERNELS)
def test_the_opacity_between_two_distances_is_the_closed_form_in_uniform_density(tabletop, kernels):
    model = FastNeRF(FastConfig(resolutions="32", upsample_steps="", kernels=kernels), SceneBounds.from_scene(tabletop))
    sigma = 0.8  # per world unit
    with torch.no_grad():
        raw = np.log(np.expm1(sigma / model.field.density_scale))  # softplus^-1
        model.field.grid[1:, 0] = float(raw)
    lo, hi = model.field.geom.lo, model.field.geom.hi
    centre = (lo + hi) / 2
    o = (centre - torch.tensor([2.0, 0.0, 0.0])).repeat(3, 1)
    d = torch.tensor([1.0, 0.0, 0.0]).repeat(3, 1)
    t0 = torch.full((3,), float(lo[0] - o[0, 0]) + 0.01)  # just inside the box
    t1 = t0 + torch.tensor([0.1, 0.5, 1.0])
    assert float(t1.max()) < float(hi[0] - o[0, 0])
    with torch.no_grad():
        acc = model._opacity_between(o, d, t0, t1, torch.full((3,), 0.5))
    torch.testing.assert_close(acc, 1 - torch.exp(-sigma * (t1 - t0)), atol=0.02, rtol=0)


@pytest.mark.slow
@pytest.mark.parametrize("kernels", KERNELS)
def test_sight_lines_clear_a_fog_and_make_the_object_solid_but_not_the_table(tabletop, kernels):
    points, rows = seen_sphere_points(tabletop)
    scene = Scene(**{**tabletop.__dict__, "points": points, "point_views": rows})
    bounds = SceneBounds.from_scene(scene)
    model = FastNeRF(
        FastConfig(
            resolutions="32", upsample_steps="", table=True, points_weight=1.0, init_alpha=0.03, kernels=kernels
        ),
        bounds,
    )
    lines = SightLines.from_scene(scene)
    every = Rays(lines.origins, lines.directions), lines.distances  # in the order of ``rows``
    on_sphere = torch.as_tensor(points[rows[:, 0], 2] > 0.3)

    def opacities():
        with torch.no_grad():
            torch.manual_seed(0)
            return model.sight_opacities(every[0], every[1])

    empty0, stopped0, solid = opacities()
    assert solid[on_sphere].float().mean() > 0.9 and not solid[~on_sphere].any()  # the table's points are its own
    assert float(empty0.mean()) > 0.2 and float(stopped0.mean()) < 0.9  # a fog fills the box
    opt = build_optimizer(model, 0.3)
    g = torch.Generator().manual_seed(1)
    for _ in range(100):
        batch, distance, _ = lines.sample(512, g)
        model.sight_loss(batch, distance).backward()
        opt.step()
        opt.zero_grad(set_to_none=True)
    empty, stopped, _ = opacities()
    assert float(empty.mean()) < 0.03  # the space in front of every point is cleared
    assert float(stopped.mean()) > 0.97  # the sphere's points stop their lines


def test_sight_lines_take_no_part_without_their_weight_and_weigh_in_proportion_to_it(tabletop):
    points, rows = seen_sphere_points(tabletop)
    scene = Scene(**{**tabletop.__dict__, "points": points, "point_views": rows})
    lines = SightLines.from_scene(scene)
    batch, distance, _ = lines.sample(64, torch.Generator().manual_seed(0))
    off = FastNeRF(FastConfig(resolutions="16", upsample_steps="", points_weight=0.0), SceneBounds.from_scene(scene))
    assert off.sight_loss(batch, distance) is None
    on = FastNeRF(
        FastConfig(resolutions="16", upsample_steps="", points_weight=0.5, init_alpha=0.02),
        SceneBounds.from_scene(scene),
    )
    full = FastNeRF(
        FastConfig(resolutions="16", upsample_steps="", points_weight=1.0, init_alpha=0.02),
        SceneBounds.from_scene(scene),
    )
    torch.manual_seed(0)
    a = float(on.sight_loss(batch, distance).detach())
    torch.manual_seed(0)
    b = float(full.sight_loss(batch, distance).detach())
    assert a > 0 and b == pytest.approx(2 * a, rel=1e-5)


def test_a_capture_trains_with_its_sight_lines_and_resumes_their_draws(tmp_path, tabletop, monkeypatch):
    from nerfkit import presets
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    points, rows = seen_sphere_points(tabletop)
    scene = Scene(**{**tabletop.__dict__, "points": points, "point_views": rows})
    small = FastConfig(resolutions="16", upsample_steps="", room_shells=0, table_resolution=32)

    def trainer(name, resume=False, data=scene, **kw):
        base = TrainConfig(
            data="tabletop",
            out=str(tmp_path / name),
            steps=30,
            batch_rays=256,
            seed=0,
            eval_views=1,
            checkpoint_seconds=1e9,
            **kw,
        )
        c, m = presets.resolve(base, small, data).configs()
        return Trainer(data, presets.without_scene(c), m, resume=resume, quiet=True), m

    t, m = trainer("on")
    assert m.points_weight == 0.02 and len(t.sight) == len(rows)  # a capture's default
    assert trainer("off", capture="off")[0].sight is None  # not a capture: no weight
    assert trainer("nopoints", data=tabletop)[0].sight is None  # a dataset that records no points
    older = Scene(**{**tabletop.__dict__, "points": points})  # points, but not who saw them
    notes = []
    monkeypatch.setattr(Trainer, "log", lambda self, msg: notes.append(msg))
    assert trainer("older", data=older)[0].sight is None
    assert any("nerfkit dataset DATASET_DIR --force" in n for n in notes)
    t.run(stop_after=20)
    again, _ = trainer("on", resume=True)
    assert again.step == 20 and torch.equal(again.sight_generator.get_state(), t.sight_generator.get_state())


def test_a_line_is_held_empty_to_its_margin_before_its_point_and_stopped_within_its_spread_past_it(tabletop):
    """A line drawn beside its point may meet the surface deeper than the point (a curved
    object near its outline): it must stop by the margin plus the spread past its spot."""
    config = FastConfig(resolutions="64", upsample_steps="", points_weight=1.0)
    model = FastNeRF(config, SceneBounds.from_scene(tabletop))
    lo, hi = model.field.geom.lo, model.field.geom.hi
    centre = (lo + hi) / 2
    o = (centre - torch.tensor([5.0, 0.0, 0.0])).repeat(2, 1)  # outside the box, looking along +x
    d = torch.tensor([1.0, 0.0, 0.0]).repeat(2, 1)
    distance = torch.tensor([5.0, 5.2])  # about the box's centre
    ends = []

    def opacity_between(o, d, t0, t1, u):
        ends.append(t1.clone())
        return torch.zeros(len(o))

    model._opacity_between = opacity_between  # type: ignore[method-assign]
    model.sight_opacities(Rays(o, d), distance)
    margin, spread = model.sight_margin(), model.sight_spread()
    assert 0 < margin < spread < 1.0 < float(hi[0] - centre[0])  # (both ends inside the box)
    torch.testing.assert_close(ends[0], distance - margin)  # empty up to the margin before
    torch.testing.assert_close(ends[1], distance + margin + spread)  # stopped within the spread past
