"""Compact model files: the fast grid stored sparsely (occupied vertices) in half precision."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from conftest import train_loop
from nerfkit.data.synthetic import sphere_scene
from nerfkit.errors import NerfkitError
from nerfkit.models.base import SceneBounds
from nerfkit.models.fast import EMPTY_RAW, FastConfig, FastNeRF
from nerfkit.models.packing import pack_grid, unpack_grid, vertices_touching
from nerfkit.output.images import render_image
from nerfkit.train.checkpoint import MODEL_FILE, load_latest_checkpoint, save_checkpoint, save_model


def touching_reference(occ: np.ndarray) -> np.ndarray:
    """Brute force: mark the 8 corners of every occupied cell."""
    cz, cy, cx = occ.shape
    out = np.zeros((cz + 1, cy + 1, cx + 1), bool)
    for z, y, x in zip(*np.nonzero(occ)):
        for dz, dy, dx in itertools.product((0, 1), repeat=3):
            out[z + dz, y + dy, x + dx] = True
    return out.reshape(-1)


def test_one_occupied_cell_marks_its_eight_corners():
    occ = torch.zeros(3, 4, 5, dtype=torch.uint8)
    occ[1, 2, 3] = 1
    keep = vertices_touching(occ).reshape(4, 5, 6)
    assert int(keep.sum()) == 8 and keep[1:3, 2:4, 3:5].all()


@pytest.mark.parametrize("seed", range(5))
def test_vertices_touching_matches_brute_force(seed):
    occ = np.random.default_rng(seed).random((4, 5, 6)) < 0.15
    assert np.array_equal(vertices_touching(torch.from_numpy(occ)).numpy(), touching_reference(occ))


def test_pack_unpack_round_trip_and_size_checks():
    gen = torch.Generator().manual_seed(0)
    grid = torch.randn(37, 4, generator=gen) * 3
    keep = torch.rand(37, generator=gen) < 0.3
    packed = pack_grid(grid[keep], keep, torch.float32)
    assert packed["mask"].shape == (5,) and packed["density"].dtype == torch.float32
    back_keep, back = unpack_grid(packed, 37, 4)
    assert torch.equal(back_keep, keep)
    assert torch.equal(back[:, 0], grid[keep, 0])  # density kept in float32 here
    assert torch.allclose(back[:, 1:], grid[keep, 1:], rtol=1e-3, atol=1e-3)  # colour in float16
    with pytest.raises(ValueError, match="rows"):
        pack_grid(grid, keep)
    with pytest.raises(ValueError, match="mask"):
        unpack_grid(packed, 45, 4)  # 45 vertices need 6 mask bytes
    with pytest.raises(ValueError, match="past the last vertex"):
        unpack_grid({**packed, "mask": packed["mask"] | 1}, 37, 4)  # bits 37..39 are padding
    with pytest.raises(ValueError, match="density"):
        unpack_grid({**packed, "density": packed["density"][:-1]}, 37, 4)
    with pytest.raises(ValueError, match="colour"):
        unpack_grid({**packed, "colour": packed["colour"].float()}, 37, 4)


@pytest.fixture(scope="module")
def trained():
    scene = sphere_scene(n_train=20, n_val=2, size=32)
    model = FastNeRF(FastConfig(resolutions="24,48", upsample_steps="40"), SceneBounds.from_scene(scene))
    opt = train_loop(model, scene, 80)
    return scene, model, opt


def _reload(run_dir, scene):
    fresh = FastNeRF(FastConfig(resolutions="24,48", upsample_steps="40"), SceneBounds.from_scene(scene))
    ckpt, path = load_latest_checkpoint(run_dir, fresh, final_model=True)
    assert path.name == MODEL_FILE
    return fresh


def test_compact_model_file_renders_like_the_model(tmp_path, trained):
    scene, model, _ = trained
    assert 0.02 < model.occupied_fraction < 0.5  # the sphere fills part of its box
    dense_dir, compact_dir = tmp_path / "dense", tmp_path / "compact"
    dense_dir.mkdir(), compact_dir.mkdir()
    save_model(dense_dir, 80, model, compact=False)
    save_model(compact_dir, 80, model)
    kept = float(vertices_touching(model.estimator.occ).float().mean())
    dense_size, compact_size = (dense_dir / MODEL_FILE).stat().st_size, (compact_dir / MODEL_FILE).stat().st_size
    grid_bytes = model.field.grid.numel() * 4
    # the grid shrinks to the kept fraction at 2 bytes a value (+ 1 bit a vertex); the rest is unchanged
    assert compact_size < dense_size - grid_bytes * (1 - kept / 2) + model.field.geom.n_vertices / 8 + 4096
    compact = _reload(compact_dir, scene)
    dense = _reload(dense_dir, scene)
    assert torch.equal(compact.estimator.occ, model.estimator.occ) and compact.field.geom.res == model.field.geom.res
    touching = vertices_touching(model.estimator.occ)
    assert torch.all(compact.field.vertex_rows[~touching] == 0) and torch.all(compact.field.vertex_rows[touching] > 0)
    kept_rows = compact.field.stored_vertices
    assert kept_rows == int(touching.sum()) < model.field.stored_vertices  # only what renders is kept
    assert torch.all(compact.field.grid[0, 0] == EMPTY_RAW) and torch.all(compact.field.grid[0, 1:] == 0)
    v, bg = scene.val, torch.zeros(3)
    for i in range(len(v)):
        a = render_image(dense, v.K[i], v.c2w[i], v.width, v.height, bg).rgb
        b = render_image(compact, v.K[i], v.c2w[i], v.width, v.height, bg).rgb
        ref = render_image(model, v.K[i], v.c2w[i], v.width, v.height, bg).rgb
        assert np.array_equal(a, ref)  # the dense file is exact
        assert np.abs(b - ref).max() < 5e-3  # the compact one to float16 rounding


def test_a_corrupt_compact_file_is_a_one_line_error(tmp_path, trained):
    scene, model, _ = trained
    save_model(tmp_path, 80, model)
    payload = torch.load(tmp_path / MODEL_FILE, weights_only=True)
    payload["model"]["grid_packed.density"] = payload["model"]["grid_packed.density"][:10]
    torch.save(payload, tmp_path / MODEL_FILE)
    with pytest.raises(NerfkitError, match="compact grid: density is"):
        _reload(tmp_path, scene)


def test_resume_checkpoints_keep_optimizer_state_and_are_pruned(tmp_path, trained):
    scene, model, opt = trained
    for step in (10, 20, 30):
        save_checkpoint(tmp_path, step, model, opt, {})
    kept = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert kept == ["step_00000030.pt"]  # only the newest (the default)
    ckpt = torch.load(tmp_path / "checkpoints" / kept[-1], weights_only=True)
    assert "model_packing" not in ckpt
    assert ckpt["model"]["field.grid"].dtype == torch.float32  # full precision to resume
    assert ckpt["optimizer"]["state"]  # Adam moments
