"""--precision is resolved once (nerfkit.precision) and every network runs in what it says."""

from __future__ import annotations

import pytest
import torch

from nerfkit.models.vanilla import VanillaConfig
from nerfkit.precision import autocast, cpu_has_native_bf16, resolve_device, resolve_precision
from nerfkit.train.config import TrainConfig
from nerfkit.train.trainer import Trainer

CPU = torch.device("cpu")


def test_resolve_precision_rules():
    assert resolve_precision("fp32", CPU) is None
    assert resolve_precision("bf16", CPU) is torch.bfloat16
    assert resolve_precision("auto", CPU) is (torch.bfloat16 if cpu_has_native_bf16() else None)
    with pytest.raises(ValueError, match="precision must be one of auto, fp32, bf16, got 'fp16'"):
        resolve_precision("fp16", CPU)


@pytest.mark.parametrize("capability, expected", [((7, 5), None), ((8, 0), torch.bfloat16), ((9, 0), torch.bfloat16)])
def test_auto_takes_bf16_only_on_gpus_that_have_it_natively(monkeypatch, capability, expected):
    """A T4 (7.5) only emulates bf16 (``is_bf16_supported`` says yes there): fp32 on it."""
    asked = []
    monkeypatch.setattr(torch.cuda, "get_device_capability", lambda device=None: asked.append(device) or capability)
    assert resolve_precision("auto", torch.device("cuda:1")) is expected
    assert asked == [torch.device("cuda:1")]  # the GPU asked for, not the current one


def test_a_gpu_this_machine_lacks_is_refused_and_the_one_asked_for_is_made_current(monkeypatch):
    from nerfkit.errors import NerfkitError

    current = []
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    monkeypatch.setattr(torch.cuda, "set_device", current.append)
    assert resolve_device("cuda:1") == torch.device("cuda:1") and current == [torch.device("cuda:1")]
    assert resolve_device("cuda") == torch.device("cuda") and len(current) == 1
    with pytest.raises(NerfkitError, match=r"GPU 2, but this machine has 2 \(cuda:0 to cuda:1\)"):
        resolve_device("cuda:2")


def test_fp32_context_turns_an_outer_autocast_off():
    a, b = torch.randn(4, 4), torch.randn(4, 4)
    with autocast(CPU, torch.bfloat16):
        assert (a @ b).dtype == torch.bfloat16
        with autocast(CPU, None):
            assert (a @ b).dtype == torch.float32


def _activation_dtypes(tmp_path, sphere, precision: str) -> tuple[set, torch.Tensor]:
    """Dtypes of the vanilla MLP's first hidden layer over one training step that also
    refreshes the occupancy grid (step 0, warm-up 0), and the refreshed cell densities."""
    cfg = TrainConfig(
        data="sphere",
        model="vanilla",
        out=str(tmp_path / precision),
        steps=1,
        batch_rays=32,
        lr=1e-3,
        precision=precision,
        eval_views=1,
        checkpoint_seconds=1e9,
    )
    mcfg = VanillaConfig(
        n_samples=8, width=16, depth=2, occupancy=True, occupancy_res=8, occupancy_warmup=0, occupancy_every=1
    )
    trainer = Trainer(sphere, cfg, mcfg, quiet=True)
    seen = []
    trainer.model.coarse.layers[0].register_forward_hook(lambda m, i, out: seen.append((out.dtype, len(out))))
    trainer.train_step()
    return seen, trainer.model.estimator.cell_sigma


@pytest.mark.parametrize("precision,dtype", [("fp32", torch.float32), ("bf16", torch.bfloat16)])
def test_vanilla_runs_every_network_call_in_the_resolved_precision(tmp_path, sphere, precision, dtype):
    seen, cell_sigma = _activation_dtypes(tmp_path, sphere, precision)
    assert torch.isfinite(cell_sigma).all()  # the occupancy refresh ran ...
    assert any(n == 8**3 for _, n in seen)  # ... through the network, one point per cell
    assert len(seen) >= 2  # and the training batch too
    assert {d for d, _ in seen} == {dtype}  # fp32 means fp32 everywhere (the refresh used bf16 before)
