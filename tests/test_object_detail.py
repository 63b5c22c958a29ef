"""The detail a capture's photos show on its object, and the grid that a plain object starts from."""

from __future__ import annotations

import numpy as np
import pytest

from nerfkit import presets
from nerfkit.cameras import look_at, project_points
from nerfkit.capture import synthetic as S
from nerfkit.data.scene import Scene, Views
from nerfkit.models.fast import widened
from nerfkit.models.fast_config import FastConfig
from nerfkit.object_detail import (
    PLAIN_GRADIENT,
    ObjectDetail,
    Photos,
    box_outline,
    gradient_magnitude,
    object_detail,
    table_points,
)
from nerfkit.train.config import TrainConfig

SIZE = (192, 144)
K = np.array([[160.0, 0.0, 96.0], [0.0, 160.0, 72.0], [0.0, 0.0, 1.0]])
TABLE = np.array([0.0, 0.0, 1.0, 0.0], np.float32)
BOX = (np.array([-0.06, -0.06, -0.01], np.float32), np.array([0.06, 0.06, 0.15], np.float32))


def plain_label() -> np.ndarray:
    label = np.empty((64, 256, 3), np.uint8)
    label[:] = (200, 25, 35)
    return label


def checked_label(cell: int = 3) -> np.ndarray:
    rows, cols = np.indices((64, 256))
    checks = ((rows // cell + cols // cell) % 2)[..., None] > 0
    return np.where(checks, np.array([230, 200, 60]), np.array([40, 60, 160])).astype(np.uint8)


def can_views(label: np.ndarray, n: int = 10, seed: int = 0) -> Views:
    """Matte photos of a can wearing ``label`` on the mottled synthetic table, from around it."""
    can = S.Cylinder(np.zeros(2), 0.033, 0.12, label, gloss=0.0, top_gloss=0.0)
    scene = S.SynthScene([], cylinders=[can], table=S.table_texture(0))
    rng = np.random.default_rng(seed)
    poses = S.orbit_views(n, np.array([0.0, 0.0, 0.05]), rng, distance=(0.35, 0.4))
    rays = S.camera_rays(K, np.zeros(5), *SIZE, 1)
    images = np.stack([S.render(scene, rays, p, 1, noise=1.0, rng=rng) for p in poses])
    return Views(poses.astype(np.float32), np.repeat(K[None], n, 0).astype(np.float32), *SIZE, images)


@pytest.mark.parametrize("width", [256, 512, 1024])
def test_a_ramp_scores_its_slope_per_512th_of_the_width(width):
    slope = 0.25 / width  # a quarter of the grey scale across the photo
    ramp = np.arange(width, dtype=np.float32) * slope
    rgb = np.repeat(np.tile(ramp, (64, 1))[..., None], 3, -1)
    inner = gradient_magnitude(rgb)[16:-16, 16:-16]
    assert inner == pytest.approx(slope * width / 512, rel=1e-3)


def test_a_pixel_follows_its_ray_to_the_table_and_the_box_outline_holds_the_box():
    c2w = look_at(np.array([0.3, -0.2, 0.4]), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    on_table = np.array([[0.02, -0.03, 0.0], [-0.05, 0.04, 0.0]])
    uv, _ = project_points(K, c2w, on_table)
    pts, ahead = table_points(K, c2w, uv, TABLE)
    assert ahead.all() and pts == pytest.approx(on_table, abs=1e-9)
    outline = box_outline(K, c2w, BOX, *SIZE)
    centre, _ = project_points(K, c2w, np.array([[0.0, 0.0, 0.07]]))
    assert outline[int(centre[0, 1]), int(centre[0, 0])]
    assert not outline[0, 0] and 0.05 < outline.mean() < 0.9
    # a box behind the camera has no outline
    behind = (np.array([2.0, -2.0, 1.0]), np.array([2.2, -1.8, 1.2]))
    assert not box_outline(K, c2w, behind, *SIZE).any()


def test_a_plain_can_is_plain_and_a_finely_checked_one_is_not():
    plain = object_detail(can_views(plain_label()), TABLE, BOX)
    checked = object_detail(can_views(checked_label()), TABLE, BOX)
    assert plain is not None and checked is not None
    assert plain.plain and not checked.plain
    assert plain.on_object < PLAIN_GRADIENT < checked.on_object
    # the same table under both, and the can the same share of the box's outline
    assert plain.on_table == pytest.approx(checked.on_table, rel=0.3)
    assert plain.object_share == pytest.approx(checked.object_share, abs=0.05)
    assert 0.1 < plain.object_share < 0.6


def test_plain_needs_both_a_low_gradient_and_no_more_than_the_tables():
    assert ObjectDetail(0.002, 0.002, 0.2).plain
    assert not ObjectDetail(0.003, 0.001, 0.2).plain  # three times the table's detail
    assert not ObjectDetail(0.006, 0.006, 0.2).plain  # a busy table does not make an object plain
    assert "0.0020 on the object" in ObjectDetail(0.002, 0.0019, 0.2).describe()


def test_too_few_photos_or_a_box_out_of_sight_give_no_figure():
    views = can_views(plain_label(), n=4)
    assert object_detail(views.subset(np.arange(2)), TABLE, BOX) is None
    far = (np.array([5.0, 5.0, 0.0], np.float32), np.array([5.1, 5.1, 0.1], np.float32))
    assert object_detail(views, TABLE, far) is None


def capture_scene(label: np.ndarray) -> Scene:
    """A capture of the can with sparse points on its label (enough for an object box)."""
    train = can_views(label, n=12)
    angle = np.random.default_rng(1).uniform(0, 2 * np.pi, 60)
    height = np.random.default_rng(2).uniform(0.01, 0.11, 60)
    points = np.stack([0.033 * np.cos(angle), 0.033 * np.sin(angle), height], 1).astype(np.float32)
    return Scene(
        train,
        Views.empty(*SIZE),
        Views.empty(*SIZE),
        near=0.1,
        far=1.0,
        center=np.array([0.0, 0.0, 0.05], np.float32),
        capture=True,
        table=TABLE,
        points=points,
    )


def test_a_plain_captured_object_widens_its_box_unless_told():
    plain, checked = capture_scene(plain_label()), capture_scene(checked_label())
    train = TrainConfig(model="fast")
    resolved = presets.resolve(train, FastConfig(), plain, user_set=set())
    assert resolved.model.object_box and resolved.model.object_box_margin == presets.PLAIN_BOX_MARGIN
    assert len(resolved.notes) == 1 and "widened by 0.65" in resolved.notes[0]
    for told in ({"object_box_margin"}, {"object_box"}):
        kept = presets.resolve(train, FastConfig(), plain, user_set=told)
        assert kept.model.object_box_margin == 0.0 and kept.notes == ()
    textured = presets.resolve(train, FastConfig(), checked, user_set=set())
    assert textured.model.object_box_margin == 0.0 and textured.notes == ()


def test_the_widened_box_grows_by_its_size_on_each_side_within_the_sphere():
    box = (np.array([0.0, 0.0, 0.0]), np.array([0.1, 0.2, 0.4]))
    lo, hi = widened(box, 0.5, np.zeros(3), 1.0)
    assert lo == pytest.approx([-0.05, -0.1, -0.2]) and hi == pytest.approx([0.15, 0.3, 0.6])
    lo, hi = widened(box, 0.5, np.zeros(3), 0.5)  # the sphere's box cuts the top
    assert hi[2] == pytest.approx(0.5) and lo[2] == pytest.approx(-0.2)
    lo, hi = widened(box, 0.0, np.zeros(3), 1.0)
    assert lo == pytest.approx(box[0]) and hi == pytest.approx(box[1])


def test_large_photos_are_looked_at_512_wide_with_the_same_verdict():
    small = can_views(checked_label(cell=6), n=8)
    big = Views(
        small.c2w,
        small.K * np.array([4.0, 4.0, 1.0])[:, None],
        4 * small.width,
        4 * small.height,
        np.stack([np.kron(im, np.ones((4, 4, 1), np.uint8)) for im in small.images]),
    )
    photos = Photos(big)
    assert (photos.width, photos.height) == (512, 384) and photos.rgb(0).shape == (384, 512, 3)
    # the same world point lands on the same place of the photo, in its own pixels
    point = np.array([[0.01, 0.02, 0.05]])
    uv_big, _ = project_points(big.K[0], big.c2w[0], point)
    uv_seen, _ = project_points(photos.K[0], photos.c2w[0], point)
    assert uv_seen == pytest.approx(uv_big * 512 / big.width)
    a, b = object_detail(small, TABLE, BOX), object_detail(big, TABLE, BOX)
    assert a is not None and b is not None and a.plain == b.plain is False
    assert b.on_object == pytest.approx(a.on_object, rel=0.5)
