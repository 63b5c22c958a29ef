"""Config bounds are declared once (``option(..., min=, max=, above=)``) and checked alike
where a config comes from: the command line (``number``), Python, or a run's config.json
(``check_ranges``)."""

from __future__ import annotations

import argparse
import dataclasses
import typing

import numpy as np
import pytest

from nerfkit.config import (
    add_alternative_dataclass_args,
    add_dataclass_args,
    base_type,
    check_ranges,
    dataclass_from_dict,
    flag_type,
    option,
    widest_bounds,
)
from nerfkit.errors import NerfkitError


def bounds():
    from nerfkit.models.base import SceneBounds

    return SceneBounds(2.0, 6.0, np.zeros(3, np.float32), 1.0, np.array([0, 0, 1], np.float32))


def vanilla(**kw):
    from nerfkit.models.vanilla import VanillaConfig, VanillaNeRF

    return VanillaNeRF(VanillaConfig(**kw), bounds())


def fast(**kw):
    from nerfkit.models.fast import FastConfig, FastNeRF

    return FastNeRF(FastConfig(**kw), bounds())


def splat(**kw):
    from nerfkit.models.splat import SplatConfig

    return SplatConfig(**kw).validate()


def train(**kw):
    from nerfkit.train.config import TrainConfig

    return TrainConfig(steps=1, **kw).validate()


def fit_image(**kw):
    from nerfkit.fit_image import FitImageConfig, validate_config

    return validate_config(FitImageConfig(**kw))


@pytest.mark.parametrize(
    "build, kw, message",
    [
        (vanilla, {"width": 0}, "--width: 0 is below the minimum 1 (allowed: 1 to 4096)"),
        (vanilla, {"n_samples": 5000}, "--n-samples: 5000 is above the maximum 4096 (allowed: 1 to 4096)"),
        (vanilla, {"width": 64.0}, "--width: '64.0' is not a whole number"),
        (vanilla, {"depth": True}, "--depth: 'True' is not a whole number"),
        (fast, {"sh_degree": 3}, "--sh-degree: 3 is above the maximum 2 (allowed: 0 to 2)"),
        (fast, {"step_ratio": -1.0}, "--step-ratio: -1.0 is below the minimum 0.01 (allowed: 0.01 to 4.0)"),
        # no table in the scene: the texture size was only checked when a table was built
        (fast, {"table_resolution": 1}, "--table-resolution: 1 is below the minimum 2 (allowed: 2 to 4096)"),
        (splat, {"sh_degree": 4}, "--sh-degree: 4 is above the maximum 3 (allowed: 0 to 3)"),
        (splat, {"init_opacity": 1.0}, "--init-opacity: 1.0 is above the maximum 0.99 (allowed: above 0, up to 0.99)"),
        (train, {"lr": 200.0}, "--lr: 200.0 is above the maximum 100 (allowed: 0 to 100)"),
        (train, {"minutes": float("nan")}, "--minutes: 'nan' is not a finite number"),
        (train, {"checkpoint_seconds": 0.0}, "--checkpoint-seconds: 0.0 must be greater than 0"),
        (train, {"seed": -1}, "--seed: -1 is below the minimum 0 (allowed: 0 to 4294967295)"),
        (fit_image, {"L": 31}, "--L: 31 is above the maximum 30 (allowed: 0 to 30)"),
        (fit_image, {"lr": float("inf")}, "--lr: 'inf' is not a finite number"),
    ],
)
def test_a_config_built_in_python_is_refused_naming_the_flag(build, kw, message):
    with pytest.raises(NerfkitError) as e:
        build(**kw)
    assert str(e.value) == message


def test_values_in_range_pass():
    from nerfkit.models.fast import FastConfig
    from nerfkit.train.config import TrainConfig

    cfg = FastConfig(sh_degree=0, room_shells=0, distortion_weight=0.0, step_ratio=0.01)  # (no unset sentinels now)
    assert check_ranges(cfg) is cfg
    assert train(lr=100, lr_final_factor=1, seed=2**32 - 1).lr == 100
    with pytest.raises(NerfkitError, match="no stopping rule"):  # the rule across fields is kept
        TrainConfig().validate()
    with pytest.raises(NerfkitError, match="--densify-from: must not be after --densify-until"):
        splat(densify_from=0.6, densify_until=0.5)


