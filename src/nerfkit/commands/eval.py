"""`nerfkit eval`: PSNR and SSIM of a trained run on a split, as JSON."""

from __future__ import annotations

import argparse

from ._common import add_run_args

HELP = "evaluate a trained run on held-out images (prints JSON)"
MEMORY_HINT = "Lower --chunk (rays rendered at once)"


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import number

    p = sub.add_parser("eval", help=HELP, description=HELP + ": mean psnr and ssim plus a per-image list; also "
                       "written to RUN/eval_<split>.json, with a contact sheet (photos beside renders) in "
                       "RUN/eval_<split>.png.")
    add_run_args(p)
    p.add_argument("--split", choices=["val", "test", "train"], default="val", help="which images (default: val)")
    p.add_argument("--fit-views", type=number(int, 0, 100_000), default=None, metavar="STEPS",
                   help="also score each view after fitting its pose to its photo with the scene frozen, for this "
                        "many steps, and then its colour correction (least squares; the run's model: an affine "
                        "colour transform, or a gain and offset per channel) (default: 100 for runs trained with "
                        "--capture, else 0: off; 0 for models that render whole views, such as splat)")
    p.set_defaults(func=run)


def write_contact_sheet(path, sheet: list, split: str) -> None:
    """Photo beside render (and beside the render after fitting pose and colour), a row per view,
    at the photos' own size (up to 640 pixels wide) so that sharpness can be judged."""
    from ..viz.plots import image_grid, native_tile_inches

    images, titles = [], []
    for photo, render, fitted, row in sheet:
        name = row["name"] or f"view {row['index']}"
        images += [photo, render]
        titles += [f"{name[:28]}", f"render {row['psnr']:.1f} dB"]
        if fitted is not None:
            images.append(fitted)
            titles.append(f"pose+colour fitted {row['psnr_fitted']:.1f} dB")
    if images:
        image_grid(path, images, titles, ncols=3 if sheet[0][2] is not None else 2,
                   suptitle=f"{split} photos and renders", tile_inches=native_tile_inches(images[0]))


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from ..errors import fail
    from ..io.atomic import write_json
    from ..tabletop import object_alone
    from ..train.evaluate import evaluate_views
    from ..train.view_corrections import ViewFitConfig
    from ._common import open_run, scene_for_run

    run_ = open_run(args)
    scene = scene_for_run(run_.info, args.data, need=args.split, allow_outside=args.allow_outside_paths)
    views = scene.splits[args.split]
    if not views.has_images:
        raise fail(scene.source, f"the {args.split} split has no images to compare with",
                   "Choose a split with images (--split val)")
    steps = args.fit_views
    whole = bool(getattr(run_.model, "whole_images", False))
    if whole and steps:
        raise fail("--fit-views", f"the {run_.info.train.model} model renders whole views, so a view's pose cannot be "
                   "fitted ray batch by ray batch", "Leave out --fit-views")
    capture = getattr(run_.info.train, "capture", "off") == "on"
    if steps is None:
        steps = 100 if capture and not whole else 0
        if whole and capture:
            print(f"note: held-out views are scored as rendered only ({run_.info.train.model} cannot fit their poses)")
    fit = ViewFitConfig(steps=steps, colour_mix=run_.info.train.colour_mix) if steps else None
    alone = object_alone(run_.model) if capture and not whole else None  # (a copy: memory for a second model)
    sheet: list = []
    result = {"split": args.split, "step": run_.step, "data": scene.source,
              **evaluate_views(run_.model, views, run_.background(), run_.chunk, run_.autocast, fit=fit,
                               scale=run_.info.bounds.radius, sheet=sheet,
                               alone=alone.model if alone is not None and alone.left_out else None)}
    write_json(Path(args.run) / f"eval_{args.split}.json", result)
    write_contact_sheet(Path(args.run) / f"eval_{args.split}.png", sheet, args.split)
    print(json.dumps(result, indent=2))
    return 0
