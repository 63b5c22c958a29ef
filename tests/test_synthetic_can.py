"""The synthetic glossy can: where rays meet it, how they mirror, and that it changes colour with the view."""

import numpy as np
import pytest

from nerfkit.capture import synthetic as S

CAN = S.Cylinder(np.array([0.1, -0.05]), radius=0.03, height=0.12, label=S.can_label(0))


def test_a_ray_straight_down_meets_the_top_at_its_height():
    o = np.array([0.11, -0.05, 1.0])
    s, n, top = S.cylinder_hits(o, np.array([[0.0, 0.0, -2.0]]), CAN)
    assert s[0] == pytest.approx((1.0 - 0.12) / 2.0)
    assert top[0] and n[0] == pytest.approx([0.0, 0.0, 1.0])


def test_a_level_ray_meets_the_side_facing_it():
    o = np.array([-1.0, -0.05 + 0.01, 0.06])
    s, n, top = S.cylinder_hits(o, np.array([[1.0, 0.0, 0.0]]), CAN)
    x = 0.1 - np.sqrt(0.03**2 - 0.01**2)  # the nearer root of the circle at y offset 0.01
    assert s[0] == pytest.approx(x + 1.0)
    assert not top[0]
    assert n[0] == pytest.approx([(x - 0.1) / 0.03, 0.01 / 0.03, 0.0])
    assert np.linalg.norm(n[0]) == pytest.approx(1.0)


@pytest.mark.parametrize(
    "o, d",
    [
        ([-1.0, -0.05, 0.2], [1.0, 0.0, 0.0]),  # above the top
        ([-1.0, 0.5, 0.06], [1.0, 0.0, 0.0]),  # beside it
        ([0.1, -0.05, 1.0], [0.0, 0.0, 1.0]),  # away from it
        ([-1.0, -0.05, -0.05], [1.0, 0.0, 0.0]),  # under the table
    ],
)
def test_rays_that_miss_it_meet_it_nowhere(o, d):
    s, _, _ = S.cylinder_hits(np.array(o, float), np.array([d], float), CAN)
    assert np.isinf(s[0])


def test_the_nearer_of_side_and_top_wins():
    """A ray down across the rim: through the top when it enters there, else the side."""
    o = np.array([0.1 - 0.05, -0.05, 0.2])
    through_top = np.array([[0.05, 0.0, -0.1]])  # at z = 0.12 it is at x = 0.09: on the top
    s, n, top = S.cylinder_hits(o, through_top, CAN)
    assert top[0] and s[0] == pytest.approx(0.8)
    steep = np.array([[0.025, 0.0, -0.2]])  # at z = 0.12 at x = 0.06: outside; meets the side lower
    s, n, top = S.cylinder_hits(o, steep, CAN)
    assert not top[0]
    assert o[0] + s[0] * steep[0, 0] == pytest.approx(0.1 - 0.03)


def test_reflect_mirrors_about_the_normal():
    d = np.array([[1.0, 0.0, -1.0], [0.0, 3.0, 0.0]])
    n = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    r = S.reflect(d, n)
    assert r == pytest.approx(np.array([[1.0, 0.0, 1.0], [0.0, -3.0, 0.0]]) / np.array([[np.sqrt(2)], [3.0]]))


def test_the_can_changes_colour_with_the_view():
    """Its mirrored room: the same point of the label seen from two sides differs, while a
    matte label (gloss 0) shades the same from both (the light is fixed)."""
    p = np.array([0.1 + 0.03, -0.05, 0.113])  # on the side facing +x, in the plain red above the letters
    for gloss, differs in ((0.3, True), (0.0, False)):
        can = S.Cylinder(CAN.center, CAN.radius, CAN.height, CAN.label, gloss=gloss)
        scene = S.SynthScene([], cylinders=[can], table=np.full((4, 4, 3), 200, np.uint8))
        colours = []
        for side in (-1.0, 1.0):
            eye = p + np.array([0.3, side * 0.2, 0.1])
            c2w = S.look_at(eye, p, np.array([0.0, 0.0, 1.0]))
            rays = S.camera_rays(np.array([[50.0, 0, 4.5], [0, 50.0, 4.5], [0, 0, 1]]), np.zeros(5), 9, 9, 1)
            colours.append(S.render(scene, rays, c2w, 1)[4, 4].astype(float))
        assert (np.abs(colours[0] - colours[1]).max() > 5) == differs


def test_an_object_capture_wraps_the_label_it_is_given_around_its_can():
    label = np.zeros((8, 32, 3), np.uint8)
    label[:] = (10, 200, 10)  # green
    K = np.array([[14.0, 0, 8], [0, 14.0, 6], [0, 0, 1]])
    cap = S.make_object_capture(n=1, size=(16, 12), K=K, can=True, label=label)
    (can,) = cap.scene.cylinders
    assert can.label is label
    default = S.make_object_capture(n=1, size=(16, 12), K=K, can=True)
    assert np.array_equal(default.scene.cylinders[0].label, S.can_label(1))  # the seed's own label
