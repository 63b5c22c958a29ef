"""`nerfkit train`: train a NeRF on a dataset, or resume a run."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys

from ..config import add_alternative_dataclass_args, add_dataclass_args, flag_of, foreign_flags
from .pipeline import RESUME_APPLIES
from .stages.train import summary_line

MEMORY_HINT = "Lower --batch-rays (rays per step) or --render-chunk (rays per rendered chunk)"
HELP = "train a NeRF on a dataset (or --resume a run)"
EPILOG = """\
examples:
  nerfkit train --data scene.npz --out runs/mine --minutes 5
  nerfkit train --config runs/mine/config.json --out runs/again    the same settings again
  nerfkit train --resume runs/mine              continue after a crash or Ctrl-C
A run folder holds config.json (every setting, as resolved), model.pt, metrics, plots and videos.
Unless given, the dataset's kind (object, capture, forward-facing) picks settings (nerfkit.presets).
"""
USAGE = """nerfkit train --data PATH [--out DIR] [--model {vanilla,fast,splat}] \
[--steps INT | --minutes FLOAT] [options]
       nerfkit train --config RUN/config.json [--out DIR] [options]
       nerfkit train --resume RUN [--steps INT | --minutes FLOAT]"""
MODEL_GROUP = "model '{}'"
MODEL_BLURBS = {"fast": "the grid", "vanilla": "the course's 8x256 MLP", "splat": "Gaussian splats"}
# the TrainConfig group the short --help shows (with -h, --help-all, --resume and --config)
FIRST_GROUP = "the options changed first"


class ModelHelp(argparse.Action):
    """``-h/--help``: the options changed first, and where the rest are; after a ``--model M``,
    every training option and M's settings. ``--help-all``: every option of every model."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        which = "all" if option_string == "--help-all" else getattr(namespace, "model", None)
        parser._print_message(help_for_model(parser, which), sys.stdout)
        parser.exit()


def help_for_model(parser: argparse.ArgumentParser, model: str | None) -> str:
    """``parser``'s help: for None the short one (the parser's own options and the options
    changed first, and the commands that show the rest); for a model name, every training
    group and that model's groups of model flags; for "all", every group."""
    groups = parser._action_groups
    if model is None:
        mine = [g for g in groups if g.title in ("options", FIRST_GROUP)]
    else:
        mine = [
            g
            for g in groups
            if not (g.title or "").startswith("model '")
            or model == "all"
            or MODEL_GROUP.format(model) in (g.title or "")
        ]
    epilog = parser.epilog
    if model is None:
        assert epilog is not None  # the parser's own, EPILOG
        epilog += (
            "\nthe other options, by group (data, optimisation, evaluation, real captures, the model's):\n"
            + "".join(
                f"  {f'nerfkit train --model {m} --help':38s}{MODEL_BLURBS.get(m, '')}\n"
                for m in _model_config_classes()
            )
            + f"  {'nerfkit train --help-all':38s}every model's\n"
        )
    parser._action_groups, parser.epilog = mine, epilog
    try:
        return parser.format_help()
    finally:
        parser._action_groups, parser.epilog = groups, EPILOG


def _model_config_classes():
    from ..models import MODEL_NAMES, model_config_class

    out = {}
    for name in MODEL_NAMES:
        with contextlib.suppress(ImportError):  # a model whose optional parts are missing
            out[name] = model_config_class(name)
    return out


def register(sub: argparse._SubParsersAction) -> None:
    from ..train.config import TrainConfig

    p = sub.add_parser(
        "train",
        help=HELP,
        description=HELP,
        epilog=EPILOG,
        usage=USAGE,
        add_help=False,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "-h",
        "--help",
        action=ModelHelp,
        help="show the options changed first and exit; after --model M, every option of M",
    )
    p.add_argument("--help-all", action=ModelHelp, help="show every option of every model and exit")
    p.add_argument(
        "--resume",
        metavar="RUN",
        help="continue this run from its newest good checkpoint (--minutes: its total; timed runs resume inexactly)",
    )
    p.add_argument(
        "--config",
        metavar="JSON",
        help="start from the settings of this run's config.json (a run "
        "folder names its own); options given beside it change them",
    )
    add_dataclass_args(p, TrainConfig, "training")
    from ..presets import kind_default_help  # (here: the top-level --help imports no torch)

    # a flag that models share (--sh-degree) takes the widest of their bounds; run() checks the chosen model's
    add_alternative_dataclass_args(p, _model_config_classes(), MODEL_GROUP, kind_default_help)
    p.set_defaults(func=run)


