"""A run keeps model.pt and one resume checkpoint; a crash while saving never loses the last one."""

from __future__ import annotations

import pytest
import torch

from nerfkit import presets
from nerfkit.models.vanilla import VanillaConfig
from nerfkit.train import checkpoint
from nerfkit.train.checkpoint import checkpoint_paths
from nerfkit.train.config import TrainConfig
from nerfkit.train.trainer import Trainer, resume, train

TINY = VanillaConfig(n_samples=4, width=8, depth=2, occupancy=False)


def cfg(tmp_path, name, **kw):
    # a checkpoint at every step's check: several are written during the run
    return presets.without_scene(
        TrainConfig(
            data="sphere",
            model="vanilla",
            out=str(tmp_path / name),
            steps=12,
            batch_rays=64,
            eval_views=1,
            eval_every=1000,
            checkpoint_seconds=1e-9,
            **kw,
        )
    )


@pytest.mark.slow
def test_a_finished_run_keeps_its_model_and_one_checkpoint(tmp_path, sphere):
    result = train(sphere, cfg(tmp_path, "a"), TINY, quiet=True)
    run = tmp_path / "a"
    assert [p.name for p in checkpoint_paths(run)] == [f"step_{result.step:08d}.pt"]
    assert (run / "model.pt").is_file()
    assert not [p for p in (run / "checkpoints").iterdir() if p.name.startswith(".")]  # no temporaries
    # more when asked for
    train(sphere, cfg(tmp_path, "b", keep_checkpoints=3), TINY, quiet=True)
    assert len(checkpoint_paths(tmp_path / "b")) == 3


def test_a_crash_while_a_checkpoint_is_written_keeps_the_previous_one(tmp_path, sphere, monkeypatch):
    run = tmp_path / "c"
    trainer = Trainer(sphere, cfg(tmp_path, "c"), TINY, quiet=True)
    trainer.run(stop_after=5)
    before = checkpoint_paths(run)
    assert [p.name for p in before] == ["step_00000005.pt"]

    real_save = torch.save

    def dies_half_way(obj, f, *a, **kw):  # the process dies with a partial file on disk
        with open(f, "wb") as out:
            out.write(b"PK\x03\x04 half a zip")
        raise KeyboardInterrupt

    monkeypatch.setattr(checkpoint.torch, "save", dies_half_way)
    again = Trainer(sphere, cfg(tmp_path, "c"), TINY, resume=True, quiet=True)
    again.step += 1
    with pytest.raises(KeyboardInterrupt):
        again.save()
    monkeypatch.setattr(checkpoint.torch, "save", real_save)
    # the whole previous checkpoint is still there, the partial one never took its name
    assert checkpoint_paths(run) == before
    resumed = resume(run, sphere, quiet=True)  # the lock removes the temporary it left
    assert resumed.step == 12
    assert [p.name for p in checkpoint_paths(run)] == ["step_00000012.pt"]
    assert not [p for p in (run / "checkpoints").iterdir() if p.name.startswith(".")]
