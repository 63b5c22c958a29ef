"""`nerfkit train`: train a NeRF on a dataset, or resume a run."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from ..config import add_alternative_dataclass_args, add_dataclass_args, dataclass_from_args, flag_of, foreign_flags

MEMORY_HINT = "Lower --batch-rays (rays per step) or --render-chunk (rays per rendered chunk)"
HELP = "train a NeRF on a dataset (or --resume a run)"
EPILOG = """\
examples:
  nerfkit train --data scene.npz --out runs/mine --minutes 5
  nerfkit train --data src/nerfkit/assets/lego_200x200.npz --model vanilla --steps 6000 --out runs/vanilla
  nerfkit train --resume runs/mine              continue after a crash or Ctrl-C
The run folder gets config.json, checkpoints/, metrics.csv/json, plots/ and progress/.
"""
USAGE = """nerfkit train --data PATH [--out DIR] [--model {vanilla,fast,splat}] [--steps INT | --minutes FLOAT] [options]
       nerfkit train --resume RUN [--steps INT | --minutes FLOAT]"""
MODEL_GROUP = "model '{}'"
MODEL_BLURBS = {"fast": "the grid (the default model)", "vanilla": "the course's 8x256 MLP", "splat": "Gaussian splats"}


class ModelHelp(argparse.Action):
    """``-h/--help``: the training flags, and the settings of the model named by a ``--model``
    before it; without one, how to see each model's (all of them run to 400 lines)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        parser._print_message(help_for_model(parser, getattr(namespace, "model", None)), sys.stdout)
        parser.exit()


def help_for_model(parser: argparse.ArgumentParser, model: str | None) -> str:
    """``parser``'s help with only ``model``'s groups of model flags; for None, none of them,
    and the epilog names the command that shows each model's."""
    groups = parser._action_groups
    mine = [g for g in groups if not (g.title or "").startswith("model '")
            or (model is not None and MODEL_GROUP.format(model) in g.title)]
    epilog = parser.epilog
    if model is None:
        epilog += "\neach model's own settings:\n" + "".join(
            f"  {f'nerfkit train --model {m} --help':38s}{MODEL_BLURBS.get(m, '')}\n" for m in _model_config_classes())
    parser._action_groups, parser.epilog = mine, epilog
    try:
        return parser.format_help()
    finally:
        parser._action_groups, parser.epilog = groups, EPILOG


def _model_config_classes():
    from ..models import MODEL_NAMES, model_config_class

    out = {}
    for name in MODEL_NAMES:
        try:
            out[name] = model_config_class(name)
        except ImportError:  # a model whose optional parts are missing
            pass
    return out


def register(sub: argparse._SubParsersAction) -> None:
    from ..train.config import TrainConfig

    p = sub.add_parser("train", help=HELP, description=HELP, epilog=EPILOG, usage=USAGE, add_help=False,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-h", "--help", action=ModelHelp,
                   help="show the training flags and exit; after --model M, M's settings too")
    p.add_argument("--resume", metavar="RUN", help="continue this run from its newest good checkpoint")
    add_dataclass_args(p, TrainConfig, "training")
    # a flag that models share (--sh-degree) takes the widest of their bounds; run() checks the chosen model's
    add_alternative_dataclass_args(p, _model_config_classes(), MODEL_GROUP)
    p.set_defaults(func=run)


# TrainConfig fields that --resume applies to the continued run (the others would change
# what the run is, so they are refused): the stopping rule, where and how often to save.
RESUME_APPLIES = ("steps", "minutes", "device", "checkpoint_seconds", "keep_checkpoints", "eval_every", "eval_views",
                  "eval_pixels", "render_chunk")


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
        raise fail("--resume", f"{flags} cannot change when a run continues (the run keeps its own settings)",
                   "Resume without them, or start a new run with another --out; --resume applies only "
                   + ", ".join(flag_of(k) for k in RESUME_APPLIES))
    return {k: getattr(args, k) for k in RESUME_APPLIES if k in given}


def refuse_other_models_flags(args: argparse.Namespace, classes: dict, model: str) -> None:
    """Refuse a model flag that ``model`` does not take (training would ignore it), e.g.
    ``--sh-degree: is a setting of the fast and splat models, not of vanilla``."""
    from ..errors import fail

    foreign = foreign_flags(args, classes, model)
    if foreign:
        flag, owners = foreign[0]
        chosen = model if args.model else f"{model} (the default --model)"
        which = (f"the {owners[0]} model" if len(owners) == 1
                 else f"the {', '.join(owners[:-1])} and {owners[-1]} models")
        raise fail(flag, f"is a setting of {which}, not of {chosen}",
                   f"Leave it out, or train with --model {' or --model '.join(owners)}")


def run(args: argparse.Namespace) -> int:
    from ..errors import fail
    from ..models import check_config
    from ..train.checkpoint import read_run
    from ..train.config import TrainConfig
    from ..train.trainer import check_new_run_folder, resume, train
    from ._common import load_as_trained

    if args.resume:
        changes = resume_changes(args)
        info = read_run(args.resume)
        for k, v in changes.items():
            print(f"resuming with {flag_of(k)} {v} (was {getattr(info.train, k)})", file=sys.stderr)
        data = args.data or info.train.data
        scene = load_as_trained(info.train, data,
                                allow_outside=bool(args.allow_outside_paths or info.train.allow_outside_paths))
        result = resume(args.resume, scene, changes=changes)
    else:
        cfg = dataclass_from_args(TrainConfig, args)
        if not cfg.data:
            raise fail("train", "no dataset given", "Pass --data FILE (try the bundled "
                       "src/nerfkit/assets/lego_200x200.npz, or run `nerfkit demo`)")
        if cfg.steps == 0 and cfg.minutes == 0:
            cfg = dataclasses.replace(cfg, minutes=5.0)
            print("no --steps or --minutes: training for 5 minutes", file=sys.stderr)
        classes = _model_config_classes()
        if cfg.model not in classes:
            raise fail("--model", f"model '{cfg.model}' is not available in this installation",
                       f"Choose one of: {', '.join(classes)}")
        refuse_other_models_flags(args, classes, cfg.model)
        model_cfg = check_config(cfg.model, dataclass_from_args(classes[cfg.model], args))  # its own bounds
        check_new_run_folder(Path(cfg.out))  # before loading the dataset: a refusal should be quick
        # RGBA images are composited on the colour the model renders behind the scene
        result = train(load_as_trained(cfg, cfg.data, allow_outside=cfg.allow_outside_paths), cfg, model_cfg)
    summary = f"run: {result.run_dir}  steps: {result.step}  training time: {result.train_seconds:.0f} s"
    if result.final_val_psnr is not None:
        summary += f"  val PSNR: {result.final_val_psnr:.2f} dB"
    print(summary)
    return 130 if result.interrupted else 0
