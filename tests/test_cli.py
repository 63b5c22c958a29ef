"""The command line itself: every subcommand's --help renders, and the top-level help lists them."""

from __future__ import annotations

import subprocess
import sys

import pytest

from nerfkit.cli import COMMANDS, main


@pytest.mark.parametrize("command", COMMANDS)
def test_every_subcommand_help_renders(command, capsys):
    # argparse %-formats help strings: a stray '%' in one option's help used to crash --help.
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: nerfkit {command}")
    assert "--" in out  # at least one option is described


def test_top_level_help_lists_every_command(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for command in COMMANDS:
        assert command in out, command


def test_top_level_help_does_not_import_torch():
    # Registering `train` imports torch for its model flags; `nerfkit --help` must not pay that.
    code = ("import sys\nfrom nerfkit.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "False"


def test_options_before_the_command_still_find_it(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--verbose", "eval", "--help"])
    assert e.value.code == 0
    assert capsys.readouterr().out.startswith("usage: nerfkit eval")


def test_every_model_flag_reaches_its_config():
    # A model field named like a training flag would be shadowed on the command line (the fast
    # model's background option once was): every field must map to a flag of its own.
    import dataclasses

    from nerfkit.cli import build_parser
    from nerfkit.config import dataclass_from_args
    from nerfkit.models import MODEL_NAMES, model_config_class
    from nerfkit.train.config import TrainConfig

    train_fields = {f.name for f in dataclasses.fields(TrainConfig)}
    for name in MODEL_NAMES:
        cls = model_config_class(name)
        assert not train_fields & {f.name for f in dataclasses.fields(cls)}, name
    args = build_parser("train").parse_args(["train", "--learn-background"])
    assert dataclass_from_args(model_config_class("fast"), args).learn_background is True


def test_python_dash_m_runs_the_same_command_line_with_its_exit_code(tmp_path):
    ok = subprocess.run([sys.executable, "-m", "nerfkit", "--help"], capture_output=True, text=True)
    assert ok.returncode == 0 and ok.stdout.startswith("usage: nerfkit")
    bad = subprocess.run([sys.executable, "-m", "nerfkit", "eval", str(tmp_path / "missing"), "--split", "val"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "no such run folder" in bad.stderr


def test_every_numeric_flag_has_a_range():
    # A flag without one is only checked for being finite: `--step-ratio -1` once reached the
    # model and died in a traceback. Flags whose every finite value is valid say so here.
    import dataclasses
    import typing

    from nerfkit.capture.calibrate import CalibrateConfig
    from nerfkit.capture.dataset import DatasetConfig
    from nerfkit.capture.poses import PoseConfig
    from nerfkit.config import base_type
    from nerfkit.fit_image import FitImageConfig
    from nerfkit.models import MODEL_NAMES, model_config_class
    from nerfkit.train.config import TrainConfig

    any_finite = {"density_bias_init"}
    classes = [TrainConfig, CalibrateConfig, DatasetConfig, PoseConfig, FitImageConfig]
    unbounded = []
    for cls in classes + [model_config_class(name) for name in MODEL_NAMES]:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if base_type(hints[f.name])[0] in (int, float) and f.metadata.get("cli") is not False:
                if f.name not in any_finite and not {"min", "max", "above"} & set(f.metadata):
                    unbounded.append(f"{cls.__name__}.{f.name}")
    assert unbounded == []
