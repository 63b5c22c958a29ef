"""The robust per-pixel weighting against transients (``--transient-quantile``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from conftest import train_loop
from nerfkit.data.scene import Scene
from nerfkit.data.synthetic import sphere_scene
from nerfkit.losses import robust
from nerfkit.models.base import SceneBounds, rgb_loss
from nerfkit.models.fast import FastConfig, FastNeRF
from nerfkit.output.images import render_image


def test_outlier_candidates_rank_above_the_quantile():
    residual = torch.arange(100.0)[torch.randperm(100)]
    cand = robust.outlier_candidates(residual, 0.8)
    # torch.quantile interpolates: the 0.8 quantile of 0..99 is 79.2, so 80..99 are candidates
    assert int(cand.sum()) == 20 and bool((residual[cand] >= 80).all())
    assert int(robust.outlier_candidates(residual, 0.5).sum()) == 50
    assert not robust.outlier_candidates(residual, 1.0).any()
    assert robust.outlier_candidates(torch.zeros(0), 0.8).shape == (0,)
    # equal residuals: nobody ranks above the others
    assert not robust.outlier_candidates(torch.ones(10), 0.8).any()


def test_trimmed_weights_need_an_outlier_in_a_mostly_outlier_cell():
    candidate = torch.tensor([True, True, False, False, True])
    share = torch.tensor([0.2, 0.9, 0.2, 0.9, 0.5])
    # a candidate in a cell of mostly outliers (share <= 0.5) is trimmed; a lone candidate among
    # inliers and an inlier among outliers keep their weight
    assert robust.trimmed_weights(candidate, share, trimming=True).tolist() == [0.0, 1.0, 1.0, 1.0, 0.0]
    # warm-up: nothing is trimmed
    assert robust.trimmed_weights(candidate, share, trimming=False).tolist() == [1.0] * 5


def test_weighted_mean_is_the_masked_mean_over_all_rays():
    per_ray = torch.tensor([1.0, 2.0, 3.0, 10.0])
    assert float(robust.weighted_mean(per_ray, torch.tensor([1.0, 1.0, 1.0, 0.0]))) == pytest.approx(6.0 / 4)
    assert float(robust.weighted_mean(per_ray, torch.ones(4))) == pytest.approx(float(per_ray.mean()))


def test_cell_index_cuts_the_longer_side_into_cells():
    # 64 x 32 photos, 16 cells across: 4-pixel cells, 16 columns and 8 rows
    uv = torch.tensor([[0, 0], [3, 3], [4, 0], [63, 31], [5, 9]])
    img = torch.tensor([0, 0, 0, 1, 2])
    flat, rows, cols = robust.cell_index(uv, img, 64, 32, cells=16)
    assert (rows, cols) == (8, 16)
    assert flat.tolist() == [0, 0, 1, 128 + 7 * 16 + 15, 256 + 2 * 16 + 1]


def test_memory_moves_each_hit_cell_toward_its_share_of_inliers():
    memory = robust.TransientMemory(2, 32, 32)  # 2-pixel cells
    cells = torch.tensor([0, 0, 0, 0, 5])
    candidate = torch.tensor([True, True, True, False, True])
    before = memory.update(cells, candidate)
    assert before.tolist() == [1.0] * 5  # every cell starts as all inliers
    r = robust.MEMORY_RATE
    assert float(memory.inliers[0]) == pytest.approx(1 + r * (0.25 - 1))
    assert float(memory.inliers[5]) == pytest.approx(1 - r)
    untouched = torch.ones(len(memory.inliers), dtype=torch.bool)
    untouched[[0, 5]] = False
    assert bool((memory.inliers[untouched] == 1).all())


def test_a_persistent_blob_is_trimmed_and_a_lone_bad_pixel_is_not():
    """Rays of one photo (2-pixel cells): a 4x4-pixel region (four cells) always bad, and at the
    last step one other pixel, among good ones, bad."""
    torch.manual_seed(0)
    memory = robust.TransientMemory(1, 32, 32)
    blob = torch.tensor([[x, y] for x in range(8, 12) for y in range(8, 12)])
    for step in range(60):
        uv = torch.cat([blob, torch.randint(0, 32, (200, 2))])
        inside = (uv[:, 0] >= 8) & (uv[:, 0] < 12) & (uv[:, 1] >= 8) & (uv[:, 1] < 12)
        error = (torch.rand(len(uv)) * 0.1 + inside.float()).unsqueeze(-1).repeat(1, 3)
        if step == 59:  # an edge pixel (whose cell other rays found good) that is bad this step
            uv[len(blob)] = torch.tensor([30, 30])
            error[len(blob)] = 1.0
        w = robust.robust_weights(error, memory, torch.zeros(len(uv), dtype=torch.long), uv, 0.8, True)
    assert bool((w[inside] == 0).all())  # the blob's cells learnt they are outliers
    assert float(w[len(blob)]) == 1.0  # the lone bad pixel sits in a cell of inliers
    assert bool((w[~inside] == 1).all())


def test_debiased_error_is_measured_from_the_photos_mean_of_its_inliers():
    memory = robust.TransientMemory(2, 8, 8)
    idx = torch.tensor([0, 0, 1, 1])
    err = torch.tensor([[0.2, 0.2, 0.2], [0.4, 0.0, 0.2], [-0.1, -0.1, -0.1], [0.9, 0.9, 0.9]])
    assert memory.debiased(idx, err).tolist() == pytest.approx((err**2).mean(-1).tolist())  # no mean yet
    inlier = torch.tensor([True, True, True, False])  # the last ray is left out
    memory.learn_bias(idx, err, inlier)
    r = robust.MEMORY_RATE
    assert memory.bias[0].tolist() == pytest.approx([r * 0.3, r * 0.1, r * 0.2])
    assert memory.bias[1].tolist() == pytest.approx([-r * 0.1] * 3)
    for _ in range(200):  # the mean converges to the photo's inliers' mean error
        memory.learn_bias(idx, err, inlier)
    assert memory.bias[1].tolist() == pytest.approx([-0.1] * 3, abs=1e-4)
    assert float(memory.debiased(idx, err)[2]) == pytest.approx(0.0, abs=1e-6)
    assert float(memory.debiased(idx, err)[3]) == pytest.approx(1.0)


def test_a_photo_off_in_exposure_is_not_trimmed_but_a_shadow_in_it_is():
    """Photo 1 is 0.3 brighter than the render everywhere (its colour correction has not caught
    up), and a 6x6-pixel patch of it is 0.5 darker (a shadow); photo 0 matches. Ranked by the
    raw error every ray of photo 1 would be an outlier; by the error less the photo's mean,
    only the shadow's are."""
    torch.manual_seed(0)
    memory = robust.TransientMemory(2, 32, 32)
    for _ in range(80):
        uv = torch.randint(0, 32, (400, 2))
        img = torch.randint(0, 2, (400,))
        shadow = (img == 1) & (uv[:, 0] < 6) & (uv[:, 1] < 6)
        err = torch.randn(400, 3) * 0.01 - 0.3 * (img == 1).float().unsqueeze(-1)
        err[shadow] += 0.5
        w = robust.robust_weights(err, memory, img, uv, 0.8, True)
    assert bool((w[shadow] == 0).all())
    assert bool((w[~shadow] == 1).all())
    raw = robust.outlier_candidates((err**2).mean(-1), 0.8)
    assert float(raw[(img == 1) & ~shadow].float().mean()) > 0.3  # what ranking by the raw error picks