def test_a_config_read_from_json_is_refused_naming_the_file_and_the_flag():
    from nerfkit.models.vanilla import VanillaConfig

    with pytest.raises(NerfkitError) as e:
        dataclass_from_dict(VanillaConfig, {"n_samples": 64, "pos_freqs": 40}, "run/config.json")
    assert str(e.value) == "run/config.json: 'pos_freqs' (--pos-freqs): 40 is above the maximum 32 (allowed: 0 to 32)"
    assert dataclass_from_dict(VanillaConfig, {"pos_freqs": 32}, "run/config.json").pos_freqs == 32


def config_classes():
    from nerfkit.capture.calibrate import CalibrateConfig
    from nerfkit.capture.dataset import DatasetConfig
    from nerfkit.capture.poses import PoseConfig
    from nerfkit.fit_image import FitImageConfig
    from nerfkit.models import MODEL_NAMES, model_config_class
    from nerfkit.train.config import TrainConfig

    return [
        TrainConfig,
        CalibrateConfig,
        DatasetConfig,
        PoseConfig,
        FitImageConfig,
        *(model_config_class(name) for name in MODEL_NAMES),
    ]


def out_of_range(kind: type, meta) -> list:
    """Values just outside a field's bounds, one per bounded end (never the value that switches
    the option off)."""
    step = 1 if kind is int else 0.5
    ends = []
    if meta.get("min") is not None:
        ends.append(kind(meta["min"] - step))
    elif meta.get("above") is not None:
        ends.append(kind(meta["above"]))
    if meta.get("max") is not None:
        ends.append(kind(meta["max"] + step))
    return [v for v in ends if v != meta.get("off")]


def test_the_parser_and_check_ranges_word_every_bound_alike():
    checked = 0
    for cls in config_classes():
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            kind = base_type(hints[f.name])[0]
            if kind not in (int, float) or not {"min", "max", "above"} & set(f.metadata):
                continue
            for value in out_of_range(kind, f.metadata):
                with pytest.raises(argparse.ArgumentTypeError) as parsed:
                    flag_type(cls, f.name)(str(value))
                default = cls()  # every field has a default
                with pytest.raises(NerfkitError) as checked_error:
                    check_ranges(dataclasses.replace(default, **{f.name: value}))
                flag = "--" + f.name.replace("_", "-")
                assert str(checked_error.value) == f"{flag}: {parsed.value}", cls.__name__
                checked += 1
    assert checked > 80  # both ends of every config's bounded fields were seen


def test_the_command_line_and_a_config_built_in_python_give_the_same_line(capsys):
    from nerfkit.cli import main

    assert main(["train", "--data", "x.npz", "--steps", "1", "--lr", "200"]) == 2
    err = capsys.readouterr().err.strip()
    with pytest.raises(NerfkitError) as e:
        train(lr=200)
    assert err == f"nerfkit train: error: argument {e.value} (see nerfkit train --help)"


@pytest.mark.parametrize(
    "metas, widest",
    [
        ([{"min": 0, "max": 2}, {"min": 0, "max": 3}], {"min": 0, "max": 3}),  # --sh-degree: fast and splat
        ([{"min": 1}, {"min": -1, "max": 5}], {"min": -1}),  # no upper end where one has none
        ([{"above": 0, "max": 1}, {"min": 0, "max": 0.5}], {"min": 0, "max": 1}),  # a tie: the inclusive end
        ([{"above": 0}, {"above": -1}], {"above": -1}),
        ([{"min": 0, "above": 1}, {"min": 2}], {"above": 1}),  # a field's lower end is the stricter of its two
        ([{"max": 4}, {}], {}),
    ],
)
def test_widest_bounds_take_every_value_any_field_takes(metas, widest):
    assert widest_bounds(metas) == widest


@dataclasses.dataclass
class _Low:
    level: int = option(1, "level of low", min=0, max=2)
    shared_text: bool = option(False, "the same help")


@dataclasses.dataclass
class _High:
    level: int = option(3, "level of high", min=1, max=3)
    shared_text: bool = option(False, "the same help")