# TrainConfig fields that --resume applies to the continued run (the others would change
# what the run is, so they are refused): the stopping rule, where and how often to save.


def resume_changes(args: argparse.Namespace) -> dict:
    """The flags given with --resume as TrainConfig changes; refuses the ones it cannot apply."""
    from ..errors import fail
    from ..train.config import TrainConfig

    given = {f.name for f in dataclasses.fields(TrainConfig) if getattr(args, f.name, None) is not None}
    for cls in _model_config_classes().values():
        given |= {f.name for f in dataclasses.fields(cls) if getattr(args, f.name, None) is not None}
    refused = sorted(given - set(RESUME_APPLIES) - {"data", "allow_outside_paths"})
    if refused:
        flags = ", ".join(flag_of(k) for k in refused)
        raise fail(
            "--resume",
            f"{flags} cannot change when a run continues (the run keeps its own settings)",
            "Resume without them, or start a new run with another --out; --resume applies only "
            + ", ".join(flag_of(k) for k in RESUME_APPLIES),
        )
    return {k: getattr(args, k) for k in RESUME_APPLIES if k in given}


def refuse_other_models_flags(args: argparse.Namespace, classes: dict, model: str) -> None:
    """Refuse a model flag that ``model`` does not take (training would ignore it), e.g.
    ``--sh-degree: is a setting of the fast and splat models, not of vanilla``."""
    from ..errors import fail

    foreign = foreign_flags(args, classes, model)
    if foreign:
        flag, owners = foreign[0]
        chosen = model if args.model else f"{model} (the default --model)"
        which = (
            f"the {owners[0]} model" if len(owners) == 1 else f"the {', '.join(owners[:-1])} and {owners[-1]} models"
        )
        raise fail(
            flag,
            f"is a setting of {which}, not of {chosen}",
            f"Leave it out, or train with --model {' or --model '.join(owners)}",
        )


def given_flags(args: argparse.Namespace, *classes: type) -> set[str]:
    """The fields of ``classes`` whose flag the command line gave (the user's choices, which the
    scene kind's preset never overrides)."""
    return {f.name for cls in classes for f in dataclasses.fields(cls) if getattr(args, f.name, None) is not None}


def run(args: argparse.Namespace) -> int:
    from ..errors import fail
    from ..train.checkpoint import read_run
    from ..train.config import TrainConfig
    from . import pipeline as api

    if args.resume:
        if args.config:
            raise fail(
                "--config",
                "cannot be given with --resume (a run continues with its own settings)",
                "Resume without --config, or start a new run from it with --out",
            )
        changes = resume_changes(args)
        info = read_run(args.resume)
        for k, v in changes.items():
            print(f"resuming with {flag_of(k)} {v} (was {getattr(info.train, k)})", file=sys.stderr)
        result = api.resume(args.resume, data=args.data, allow_outside_paths=bool(args.allow_outside_paths), **changes)
    else:
        classes = _model_config_classes()
        model = args.model
        if model is None and args.config:
            from ..train.checkpoint import read_settings

            model = read_settings(args.config)[0].model
        if model is not None:
            if model not in classes:
                raise fail(
                    "--model",
                    f"model '{model}' is not available in this installation",
                    f"Choose one of: {', '.join(classes)}",
                )
            refuse_other_models_flags(args, classes, model)
        # no model named: train() chooses the dataset kind's, or the one the model flags given belong to
        chosen = [classes[model]] if model is not None else list(classes.values())
        given = {name: getattr(args, name) for name in given_flags(args, TrainConfig, *chosen)}
        result = api.train(config=args.config, **given)
    print(summary_line(result))
    return 130 if result.interrupted else 0
