"""How well a capture's photos agree on its table (`nerfkit.capture.agreement`)."""

from __future__ import annotations

import numpy as np
import pytest

from nerfkit.capture import synthetic as S
from nerfkit.capture.agreement import (
    AGREEMENT_NOTE_DB,
    agreement_notes,
    consistency,
    measure_agreement,
    psnr_of,
    table_points,
)
from nerfkit.capture.camera import nerfkit_K
from nerfkit.data.scene import Views

SIZE = (320, 240)
K_CV = np.array([[270.0, 0.0, 161.3], [0.0, 270.0, 118.9], [0.0, 0.0, 1.0]])  # OpenCV: pixel centres at integers
TABLE = np.array([0.0, 0.0, 1.0, 0.0])
CENTER = np.array([0.0, 0.0, 0.03])
SPHERE = S.Sphere(np.array([0.0, 0.0, 0.03]), 0.03)
RADIUS = 0.08  # the square reaches 1.4 radii: 0.11 m around the object's foot


def photos(spheres=(), n: int = 6, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(n, H, W, 3) uint8 photos of a textured table with a tag sheet (and ``spheres``) from
    a ring of cameras, and their (n, 4, 4) poses."""
    decal, _ = S.tag_sheet([0, 1], 0.04, 2, 0.01)
    scene = S.SynthScene([decal], list(spheres), table=S.table_texture(seed))
    c2w = S.orbit_views(n, np.zeros(3), np.random.default_rng(seed), distance=(0.3, 0.36))
    rays = S.camera_rays(K_CV, np.zeros(5), *SIZE, supersample=2)
    return np.stack([S.render(scene, rays, p, 2) for p in c2w]), c2w


def views_of(images: np.ndarray, c2w: np.ndarray, K: np.ndarray | None = None) -> Views:
    K = nerfkit_K(K_CV) if K is None else K
    return Views(
        c2w.astype(np.float32),
        np.repeat(K[None], len(c2w), 0).astype(np.float32),
        SIZE[0],
        SIZE[1],
        images,
        [f"p{i}.png" for i in range(len(c2w))],
    )


@pytest.fixture(scope="module")
def table_only():
    return photos()


def test_photos_of_one_table_agree_and_a_pose_off_by_a_degree_does_not(table_only):
    images, c2w = table_only
    same = measure_agreement(views_of(images, c2w), CENTER, TABLE, RADIUS)
    assert same is not None and same.psnr > 30 and same.photos_per_point == 6
    # the pixel convention: the same cameras with the principal point a pixel off agree less
    shifted = nerfkit_K(K_CV) + np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 0]])
    assert measure_agreement(views_of(images, c2w, shifted), CENTER, TABLE, RADIUS).psnr < same.psnr - 2
    a = np.radians(1.0)  # a photo tilted by a degree: its view of the table shifts by 4.7 pixels
    tilt = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    tilted = c2w.copy()
    tilted[0, :3, :3] = c2w[0, :3, :3] @ tilt
    assert measure_agreement(views_of(images, tilted), CENTER, TABLE, RADIUS).psnr < same.psnr - 8


def test_exposure_changes_cost_what_their_gains_predict(table_only):
    images, c2w = table_only
    gains = np.array([0.6, 1.0, 0.7, 0.9, 0.65, 0.95])  # (none brighter: white paper would clip)
    exposed = np.clip(images * gains[:, None, None, None] + 0.5, 0, 255).astype(np.uint8)
    pts = table_points(CENTER, TABLE, 1.4 * RADIUS, 201)
    mean, count, _, seen = consistency(views_of(images, c2w), pts)
    good = count >= 3
    g_mean = (seen * gains[:, None]).sum(0) / np.maximum(count, 1)  # (m,) the gains' mean over the photos seeing it
    # photo i shows point p as mean_p * gain_i: it differs from the points' mean by mean_p * (gain_i - g_mean_p)
    squared = (mean[None] * (gains[:, None] - g_mean)[..., None]) ** 2  # (n, m, 3)
    want = psnr_of((squared.mean(-1) * seen)[:, good].sum() / seen[:, good].sum())
    got = measure_agreement(views_of(exposed, c2w), CENTER, TABLE, RADIUS)
    assert got.psnr == pytest.approx(want, abs=0.3)
    same = measure_agreement(views_of(images, c2w), CENTER, TABLE, RADIUS)
    assert got.psnr < same.psnr - 8
    # what the exposure costs, evening it out takes back (up to the gains' rounding to 8 bits)
    assert got.psnr_exposure_evened > same.psnr - 2
    note = agreement_notes(got.as_json())
    assert len(note) == 2 and "mostly the phone's exposure" in note[1]


def test_a_shadow_is_not_taken_for_the_exposure(table_only):
    images, c2w = table_only
    shaded = images.copy()
    h, w = shaded.shape[1:3]
    for i in (0, 3):  # two photos with a dark patch over the middle of the table
        shaded[i, h // 3 : 2 * h // 3, w // 4 : 3 * w // 4] //= 2
    got = measure_agreement(views_of(shaded, c2w), CENTER, TABLE, RADIUS)
    same = measure_agreement(views_of(images, c2w), CENTER, TABLE, RADIUS)
    # a gain per photo takes back little of what the shadows cost (the gains above: all of it)
    assert got.psnr < AGREEMENT_NOTE_DB and got.psnr_exposure_evened - got.psnr < 0.25 * (same.psnr - got.psnr)
    note = agreement_notes(got.as_json())
    assert len(note) == 2 and "not only from the phone's exposure" in note[1] and "shadow" in note[1]


def test_the_objects_box_keeps_what_it_hides_out_of_the_table():
    images, c2w = photos([SPHERE])
    views = views_of(images, c2w)
    box = (SPHERE.center - SPHERE.radius, SPHERE.center + SPHERE.radius)
    clear = measure_agreement(views, CENTER, TABLE, RADIUS, box)
    blind = measure_agreement(views, CENTER, TABLE, RADIUS)
    assert clear.psnr > 30 and clear.psnr > blind.psnr + 5  # the sphere's colours are not the table's
    assert clear.points < blind.points  # the points under the box are left out


def test_too_few_photos_or_none_seeing_the_table_give_no_figure(table_only):
    images, c2w = table_only
    assert measure_agreement(views_of(images[:2], c2w[:2]), CENTER, TABLE, RADIUS) is None
    far_off = CENTER + [5.0, 0.0, 0.0]  # a square no photo sees
    assert measure_agreement(views_of(images, c2w), far_off, TABLE, RADIUS) is None


def test_notes_give_advice_only_below_the_bar():
    high = agreement_notes({"psnr": AGREEMENT_NOTE_DB + 2, "psnr_exposure_evened": AGREEMENT_NOTE_DB + 5})
    assert len(high) == 1
    light = agreement_notes({"psnr": AGREEMENT_NOTE_DB - 2, "psnr_exposure_evened": AGREEMENT_NOTE_DB - 1.5})
    assert len(light) == 2 and f"{AGREEMENT_NOTE_DB - 2:.1f} dB" in light[0] and "shadow" in light[1]
    assert "AE/AF lock" not in light[1]  # evening the exposure out gains 0.5 dB: not worth a word
    both = agreement_notes({"psnr": AGREEMENT_NOTE_DB - 3, "psnr_exposure_evened": AGREEMENT_NOTE_DB - 1})
    assert "shadow" in both[1] and "AE/AF lock" in both[1]


def test_sample_bilinear_reads_a_plane_exactly_at_any_point_and_clamps_outside():
    """A plane f(u, v) = 0.01 u + 0.02 v (pixel centres at +0.5) is read back exactly between
    pixels, over more points than one cv2.remap call takes; outside, the border pixel's value."""
    from nerfkit.images import REMAP_CHUNK, sample_bilinear

    h, w = 40, 60
    v, u = np.mgrid[0:h, 0:w] + 0.5
    image = np.stack([0.01 * u + 0.02 * v, 1.0 - 0.01 * u], -1).astype(np.float32)
    rng = np.random.default_rng(0)
    uv = rng.uniform([0.5, 0.5], [w - 0.5, h - 0.5], (REMAP_CHUNK + 5000, 2))
    got = sample_bilinear(image, uv)
    assert got.shape == (len(uv), 2)
    # (OpenCV weighs the four pixels in steps of 1/32 px: 0.03 of a pixel's rise at most)
    np.testing.assert_allclose(got[:, 0], 0.01 * uv[:, 0] + 0.02 * uv[:, 1], atol=0.03 * 0.03)
    np.testing.assert_allclose(got[:, 1], 1.0 - 0.01 * uv[:, 0], atol=0.03 * 0.01)
    outside = sample_bilinear(image, np.array([[-5.0, 0.5], [w + 9.0, h - 0.5]]))
    np.testing.assert_allclose(outside, image[[0, h - 1], [0, w - 1]], atol=1e-6)