def test_fast_loss_trims_only_after_the_warm_up_and_with_the_batch_seen():
    scene = sphere_scene(n_train=2, n_val=1, size=8)
    config = FastConfig(resolutions="8", upsample_steps="", transient_quantile=0.5, transient_start=0.5)
    model = FastNeRF(config, SceneBounds.from_scene(scene))
    target = torch.zeros(4, 3)
    rgb = torch.tensor([[0.0] * 3, [0.1] * 3, [0.9] * 3, [1.0] * 3])
    uv, img = torch.tensor([[0, 0], [0, 1], [1, 0], [1, 1]]), torch.zeros(4, dtype=torch.long)
    mse = float(rgb_loss(rgb, target))
    # (1) no batch seen: the plain loss
    assert float(model._photometric(rgb, target)) == pytest.approx(mse)
    # (2) warm-up: plain, while the memory learns that the cells (a pixel each) of the bad rays are bad
    for _ in range(20):
        model.see_batch(0.1, img, uv, (2, 8, 8))
        assert float(model._photometric(rgb, target)) == pytest.approx(mse)
    # (3) trimming: the two rays above the median drop out of the mean over four rays
    model.see_batch(0.6, img, uv, (2, 8, 8))
    assert float(model._photometric(rgb, target)) == pytest.approx((0.0 + 0.01) * 3 / 12)


