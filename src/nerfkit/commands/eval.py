"""`nerfkit eval`: PSNR and SSIM of a trained run on a split, as JSON."""

from __future__ import annotations

import argparse

from ._common import add_run_device_args, scene_for_run

HELP = "evaluate a trained run on held-out images (prints JSON)"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help=HELP, description=HELP + ": mean psnr and ssim plus a per-image list; also "
                       "written to RUN/eval_<split>.json.")
    p.add_argument("run", metavar="RUN", help="run folder written by `nerfkit train`")
    p.add_argument("--data", help="dataset (default: the one the run was trained on)")
    p.add_argument("--split", choices=["val", "test", "train"], default="val", help="which images (default: val)")
    add_run_device_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    import torch

    from ..errors import fail
    from ..io.atomic import write_json
    from ..train.checkpoint import load_run
    from ..train.config import parse_background, resolve_autocast, resolve_device
    from ..train.evaluate import evaluate_views

    device = resolve_device(args.device)
    model, info, step = load_run(args.run, device)
    scene = scene_for_run(info, args.data)
    views = scene.splits[args.split]
    if not views.has_images:
        raise fail(scene.source, f"the {args.split} split has no images to compare with",
                   "Choose a split with images (--split val)")
    bg = torch.tensor(parse_background(info.train.background), device=device)
    result = {"split": args.split, "step": step, "data": scene.source,
              **evaluate_views(model, views, bg, args.chunk or info.train.render_chunk, resolve_autocast(info.train.precision, device))}
    write_json(Path(args.run) / f"eval_{args.split}.json", result)
    print(json.dumps(result, indent=2))
    return 0
