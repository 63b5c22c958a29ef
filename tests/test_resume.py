"""What a resumed run takes back from a checkpoint besides the model (nerfkit.train.resume)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nerfkit.data.rays import RaysData
from nerfkit.data.scene import Views
from nerfkit.errors import NerfkitError
from nerfkit.train.resume import psnr_window, restore_rng, restore_views, resumed_precision, rng_state
from nerfkit.train.view_corrections import ViewCorrections


def test_the_psnr_window_keeps_the_last_finite_values_and_ignores_anything_else():
    assert psnr_window([float(v) for v in range(15)]) == [float(v) for v in range(5, 15)]
    assert psnr_window([1.0, float("nan")]) == [] and psnr_window(None) == [] and psnr_window([1]) == []


def test_a_resumed_run_keeps_its_precision_unless_bf16_is_not_native_here():
    cpu = torch.device("cpu")
    assert resumed_precision("fp32", torch.bfloat16, cpu) == (None, None)
    assert resumed_precision("bf16", torch.bfloat16, cpu) == (torch.bfloat16, None)
    here, warning = resumed_precision("bf16", None, cpu)
    assert here is None and warning is not None and "fp32" in warning
    assert resumed_precision(None, torch.bfloat16, cpu) == (torch.bfloat16, None)  # older checkpoints


def test_the_random_streams_go_on_where_they_were_saved():
    images = np.zeros((2, 4, 4, 3), np.uint8)
    K = np.tile(np.array([[4, 0, 2], [0, 4, 2], [0, 0, 1]], np.float32), (2, 1, 1))
    rays = RaysData(
        Views(np.tile(np.eye(4, dtype=np.float32), (2, 1, 1)), K, 4, 4, images), torch.device("cpu"), seed=0
    )
    sight, cpu = torch.Generator().manual_seed(1), torch.device("cpu")
    saved = rng_state(rays, sight, cpu)
    first = (torch.rand(3), rays.sample(5).uv, torch.rand(2, generator=sight))
    restore_rng(saved, rays, sight, cpu)
    again = (torch.rand(3), rays.sample(5).uv, torch.rand(2, generator=sight))
    assert all(torch.equal(a, b) for a, b in zip(first, again))


def test_per_view_corrections_come_back_and_other_ones_are_refused(tmp_path):
    views = ViewCorrections(3, 1.0, True, True, False)
    with torch.no_grad():
        for p in views.parameters():
            p.add_(0.5)
    optimizer = torch.optim.Adam(views.param_groups(1e-3, 1e-3))
    ckpt = {"views": views.state_dict(), "views_optimizer": optimizer.state_dict()}
    again = ViewCorrections(3, 1.0, True, True, False)
    restore_views(ckpt, tmp_path / "c.pt", again, torch.optim.Adam(again.param_groups(1e-3, 1e-3)))
    assert all(torch.equal(a, b) for a, b in zip(views.state_dict().values(), again.state_dict().values()))
    with pytest.raises(NerfkitError, match="no per-view corrections"):
        restore_views({}, tmp_path / "c.pt", again, None)
