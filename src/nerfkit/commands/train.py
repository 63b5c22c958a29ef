"""`nerfkit train`: train a NeRF on a dataset, or resume a run."""

from __future__ import annotations

import argparse
import dataclasses

from ..config import add_dataclass_args, dataclass_from_args

HELP = "train a NeRF on a dataset (or --resume a run)"
EPILOG = """\
examples:
  nerfkit train --data scene.npz --out runs/mine --minutes 5
  nerfkit train --data src/nerfkit/assets/lego_200x200.npz --model vanilla --steps 20000 --out runs/vanilla
  nerfkit train --resume runs/mine              continue after a crash or Ctrl-C
The run folder gets config.json, checkpoints/, metrics.csv/json, plots/ and progress/.
"""


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

    p = sub.add_parser("train", help=HELP, description=HELP, epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--resume", metavar="RUN", help="continue this run from its newest good checkpoint")
    add_dataclass_args(p, TrainConfig, "training")
    for name, cls in _model_config_classes().items():
        add_dataclass_args(p, cls, f"model '{name}'")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..data.load import load_scene
    from ..errors import fail
    from ..train.checkpoint import read_run
    from ..train.config import TrainConfig
    from ..train.trainer import resume, train

    if args.resume:
        info = read_run(args.resume)
        result = resume(args.resume, load_scene(args.data or info.train.data), steps=args.steps, minutes=args.minutes)
    else:
        cfg = dataclass_from_args(TrainConfig, args)
        if not cfg.data:
            raise fail("train", "no dataset given", "Pass --data FILE (try the bundled "
                       "src/nerfkit/assets/lego_200x200.npz, or run `nerfkit demo`)")
        if cfg.steps == 0 and cfg.minutes == 0:
            cfg = dataclasses.replace(cfg, minutes=5.0)
        classes = _model_config_classes()
        if cfg.model not in classes:
            raise fail("--model", f"model '{cfg.model}' is not available in this installation",
                       f"Choose one of: {', '.join(classes)}")
        model_cfg = dataclass_from_args(classes[cfg.model], args)
        result = train(load_scene(cfg.data), cfg, model_cfg)
    summary = f"run: {result.run_dir}  steps: {result.step}  training time: {result.train_seconds:.0f} s"
    if result.final_val_psnr is not None:
        summary += f"  val PSNR: {result.final_val_psnr:.2f} dB"
    print(summary)
    return 130 if result.interrupted else 0
