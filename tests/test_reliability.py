"""Crash and resume, atomic outputs, safe loading, numerical guard (issue 6)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import sigint_as_a_terminal_gives_it, tiny_vanilla
from nerfkit.cli import main
from nerfkit.errors import NerfkitError
from nerfkit.images import to_uint8, write_image
from nerfkit.io.atomic import atomic_path, write_json
from nerfkit.models.vanilla import VanillaConfig
from nerfkit.train.checkpoint import load_run
from nerfkit.train.config import TrainConfig
from nerfkit.train.trainer import train

TINY = tiny_vanilla(batch_rays=128, lr="3e-3", seed=3, eval_every=50)


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "nerfkit.cli", *args]


def wait_for(predicate, timeout: float, proc: subprocess.Popen | None = None) -> None:
    end = time.time() + timeout
    while time.time() < end:
        if predicate():
            return
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"process ended early: {proc.stderr.read() if proc.stderr else ''}")
        time.sleep(0.05)
    raise AssertionError("timed out")


def final_state(run: Path) -> dict:
    ckpt = sorted((run / "checkpoints").glob("*.pt"))[-1]
    return torch.load(ckpt, weights_only=True)


@pytest.mark.slow
def test_sigkill_then_resume_matches_an_uninterrupted_run(tmp_path, sphere_npz):
    steps = "400"
    reference = tmp_path / "reference"
    assert main(["train", "--data", str(sphere_npz), "--out", str(reference), "--steps", steps, *TINY]) == 0

    run = tmp_path / "killed"
    proc = subprocess.Popen(
        cli(
            "train",
            "--data",
            str(sphere_npz),
            "--out",
            str(run),
            "--steps",
            steps,
            "--checkpoint-seconds",
            "0.3",
            *TINY,
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    wait_for(
        lambda: any((run / "checkpoints").glob("step_*.pt")) if (run / "checkpoints").exists() else False, 120, proc
    )
    time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed_at = max(int(p.stem.split("_")[1]) for p in (run / "checkpoints").glob("step_*.pt"))
    assert 0 < killed_at < int(steps), "kill must land mid-run"

    assert main(["train", "--resume", str(run)]) == 0
    a, b = final_state(reference), final_state(run)
    assert a["step"] == b["step"] == int(steps)
    for k in a["model"]:
        torch.testing.assert_close(a["model"][k], b["model"][k], rtol=1e-3, atol=1e-4)
    rows_a, rows_b = json.loads(a["rows"]), json.loads(b["rows"])
    assert [(r["step"], r["split"]) for r in rows_a] == [(r["step"], r["split"]) for r in rows_b]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["step"] == int(steps) and len(metrics["rows"]) == len(rows_a)


@pytest.mark.slow
def test_ctrl_c_saves_a_checkpoint_and_exits_cleanly(tmp_path, sphere_npz):
    run = tmp_path / "interrupted"
    proc = subprocess.Popen(
        cli("train", "--data", str(sphere_npz), "--out", str(run), "--steps", "100000", *TINY),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=sigint_as_a_terminal_gives_it,
    )
    wait_for(lambda: (run / "progress").exists() and len(list((run / "progress").glob("*.png"))) >= 2, 120, proc)
    proc.send_signal(signal.SIGINT)
    time.sleep(0.05)
    proc.send_signal(signal.SIGINT)  # pressed twice: the save must still finish (it once stopped half-way)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "--resume" in err and "Traceback" not in err
    state = final_state(run)
    assert 50 <= state["step"] < 100000
    assert (run / "metrics.csv").exists() and (run / "plots" / "psnr.png").exists()


def test_atomic_write_keeps_the_old_file_when_interrupted(tmp_path):
    target = tmp_path / "out.json"
    write_json(target, {"version": 1})
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text('{"version": 2, "trunc')
        raise RuntimeError("crash between write and rename")
    assert json.loads(target.read_text()) == {"version": 1}
    assert list(tmp_path.iterdir()) == [target]  # no temporary left behind


def test_a_diverged_render_is_written_black_where_it_is_not_a_number(tmp_path):
    import imageio.v3 as iio

    image = np.array([[[np.nan, np.inf, -np.inf], [0.5, 1.5, -0.5]]], np.float32)  # (1, 2, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "invalid value encountered in cast"
        write_image(tmp_path / "x.png", image)
        frame = to_uint8(image)  # what the videos' frames go through too
    assert iio.imread(tmp_path / "x.png").tolist() == [[[0, 255, 0], [128, 255, 0]]]
    assert frame.tolist() == [[[0, 255, 0], [128, 255, 0]]]


def test_a_full_disk_is_a_clear_error_and_the_old_file_stays(tmp_path, monkeypatch):
    import errno
    import shutil
    from collections import namedtuple

    target = tmp_path / "step_00000100.pt"
    write_json(target, {"version": 1})
    # ENOSPC, whatever the free space says
    with pytest.raises(NerfkitError, match="disk is full.*--resume"), atomic_path(target) as tmp:
        tmp.write_text("partial")
        raise OSError(errno.ENOSPC, "No space left on device")
    # torch.save reports a full disk as a RuntimeError about the zip writer's position
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda _: usage(10 << 30, (10 << 30) - (1 << 20), 1 << 20))
    with pytest.raises(NerfkitError, match="disk is full"), atomic_path(target) as tmp:
        torch.save({"x": torch.zeros(10)}, tmp)
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 108156544 vs 108156436")
    assert json.loads(target.read_text()) == {"version": 1}
    assert list(tmp_path.iterdir()) == [target]  # no temporary left behind
    monkeypatch.setattr(shutil, "disk_usage", lambda _: usage(10 << 30, 1 << 30, 9 << 30))
    # with space to spare, other errors stay what they are
    with pytest.raises(RuntimeError, match="unrelated"), atomic_path(target):
        raise RuntimeError("unrelated")


def test_sigkill_during_a_write_leaves_the_old_file_intact(tmp_path):
    target = tmp_path / "big.npz"
    np.savez(target, a=np.arange(10))
    script = (
        "import numpy as np, time, sys\n"
        "from nerfkit.io.atomic import atomic_path\n"
        f"with atomic_path({str(target)!r}) as tmp:\n"
        "    f = open(tmp, 'wb'); f.write(b'x' * 1000); f.flush()\n"
        "    print('writing', flush=True); time.sleep(60)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "writing"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with np.load(target) as d:
        assert np.array_equal(d["a"], np.arange(10))


def _trained_run(tmp_path, sphere, steps=20, name="run"):
    cfg = TrainConfig(
        data="x",
        model="vanilla",
        out=str(tmp_path / name),
        steps=steps,
        batch_rays=64,
        lr=1e-3,
        eval_views=1,
        checkpoint_seconds=1e9,
    )
    train(sphere, cfg, VanillaConfig(n_samples=8, width=16, depth=2), quiet=True)
    return tmp_path / name


@pytest.mark.slow
def test_crafted_checkpoint_is_refused_without_running_code(tmp_path, sphere):
    run = _trained_run(tmp_path, sphere)
    good = sorted((run / "checkpoints").glob("*.pt"))[-1]
    marker = tmp_path / "pwned"

    class Payload:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    torch.save({"format": "nerfkit-checkpoint", "x": Payload()}, run / "checkpoints" / "step_99999999.pt")
    model, _, step = load_run(run)  # falls back to the good checkpoint, with a warning
    assert step == int(good.stem.split("_")[1])
    assert not marker.exists()


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["truncate", "garbage", "wrong_version", "other_model"])
def test_broken_newest_checkpoint_falls_back_to_previous(tmp_path, sphere, damage, capsys):
    run = _trained_run(tmp_path, sphere)
    good = sorted((run / "checkpoints").glob("*.pt"))[-1]
    bad = run / "checkpoints" / "step_00000999.pt"
    data = good.read_bytes()
    if damage == "truncate":
        bad.write_bytes(data[: len(data) // 3])
    elif damage == "garbage":
        bad.write_bytes(b"\x00" * 100)
    else:
        ckpt = torch.load(good, weights_only=True)
        ckpt["version" if damage == "wrong_version" else "model_name"] = 99 if damage == "wrong_version" else "FastNeRF"
        torch.save(ckpt, bad)
    model, _, step = load_run(run)
    assert step == 20
    assert "step_00000999.pt" in capsys.readouterr().err
    good.unlink()
    assert load_run(run)[2] == 20  # model.pt, though older than the broken file's name says
    (run / "model.pt").unlink()
    with pytest.raises(NerfkitError, match="no checkpoint could be loaded"):
        load_run(run)


def test_non_finite_steps_are_skipped_then_the_run_stops_with_checkpoint_intact(tmp_path, sphere, monkeypatch):
    run = _trained_run(tmp_path, sphere, steps=10)
    before = torch.load(sorted((run / "checkpoints").glob("*.pt"))[-1], weights_only=True)
    from nerfkit.train import trainer as trainer_mod

    trainer = trainer_mod.Trainer(
        sphere, trainer_mod.read_run(run).train, VanillaConfig(n_samples=8, width=16, depth=2), resume=True, quiet=True
    )
    trainer.cfg.steps = 100
    original = trainer.model.render_rays
    calls = {"n": 0}

    def poisoned(rays, background, perturb):
        out = original(rays, background, perturb)
        calls["n"] += 1
        if calls["n"] % 2 == 0 or calls["n"] > 6:  # some bad steps, then only bad ones
            out.rgb = out.rgb * float("nan")
        return out

    trainer.model.render_rays = poisoned
    with pytest.raises(NerfkitError, match="diverged"):
        trainer.run()
    assert trainer.step > 10  # good steps between the first bad ones went through
    for p in trainer.model.parameters():
        assert torch.isfinite(p).all()
    newest = torch.load(sorted((run / "checkpoints").glob("*.pt"))[-1], weights_only=True)
    assert newest["step"] == before["step"]  # no checkpoint written from a diverged state


def test_verbose_shows_the_traceback(tmp_path, capsys):
    assert main(["eval", str(tmp_path / "missing")]) == 2
    assert "Traceback" not in capsys.readouterr().err
    assert main(["--verbose", "eval", str(tmp_path / "missing")]) == 2
    assert "Traceback" in capsys.readouterr().err


def test_json_files_are_standard_json_with_null_for_a_number_that_is_not_finite(tmp_path):
    from nerfkit.io.atomic import write_json

    values = {"loss": float("nan"), "rows": [np.float32("inf"), 1.5], "a": np.array([np.nan, 2.0])}
    write_json(tmp_path / "m.json", values)
    text = (tmp_path / "m.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"loss": None, "rows": [None, 1.5], "a": [None, 2.0]}
