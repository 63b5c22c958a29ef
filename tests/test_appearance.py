"""The colour of a new view from the training photos taken near it (models/appearance.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nerfkit.cameras import intrinsics_matrix, look_at
from nerfkit.models.appearance import (
    DirectionalColour,
    camera_directions,
    direction_weights,
    neighbour_spacing,
)
from nerfkit.models.base import NerfModel, RenderOutput, SceneBounds
from nerfkit.output.images import render_image


def ring(n: int, radius: float = 2.0, height: float = 0.0) -> np.ndarray:
    """(n, 4, 4) cameras evenly on a horizontal circle about the origin, looking at it."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    eyes = np.stack([radius * np.cos(a), radius * np.sin(a), np.full(n, height)], 1)
    return np.stack([look_at(e, np.zeros(3), np.array([0.0, 0.0, 1.0])) for e in eyes])


def photos(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return np.eye(3) + 0.1 * rng.normal(size=(n, 3, 3)), 0.05 * rng.normal(size=(n, 3))


def test_camera_directions_are_unit_vectors_from_the_centre():
    c2w = np.tile(np.eye(4), (3, 1, 1))
    c2w[:, :3, 3] = [[3, 0, 1], [1, 4, 1], [1, 0, -1]]
    d = camera_directions(c2w, np.array([1.0, 0.0, 1.0]))
    np.testing.assert_allclose(d, [[1, 0, 0], [0, 1, 0], [0, 0, -1]], atol=1e-12)


def test_the_neighbour_spacing_of_a_ring_is_the_angle_to_the_third_nearest():
    # 36 cameras 10 degrees apart: the nearest two at 10, the third at 20 degrees
    d = camera_directions(ring(36), np.zeros(3))
    assert neighbour_spacing(d) == pytest.approx(np.radians(20.0))
    assert neighbour_spacing(d, k=1) == pytest.approx(np.radians(10.0))
    assert neighbour_spacing(d[:1]) == 0.0


def test_weights_sum_to_one_pick_a_photo_on_its_direction_and_split_evenly_between_two():
    train = camera_directions(ring(12), np.zeros(3))  # 30 degrees apart
    on = direction_weights(train, train[4:5], np.radians(3.0))
    np.testing.assert_allclose(on[0], np.eye(12)[4], atol=1e-6)
    half = (train[0] + train[1]) / np.linalg.norm(train[0] + train[1])
    w = direction_weights(train, half[None], np.radians(10.0))[0]
    assert w[0] == pytest.approx(w[1]) and w[0] + w[1] > 0.98
    wide = direction_weights(train, train[:3], np.radians(1e4))
    np.testing.assert_allclose(wide.sum(1), 1.0)
    np.testing.assert_allclose(wide, 1 / 12, atol=1e-4)  # a wide kernel: the photos' average


def test_far_from_every_photo_the_nearest_weighs_most_without_underflow():
    train = camera_directions(ring(4), np.zeros(3))
    up = np.array([[0.05, 0.0, 1.0]]) / np.linalg.norm([0.05, 0.0, 1.0])  # ~87 degrees from all, nearest photo 0
    w = direction_weights(train, up, np.radians(2.0))[0]
    assert np.isfinite(w).all() and w.sum() == pytest.approx(1.0) and int(np.argmax(w)) == 0


def test_a_photos_own_pose_gets_its_correction_and_a_pose_between_two_their_mean():
    c2w = ring(8)
    M, b = photos(8)
    colour = DirectionalColour.of_photos(c2w, M, b, np.zeros(3))
    assert colour.width == pytest.approx(np.radians(45.0))  # 45 degrees apart: the third nearest at 90, halved
    narrow = DirectionalColour(colour.directions, M, b, colour.center, np.radians(2.0))
    Mi, bi = narrow.correction(c2w[3])
    np.testing.assert_allclose(Mi, M[3], atol=1e-9)
    np.testing.assert_allclose(bi, b[3], atol=1e-9)
    between = ring(16)[7]  # half-way between photos 3 and 4 of the 8
    Mh, bh = narrow.correction(between)
    np.testing.assert_allclose(Mh, (M[3] + M[4]) / 2, atol=1e-6)
    np.testing.assert_allclose(bh, (b[3] + b[4]) / 2, atol=1e-6)
    rgb = torch.rand(5, 3, dtype=torch.float64)
    torch.testing.assert_close(narrow.apply(rgb, c2w[3]), rgb @ torch.from_numpy(M[3]).T + torch.from_numpy(b[3]))


def test_the_payload_round_trips_and_a_malformed_one_is_refused():
    M, b = photos(5)
    colour = DirectionalColour.of_photos(ring(5), M, b, np.array([0.1, 0.2, 0.3]))
    back = DirectionalColour.from_payload(colour.payload())
    for name in ("directions", "matrices", "offsets", "center"):
        np.testing.assert_array_equal(getattr(back, name), getattr(colour, name))
    assert back.width == colour.width
    bad = colour.payload()
    bad["matrices"] = bad["matrices"][:, :2]
    for payload in (bad, {**colour.payload(), "width": 0.0}, {"width": 1.0}, [1, 2]):
        with pytest.raises(ValueError, match="appearance"):
            DirectionalColour.from_payload(payload)
    nan = colour.payload()
    nan["offsets"] = nan["offsets"].clone()
    nan["offsets"][0, 0] = float("nan")
    with pytest.raises(ValueError, match="non-finite"):
        DirectionalColour.from_payload(nan)


class Grey(NerfModel):
    """A model that renders every ray mid-grey."""

    def render_rays(self, rays, background, perturb):
        n = len(rays)
        return RenderOutput(torch.full((n, 3), 0.5), torch.ones(n), torch.ones(n))


def test_render_image_draws_each_view_in_the_colour_of_the_photos_near_it():
    model = Grey(SceneBounds(near=0.1, far=5.0, center=np.zeros(3), radius=1.0, up=np.array([0.0, 0.0, 1.0])))
    c2w = ring(4)
    M = np.stack([np.diag([1.2, 1.0, 0.8]), np.eye(3), np.diag([0.6, 0.6, 0.6]), np.eye(3)])
    b = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    K = intrinsics_matrix(8.0, 8.0, 4.0, 4.0)
    plain = render_image(model, K, c2w[0], 8, 8, torch.zeros(3))
    assert plain is not None and np.allclose(plain.rgb, 0.5)
    model.appearance = DirectionalColour(camera_directions(c2w, np.zeros(3)), M, b, np.zeros(3), np.radians(1.0))
    expected = {0: [0.6, 0.5, 0.4], 1: [0.6, 0.5, 0.5], 2: [0.3, 0.3, 0.3]}
    for i, rgb in expected.items():
        view = render_image(model, K, c2w[i], 8, 8, torch.zeros(3))
        assert view is not None
        np.testing.assert_allclose(view.rgb, np.broadcast_to(rgb, (8, 8, 3)), atol=1e-6)