def test_a_shared_flag_takes_the_widest_bounds_and_each_ones_help():
    parser = argparse.ArgumentParser()
    add_alternative_dataclass_args(parser, {"low": _Low, "high": _High}, "config '{}'")
    assert parser.parse_args(["--level", "3"]).level == 3
    assert parser.parse_args(["--level", "0"]).level == 0
    with pytest.raises(SystemExit):
        parser.parse_args(["--level", "4"])
    help_text = parser.format_help()
    assert "config 'low' and config 'high':" in help_text
    assert "low: level of low (default: 1); high: level of high (default: 3)" in " ".join(help_text.split())
    assert "the same help (default: False)" in " ".join(help_text.split())  # one help where they agree
    with pytest.raises(NerfkitError) as e:  # the chosen config's own bounds
        check_ranges(_Low(level=3), owner="the low config")
    assert str(e.value) == "--level: 3 is above the maximum 2 (allowed: 0 to 2) for the low config"


def test_configs_sharing_a_flag_must_agree_on_its_type_and_choices():
    @dataclasses.dataclass
    class Other:
        level: float = option(0.5, "a float level")

    with pytest.raises(TypeError, match="--level: low, other give it different types or choices"):
        add_alternative_dataclass_args(argparse.ArgumentParser(), {"low": _Low, "other": Other}, "{}")
    # separate configs' flags must not meet: the later one's bounds would be lost
    parser = argparse.ArgumentParser()
    add_dataclass_args(parser, _Low)
    with pytest.raises(argparse.ArgumentError, match="conflicting option string: --level"):
        add_dataclass_args(parser, _High)


def test_an_off_value_is_allowed_beside_the_range():
    """train --downscale: 0 keeps the images' size, 1 or more divides it; 0.5 is neither."""
    from nerfkit.train.config import TrainConfig

    parse = flag_type(TrainConfig, "downscale")
    assert parse("0") == 0 and parse("1") == 1 and parse("4") == 4
    with pytest.raises(argparse.ArgumentTypeError, match=r"^0.5 is below the minimum 1 \(or 0: off\)$"):
        parse("0.5")
    assert check_ranges(TrainConfig(steps=1, downscale=0.0)).downscale == 0
    with pytest.raises(NerfkitError, match=r"^--downscale: 0.5 is below the minimum 1 \(or 0: off\)$"):
        check_ranges(TrainConfig(steps=1, downscale=0.5))


@pytest.mark.parametrize(
    "command", [["calibrate", "calib/"], ["poses", "photos/", "--out", "o"], ["capture", "photos/", "--out", "o"]]
)
def test_a_tag_size_in_millimetres_is_refused_with_the_metres_it_meant(command, capsys):
    from nerfkit.cli import main
    from nerfkit.config import TAG_SIDE_MAX, tag_side

    assert main([*command, "--tag-size", "60"]) == 2  # refused before any photo is read
    err = capsys.readouterr().err
    assert "60 mm is 0.06, 60 cm is 0.6" in err and f"nerfkit {command[0]} --help" in err
    assert tag_side("0.06") == 0.06 and tag_side(str(TAG_SIDE_MAX)) == TAG_SIDE_MAX
    for text, hint in (("1e3", ": 1e3 mm is 1"), ("5000", ")")):  # only the lengths it takes
        with pytest.raises(argparse.ArgumentTypeError) as e:
            tag_side(text)
        assert str(e.value).endswith(hint) and "cm" not in str(e.value)
    for bad in ("0", "-0.06", "nan"):
        with pytest.raises(argparse.ArgumentTypeError):
            tag_side(bad)


def test_a_switch_is_one_flag_that_switches_its_default():
    """A yes/no field marked ``switch`` is one flag with the field's help: ``--no-crop`` for
    export's ``crop`` (True by default), ``--object`` for render's ``object`` (False); not
    given, it is None and the dataclass' default stands."""
    from nerfkit.config import dataclass_from_args

    @dataclasses.dataclass
    class Cut:
        crop: bool = option(True, "keep points outside the box (100%)", switch=True)
        alone: bool = option(False, "the object alone", switch=True)

    parser = argparse.ArgumentParser()
    add_dataclass_args(parser, Cut)
    assert dataclass_from_args(Cut, parser.parse_args([])) == Cut(crop=True, alone=False)
    assert parser.parse_args([]).crop is None
    assert dataclass_from_args(Cut, parser.parse_args(["--no-crop", "--alone"])) == Cut(crop=False, alone=True)
    for wrong in ("--crop", "--no-alone"):
        with pytest.raises(SystemExit):
            parser.parse_args([wrong])
    shown = parser.format_help()
    assert "keep points outside the box (100%)" in shown and "default" not in shown


