"""The command line itself: every subcommand's --help renders, and the top-level help lists them."""

from __future__ import annotations

import functools
import subprocess
import sys
from pathlib import Path

import pytest

from nerfkit.cli import COMMANDS, main

LEGO = Path(__file__).resolve().parents[1] / "src" / "nerfkit" / "assets" / "lego_200x200.npz"


@pytest.mark.parametrize("command", COMMANDS)
def test_every_subcommand_help_renders(command, capsys):
    # argparse %-formats help strings: a stray '%' in one option's help used to crash --help.
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: nerfkit {command}")
    assert "--" in out  # at least one option is described


def test_render_help_states_the_orbit_frames_it_renders(capsys):
    from nerfkit.data.scene import ORBIT_FRAMES

    with pytest.raises(SystemExit):
        main(["render", "--help"])
    assert f"(default: {ORBIT_FRAMES}, {ORBIT_FRAMES / 30:g} s at 30 fps)" in " ".join(capsys.readouterr().out.split())


def test_top_level_help_lists_every_command(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for command in COMMANDS:
        assert command in out, command


def test_top_level_help_does_not_import_torch():
    # Registering `train` imports torch for its model flags; `nerfkit --help` must not pay that,
    # nor NumPy's start-up (the commands' options, nerfkit.commands.options, are plain Python).
    code = (
        "import sys\nfrom nerfkit.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
        "print('torch' in sys.modules, 'numpy' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "False False"


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


@pytest.mark.slow
def test_python_dash_m_runs_the_same_command_line_with_its_exit_code(tmp_path):
    ok = subprocess.run([sys.executable, "-m", "nerfkit", "--help"], capture_output=True, text=True)
    assert ok.returncode == 0 and ok.stdout.startswith("usage: nerfkit")
    bad = subprocess.run(
        [sys.executable, "-m", "nerfkit", "eval", str(tmp_path / "missing"), "--split", "val"],
        capture_output=True,
        text=True,
    )
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
            numeric = base_type(hints[f.name])[0] in (int, float) and f.metadata.get("cli") is not False
            if numeric and f.name not in any_finite and not {"min", "max", "above"} & set(f.metadata):
                unbounded.append(f"{cls.__name__}.{f.name}")
    assert unbounded == []


def test_splat_takes_sh_degree_3_through_the_real_parser(tmp_path, capsys):
    # --sh-degree is fast's (0 to 2) and splat's (0 to 3): the flag was parsed with fast's bounds only
    from nerfkit.cli import build_parser
    from nerfkit.config import dataclass_from_args
    from nerfkit.models import check_config, model_config_class

    args = build_parser("train").parse_args(["train", "--model", "splat", "--sh-degree", "3"])
    assert check_config("splat", dataclass_from_args(model_config_class("splat"), args)).sh_degree == 3
    missing = tmp_path / "missing.npz"
    assert (
        main(
            [
                "train",
                "--model",
                "splat",
                "--sh-degree",
                "3",
                "--data",
                str(missing),
                "--steps",
                "1",
                "--out",
                str(tmp_path / "run"),
            ]
        )
        == 2
    )
    assert capsys.readouterr().err.strip() == f"nerfkit train: error: {missing}: no such file or folder. Check the path"


# without --model the dataset's kind names the model (lego as a capture: fast), so the dataset is read first
@pytest.mark.parametrize("model", [["--capture", "on"], ["--model", "fast"]])
def test_the_fast_model_refuses_sh_degree_3_in_one_line_naming_itself(model, tmp_path, capsys):
    assert (
        main(
            [
                "train",
                *model,
                "--sh-degree",
                "3",
                "--data",
                str(LEGO),
                "--steps",
                "1",
                "--out",
                str(tmp_path / "run"),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert err == "nerfkit train: error: --sh-degree: 3 is above the maximum 2 (allowed: 0 to 2) for the fast model\n"
    assert not (tmp_path / "run").exists()
    # above every model's bound: refused when parsed
    assert main(["train", "--model", "splat", "--sh-degree", "4", "--data", "x.npz", "--steps", "1"]) == 2
    assert "argument --sh-degree: 4 is above the maximum 3 (allowed: 0 to 3)" in capsys.readouterr().err


def test_a_flag_models_share_gives_each_models_help(capsys):
    with pytest.raises(SystemExit):
        main(["train", "--model", "fast", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "model 'fast' and model 'splat': --sh-degree INT fast: spherical-harmonic degree" in out
    assert "(0, 1 or 2) (default: 1); splat: largest spherical-harmonic degree of the colour (0-3) (default: 3)" in out


def test_train_help_shows_the_model_named_before_it(capsys):
    # All three models' settings run to 400 lines: --help shows the training flags and how to
    # see a model's; after --model M it adds M's groups (a shared flag's group too), no other's.
    def help_of(*argv):
        with pytest.raises(SystemExit) as e:
            main(["train", *argv, "--help"])
        assert e.value.code == 0
        return capsys.readouterr().out

    plain = help_of()
    assert "--steps" in plain and "--n-samples" not in plain and "--resolutions" not in plain
    assert "nerfkit train --model splat --help" in plain
    vanilla = help_of("--model", "vanilla")
    assert "model 'vanilla':" in vanilla and "--n-samples" in vanilla
    assert "--resolutions" not in vanilla and "--sh-degree" not in vanilla and "--model splat --help" not in vanilla
    splat = help_of("--model", "splat")
    assert "--max-gaussians" in splat and "--sh-degree" in splat and "--n-samples" not in splat
    assert help_of() == plain  # the parser is left as it was


def _model_number_fields(model: str):
    import dataclasses
    import typing

    from nerfkit.config import base_type
    from nerfkit.models import model_config_class

    cls = model_config_class(model)
    hints = typing.get_type_hints(cls)
    return [
        (f.name, base_type(hints[f.name])[0], f.metadata)
        for f in dataclasses.fields(cls)
        if base_type(hints[f.name])[0] in (int, float) and f.metadata.get("cli") is not False
    ]


def _within(kind: type, meta):
    """The values a field's own bounds take."""
    from hypothesis import strategies as st

    low, above, high = meta.get("min"), meta.get("above"), meta.get("max")
    if kind is int:
        if above is not None:
            low = max(low, int(above) + 1) if low is not None else int(above) + 1  # the bounds here are whole
        return st.integers(low, high)
    exclusive = above is not None and (low is None or above >= low)
    return st.floats(above if exclusive else low, high, exclude_min=exclusive, allow_nan=False, allow_infinity=False)


@functools.cache
def _train_parser():
    from nerfkit.cli import build_parser

    return build_parser("train")


@pytest.mark.parametrize("model", ["vanilla", "fast", "splat"])
def test_no_flag_is_narrower_than_a_models_own_bounds(model):
    # Every value a model's config takes, the real `nerfkit train` parser takes for its flag: a flag
    # several models share is parsed within the widest of their bounds (check_config then checks the model's).
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from nerfkit.models import MODEL_NAMES

    assert model in MODEL_NAMES
    fields = _model_number_fields(model)
    assert fields

    @settings(max_examples=40, deadline=None)
    @given(st.tuples(*(_within(kind, meta) for _, kind, meta in fields)))
    def parsed(values):
        for (name, _, _), value in zip(fields, values):
            flag = "--" + name.replace("_", "-")
            # --flag=VALUE: argparse reads a lone -1e+16 as a flag
            assert getattr(_train_parser().parse_args(["train", f"{flag}={value}"]), name) == value, flag

    parsed()


@pytest.mark.parametrize(
    "flags, error",
    [
        (
            ["--model", "vanilla", "--sh-degree", "3"],
            "--sh-degree: is a setting of the fast and splat models, not of vanilla. Leave it out, or train with "
            "--model fast or --model splat",
        ),
        (
            ["--model", "splat", "--width", "64"],
            "--width: is a setting of the vanilla model, not of splat. Leave it out, or train with --model vanilla",
        ),
        (
            ["--model", "vanilla", "--no-learn-background"],
            "--learn-background: is a setting of the fast and splat models, not of vanilla. "
            "Leave it out, or train with --model fast or --model splat",
        ),
    ],
)
def test_a_flag_of_another_model_is_refused_before_anything_is_read_or_written(flags, error, tmp_path, capsys):
    # `--model vanilla --sh-degree 3` trained vanilla and dropped --sh-degree without a word
    data = tmp_path / "missing.npz"  # the flag is refused first: the dataset is not looked at
    assert main(["train", *flags, "--data", str(data), "--steps", "1", "--out", str(tmp_path / "run")]) == 2
    assert capsys.readouterr().err == f"nerfkit train: error: {error}\n"
    assert not (tmp_path / "run").exists()


def test_without_a_model_a_flag_the_datasets_model_does_not_take_is_refused(tmp_path, capsys):
    assert (
        main(["train", "--resolutions", "32,64", "--data", str(LEGO), "--steps", "1", "--out", str(tmp_path / "r")])
        == 2
    )
    assert capsys.readouterr().err == (
        "nerfkit train: error: --resolutions: is a setting of the fast model, not of splat (the default --model for "
        "an object dataset). Leave it out, or train with --model fast\n"
    )
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    "argv, error",
    [
        (
            ["capture", "photos/", "--tagsize", "0.06", "--out", "o"],  # argparse said: "required: --tag-size"
            "nerfkit capture: error: unrecognized argument --tagsize: did you mean --tag-size? (see nerfkit "
            "capture --help)",
        ),
        (
            ["--verbose", "train", "--data", "x.npz", "--stepz=3"],
            "nerfkit train: error: unrecognized argument --stepz: did you mean --steps? (see nerfkit train --help)",
        ),
        (
            ["render", "run", "--bogus", "1"],
            "nerfkit render: error: unrecognized argument --bogus (see nerfkit render --help)",
        ),
        (
            ["eval", "run", "--verbose"],
            "nerfkit eval: error: --verbose goes before the command: nerfkit --verbose eval ... (see nerfkit --help)",
        ),
        (
            ["--verbose", "pose", "photos/"],
            "nerfkit: error: unknown command 'pose': did you mean poses? (see nerfkit --help)",
        ),
        (
            ["photos/"],
            "nerfkit: error: unknown command 'photos/' (the commands: demo, capture, frames, train, render, eval, "
            "fit-image, convert, export, tags, calibrate, poses, dataset, view) (see nerfkit --help)",
        ),
        (
            ["capture", "photos/", "--tag-size", "0.06", "--out", "o", "--minutes", "1", "--steps", "9"],
            "nerfkit capture: error: argument --steps: not allowed with argument --minutes (see nerfkit capture "
            "--help)",
        ),
    ],
)
def test_an_unknown_flag_is_named_by_its_command_with_the_nearest_one(argv, error, capsys):
    assert main(argv) == 2
    assert capsys.readouterr().err == error + "\n"


def test_abbreviated_flags_and_values_after_a_double_dash_are_not_unknown(capsys):
    from nerfkit.cli import build_parser, unknown_option

    parser = build_parser("render")
    assert unknown_option(parser, ["render", "run", "--fram", "3"]) is None  # argparse takes --frames
    assert unknown_option(parser, ["render", "--", "--odd-run-name"]) is None
