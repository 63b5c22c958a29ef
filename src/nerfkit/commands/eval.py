"""`nerfkit eval`: PSNR and SSIM of a trained run on a split, as JSON."""

from __future__ import annotations

import argparse

from ._common import add_run_args

HELP = "evaluate a trained run on held-out images (prints JSON)"
MEMORY_HINT = "Lower --chunk (rays rendered at once)"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help=HELP, description=HELP + ": mean psnr and ssim plus a per-image list; also "
                       "written to RUN/eval_<split>.json.")
    add_run_args(p)
    p.add_argument("--split", choices=["val", "test", "train"], default="val", help="which images (default: val)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from ..errors import fail
    from ..io.atomic import write_json
    from ..train.evaluate import evaluate_views
    from ._common import open_run, scene_for_run

    run_ = open_run(args)
    scene = scene_for_run(run_.info, args.data, need=args.split, allow_outside=args.allow_outside_paths)
    views = scene.splits[args.split]
    if not views.has_images:
        raise fail(scene.source, f"the {args.split} split has no images to compare with",
                   "Choose a split with images (--split val)")
    result = {"split": args.split, "step": run_.step, "data": scene.source,
              **evaluate_views(run_.model, views, run_.background(), run_.chunk, run_.autocast)}
    write_json(Path(args.run) / f"eval_{args.split}.json", result)
    print(json.dumps(result, indent=2))
    return 0