def test_a_field_parsed_by_its_own_type_is_checked_by_it_everywhere(capsys):
    """A field with ``parse`` metadata (an argparse type: tags' ``--tag-size``, ``tag_side``) is
    parsed by it on the command line, and a value given otherwise is checked by it too
    (:func:`check_ranges`), in its words; the field's bounds are not looked for."""
    from nerfkit.config import tag_side

    @dataclasses.dataclass
    class Sheet:
        side: float = option(0.05, "a tag's side in metres", parse=tag_side)

    parser = argparse.ArgumentParser()
    add_dataclass_args(parser, Sheet)
    assert parser.parse_args(["--side", "0.04"]).side == 0.04
    with pytest.raises(SystemExit):
        parser.parse_args(["--side", "60"])
    assert "60 mm is 0.06" in capsys.readouterr().err
    assert check_ranges(Sheet(0.1)) == Sheet(0.1)
    with pytest.raises(NerfkitError, match=r"--side: 60 is not a printed tag's side .*60 mm is 0.06"):
        check_ranges(Sheet(60))
    with pytest.raises(NerfkitError, match="--side: 'x' is not a number"):
        check_ranges(Sheet("x"))  # type: ignore[arg-type]


def test_a_field_may_have_a_flag_of_another_name():
    """A field with ``flag`` metadata (tags' ``dictionary``) is that flag, read into the field
    (:func:`dataclass_from_args`); a wrong value of it is named by that flag."""
    from nerfkit.config import check_values, dataclass_from_args

    @dataclasses.dataclass
    class Tags:
        dictionary: str = option("DICT_4X4_50", "ArUco dictionary", flag="--dict", metavar="DICT")
        count: int = option(4, "tags", min=1, flag="--n")

    parser = argparse.ArgumentParser()
    add_dataclass_args(parser, Tags)
    assert dataclass_from_args(Tags, parser.parse_args(["--dict", "DICT_5X5_50"])) == Tags("DICT_5X5_50")
    assert "--dict DICT" in parser.format_help() and "--dictionary" not in parser.format_help()
    with pytest.raises(SystemExit):
        parser.parse_args(["--dictionary", "DICT_5X5_50"])
    with pytest.raises(NerfkitError, match="--dict: 3 is not text"):
        check_values(Tags, {"dictionary": 3})
    with pytest.raises(NerfkitError, match="--n: 0 is below the minimum 1"):
        check_ranges(Tags(count=0))


def test_the_fields_of_an_exclusive_set_are_one_flag_at_most(capsys):
    """Fields sharing an ``exclusive`` name (convert's ``--size`` and ``--downscale``) are
    mutually exclusive flags, and :func:`check_exclusive` refuses both given otherwise (a field
    at its default is not given), naming the later by the earlier, as argparse does."""
    from nerfkit.config import check_exclusive, dataclass_from_args

    @dataclasses.dataclass
    class Resize:
        size: int | None = option(None, "longest side", min=1, exclusive="size", metavar="PX")
        downscale: float | None = option(
            None, "divide by", min=1, exclusive="size", exclusive_fix="Resize one way", metavar="F"
        )
        quality: int = option(95, "JPEG quality", min=1, max=100)

    parser = argparse.ArgumentParser()
    add_dataclass_args(parser, Resize)
    assert "[--size PX | --downscale F]" in parser.format_usage()
    assert dataclass_from_args(Resize, parser.parse_args(["--downscale", "2"])) == Resize(downscale=2.0)
    with pytest.raises(SystemExit):
        parser.parse_args(["--size", "200", "--downscale", "2"])
    assert "--downscale: not allowed with argument --size" in capsys.readouterr().err
    assert check_exclusive(Resize(size=200, quality=90)) == Resize(size=200, quality=90)
    with pytest.raises(NerfkitError, match="--downscale: not allowed with --size. Resize one way"):
        check_exclusive(Resize(size=200, downscale=2.0))