def blotted(scene: Scene, seed: int = 0) -> tuple[Scene, np.ndarray]:
    """``scene`` with a dark disc ("a shadow") of radius 4 pixels at a different place on the
    sphere in each training photo; returns it and the (n, H, W) bool discs."""
    rng = np.random.default_rng(seed)
    v = scene.train
    images, masks = v.images.copy(), np.zeros(v.images.shape[:3], bool)
    yy, xx = np.mgrid[: v.height, : v.width]
    for i in range(len(v)):
        on = np.argwhere(images[i].max(-1) > 0)  # pixels of the sphere
        cy, cx = on[rng.integers(len(on))]
        masks[i] = (yy - cy) ** 2 + (xx - cx) ** 2 <= 16
        images[i][masks[i]] = (images[i][masks[i]] * 0.15).astype(np.uint8)
    return replace(scene, train=replace(v, images=images)), masks


def test_trimming_keeps_moving_shadows_out_of_the_scene():
    clean = sphere_scene(n_train=20, n_val=3, size=32)
    scene, masks = blotted(clean)
    errors, val = {}, {}
    for q in (0.0, 0.8):
        config = FastConfig(resolutions="24,48", upsample_steps="40", transient_quantile=q, transient_start=0.2)
        model = FastNeRF(config, SceneBounds.from_scene(scene))
        train_loop(model, scene, 250)
        bg, v = torch.zeros(3), clean.train
        sq = []
        for i in range(len(v)):  # the clean photo under each shadow, as the model renders it
            rgb = render_image(model, v.K[i], v.c2w[i], v.width, v.height, bg).rgb
            sq.append(((rgb - v.images[i] / 255.0) ** 2).mean(-1)[masks[i]])
        errors[q] = float(np.concatenate(sq).mean())
        w = clean.val
        views = [render_image(model, w.K[i], w.c2w[i], w.width, w.height, bg).rgb for i in range(len(w))]
        val[q] = np.mean([-10 * np.log10(np.mean((r - t / 255.0) ** 2)) for r, t in zip(views, w.images)])
    # the shadows leave a smear without trimming; with it, the error under them is much lower
    assert errors[0.8] < 0.5 * errors[0.0], errors
    # and the held-out views (no shadows) render at least as well
    assert val[0.8] > val[0.0] + 1.0, val


def test_the_memory_of_transients_round_trips_and_refuses_tensors_that_do_not_fit():
    memory = robust.TransientMemory(2, 32, 16)
    memory.inliers[3], memory.bias[1, 2] = 0.25, -0.5
    back = robust.TransientMemory.from_state(memory.state())
    assert back.shape == (2, 32, 16)
    torch.testing.assert_close(back.inliers, memory.inliers)
    torch.testing.assert_close(back.bias, memory.bias)
    for bad in ({"inliers": torch.ones(3)}, {"bias": torch.full((2, 3), float("nan"))}, {"shape": torch.ones(3)}):
        with pytest.raises(ValueError):
            robust.TransientMemory.from_state({**memory.state(), **bad})
