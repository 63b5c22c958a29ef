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
    base = dict(steps=12, batch_rays=64, eval_views=1, eval_every=1000, checkpoint_seconds=1e-9)
    return presets.without_scene(
        TrainConfig(data="sphere", model="vanilla", out=str(tmp_path / name), **{**base, **kw})
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


def test_a_broken_checkpoint_newer_than_the_good_one_is_set_aside_on_resume(tmp_path, sphere, capsys):
    """A truncated step_99 beside a good step_40: the resume goes on from step 40, moves step_99
    into checkpoints/broken/ (never deleting it), and keeps the checkpoint it writes, so that
    eval and the next resume load the run."""
    run = tmp_path / "r"
    train(sphere, cfg(tmp_path, "r", steps=40, checkpoint_seconds=1e9), TINY, quiet=True)
    good = run / "checkpoints" / "step_00000040.pt"
    data = good.read_bytes()
    assert data[:4] == b"PK\x03\x04"
    broken = run / "checkpoints" / "step_00000099.pt"
    broken.write_bytes(data[: len(data) // 2])  # a copy cut short
    capsys.readouterr()
    assert resume(run, sphere, steps=70, quiet=True).step == 70
    err = capsys.readouterr().err
    assert "step_00000099.pt" in err and "used the older step_00000040.pt" in err and "broken" in err
    assert [p.name for p in checkpoint_paths(run)] == ["step_00000070.pt"]
    assert (run / "checkpoints" / "broken" / "step_00000099.pt").read_bytes() == data[: len(data) // 2]
    assert checkpoint.load_run(run)[2] == 70
    assert resume(run, sphere, steps=75, quiet=True).step == 75


def test_pruning_keeps_the_checkpoint_just_written_whatever_is_newer(tmp_path, sphere):
    trainer = Trainer(sphere, cfg(tmp_path, "p", keep_checkpoints=2), TINY, quiet=True)
    trainer.run(stop_after=3)
    folder = tmp_path / "p" / "checkpoints"
    (folder / "step_00000099.pt").write_bytes(b"PK\x03\x04 cut short")
    for step in (4, 5):
        trainer.step = step
        trainer.save()
    assert [p.name for p in checkpoint_paths(tmp_path / "p")] == [
        "step_00000099.pt",  # not this run's to delete
        "step_00000005.pt",
        "step_00000004.pt",
    ]


def test_eval_falls_back_to_model_pt_when_a_newer_checkpoint_does_not_load(tmp_path, sphere):
    run = tmp_path / "m"
    train(sphere, cfg(tmp_path, "m", steps=6, checkpoint_seconds=1e9), TINY, quiet=True)
    (run / "checkpoints" / "step_00000006.pt").unlink()
    (run / "checkpoints" / "step_00000099.pt").write_bytes(b"PK\x03\x04 cut short")
    model, _, step = checkpoint.load_run(run)
    assert step == 6


def test_a_checkpoint_cut_short_is_named_so_and_no_checkpoint_loading_gives_one_fix(tmp_path, sphere):
    run = tmp_path / "t"
    train(sphere, cfg(tmp_path, "t", steps=3, checkpoint_seconds=1e9), TINY, quiet=True)
    for path in [run / "model.pt", *checkpoint_paths(run)]:
        data = path.read_bytes()
        path.write_bytes(data[:-30])  # the end of the zip, its list of members, is missing
    with pytest.raises(checkpoint.NerfkitError) as e:
        checkpoint.load_run(run)
    text = str(e.value)
    assert text.count("the file is cut short or damaged") == 2 and "something else" not in text
    assert text.endswith("Copy the run again from where it was made, or train it again")
    assert text.count(". ") == 1  # one fix, at the end
