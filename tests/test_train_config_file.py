"""`nerfkit train --config RUN/config.json`: a run's recorded settings start a new run."""

from __future__ import annotations

import json

import pytest

from conftest import tiny_vanilla
from nerfkit.cli import main

TINY = [*tiny_vanilla(samples=4, width=8), "--checkpoint-seconds", "1e9"]


def settings(run) -> dict:
    return json.loads((run / "config.json").read_text())


@pytest.mark.slow
def test_a_config_file_reproduces_a_run_and_flags_beside_it_change_it(tmp_path, sphere_npz, capsys):
    first = tmp_path / "a"
    assert (
        main(
            [
                "train",
                "--data",
                str(sphere_npz),
                "--out",
                str(first),
                "--steps",
                "3",
                "--lr",
                "0.002",
                "--device",
                "cpu",
                *TINY,
            ]
        )
        == 0
    )
    again = tmp_path / "b"
    assert main(["train", "--config", str(first / "config.json"), "--out", str(again), "--device", "cpu"]) == 0
    a, b = settings(first), settings(again)
    assert b["model"] == a["model"] and b["model"]["width"] == 8
    assert {k: v for k, v in b["train"].items() if k != "out"} == {k: v for k, v in a["train"].items() if k != "out"}
    assert a["train"]["preset"] == "object" and a["train"]["lr"] == 0.002 and a["train"]["render_chunk"] == 4096
    # a flag beside it wins; a run folder names its own config.json
    changed = tmp_path / "c"
    assert (
        main(
            ["train", "--config", str(first), "--out", str(changed), "--steps", "2", "--depth", "3", "--device", "cpu"]
        )
        == 0
    )
    c = settings(changed)
    assert (c["train"]["steps"], c["model"]["depth"], c["train"]["lr"]) == (2, 3, 0.002)
    capsys.readouterr()


def test_a_config_file_is_refused_with_resume_or_over_its_own_run(tmp_path, capsys):
    bad = tmp_path / "config.json"
    bad.write_text(json.dumps({"train": {"lr": "fast"}, "model": {}}))
    assert main(["train", "--config", str(bad), "--out", str(tmp_path / "x")]) == 2
    assert "config key 'lr' should be float" in capsys.readouterr().err
    assert main(["train", "--config", str(bad), "--resume", str(tmp_path)]) == 2
    assert "--config: cannot be given with --resume" in capsys.readouterr().err
    assert main(["train", "--config", str(tmp_path / "nope.json")]) == 2
    assert "nope.json: no such file" in capsys.readouterr().err


@pytest.mark.parametrize("argv, lines", [([], 45), (["--help-all"], 1000)])
def test_the_short_help_fits_a_screen_and_the_full_one_has_every_group(argv, lines, capsys):
    with pytest.raises(SystemExit):
        main(["train", *(argv or ["--help"])])
    out = capsys.readouterr().out
    assert len(out.splitlines()) <= lines
    assert "--data" in out and "--config" in out and "--help-all" in out
    if argv:
        for group in (
            "data:",
            "optimisation:",
            "evaluation and checkpoints:",
            "real captures:",
            "model 'fast':",
            "model 'splat':",
            "model 'vanilla':",
        ):
            assert group in out
    else:
        assert "--lr " not in out and "--resolutions" not in out


def test_a_config_file_of_another_model_leaves_the_settings_each_model_presets(tmp_path):
    import dataclasses

    from nerfkit.commands.pipeline import train_settings
    from nerfkit.models.fast_config import FastConfig
    from nerfkit.presets import MODEL_TRAINING
    from nerfkit.train.config import TrainConfig

    fast = dataclasses.replace(TrainConfig(), model="fast", lr=0.3, batch_rays=4096, render_chunk=65536)
    (tmp_path / "config.json").write_text(
        json.dumps({"train": dataclasses.asdict(fast), "model": dataclasses.asdict(FastConfig())})
    )
    cfg, _, given = train_settings({"model": "vanilla"}, tmp_path / "config.json")
    assert not given & set(MODEL_TRAINING["vanilla"])  # vanilla's own (lr 5e-4, ...) apply, not fast's 0.3
    cfg, _, given = train_settings({"model": "vanilla", "lr": 1e-3}, tmp_path / "config.json")
    assert cfg.lr == 1e-3 and "lr" in given  # one given beside it wins
    cfg, _, given = train_settings({}, tmp_path / "config.json")
    assert (cfg.model, cfg.lr) == ("fast", 0.3) and "lr" in given  # the same model: the config's own
