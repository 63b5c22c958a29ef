"""`nerfkit eval`: PSNR and SSIM of a trained run on a split, printed and written as JSON."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, cast

from ._common import add_run_args

if TYPE_CHECKING:
    from ..models.base import NerfModel

HELP = "evaluate a trained run on held-out images: PSNR and SSIM"
MEMORY_HINT = "Lower --chunk (rays rendered at once)"


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import number

    p = sub.add_parser(
        "eval",
        help=HELP,
        description=HELP + ". Prints the means and each view's scores, and "
        "writes them to RUN/eval_<split>.json (with each view's fitted pose and colour for a capture), "
        "with a contact sheet (photos beside renders) in RUN/eval_<split>.png.",
    )
    add_run_args(p)
    p.add_argument("--split", choices=["val", "test", "train"], default="val", help="which images (default: val)")
    p.add_argument(
        "--fit-views",
        type=number(int, 0, 100_000),
        default=None,
        metavar="STEPS",
        help="also score each view after fitting its pose to its photo with the scene frozen, for this "
        "many steps, and then each half of the photo with a gain and offset per channel solved on "
        "the other half (least squares; NeRF-W's protocol, both ways) (default: 100 for runs "
        "trained with --capture, else 0: off; 0 for models that render whole views, such as splat)",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print the JSON that RUN/eval_<split>.json holds instead of the summary (for scripts)",
    )
    p.set_defaults(func=run)


def write_contact_sheet(path, sheet: list, split: str) -> None:
    """Photo beside render (and beside the render with its pose fitted and each half's colour
    solved on the other half), a row per view,
    at the photos' own size (up to 640 pixels wide) so that sharpness can be judged."""
    from ..viz.plots import image_grid, native_tile_inches

    images, titles = [], []
    for photo, render, fitted, row in sheet:
        name = row["name"] or f"view {row['index']}"
        images += [photo, render]
        titles += [f"{name[:28]}", f"render {row['psnr']:.1f} dB"]
        if fitted is not None:
            images.append(fitted)
            titles.append(f"pose fitted, colour from the other half {row['psnr_fitted']:.1f} dB")
    if images:
        image_grid(
            path,
            images,
            titles,
            ncols=3 if sheet[0][2] is not None else 2,
            suptitle=f"{split} photos and renders",
            tile_inches=native_tile_inches(images[0]),
        )


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from ..errors import fail
    from ..io.atomic import write_json
    from ..surroundings import object_alone
    from ..train.evaluate import evaluate_views
    from ..train.view_corrections import ViewFitConfig
    from ._common import open_run, scene_for_run

    run_ = open_run(args)
    scene = scene_for_run(run_.info, args.data, need=args.split, allow_outside=args.allow_outside_paths)
    views = scene.splits[args.split]
    if not views.has_images:
        other = scene.split_with_images(args.split)
        raise fail(
            scene.source,
            f"the {args.split} split has no images to compare with",
            f"Choose a split with images (--split {other})" if other else None,
        )
    steps = args.fit_views
    whole = bool(getattr(run_.model, "whole_images", False))
    if whole and steps:
        raise fail(
            "--fit-views",
            f"the {run_.info.train.model} model renders whole views, so a view's pose cannot be "
            "fitted ray batch by ray batch",
            "Leave out --fit-views",
        )
    capture = getattr(run_.info.train, "capture", "off") == "on"
    if steps is None:
        steps = 100 if capture and not whole else 0
        if whole and capture:
            print(f"note: held-out views are scored as rendered only ({run_.info.train.model} cannot fit their poses)")
    fit = ViewFitConfig(steps=steps) if steps else None  # (a gain and offset per channel: see evaluate)
    alone = object_alone(run_.model) if capture and not whole else None  # (a copy: memory for a second model)
    sheet: list = []
    result = {
        "split": args.split,
        "step": run_.step,
        "data": scene.source,
        **evaluate_views(
            run_.model,
            views,
            run_.background(),
            run_.chunk,
            run_.autocast,
            fit=fit,
            scale=run_.info.bounds.radius,
            sheet=sheet,
            alone=cast("NerfModel", alone.model) if alone is not None and alone.left_out else None,
        ),
    }
    json_path, sheet_path = Path(args.run) / f"eval_{args.split}.json", Path(args.run) / f"eval_{args.split}.png"
    write_json(json_path, result)
    write_contact_sheet(sheet_path, sheet, args.split)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(summary(result))
        print(f"wrote {json_path}" + (f" and {sheet_path} (photo beside render)" if sheet else ""))
    return 0


# views listed one by one up to this many; beyond, the lowest and highest few
LISTED_VIEWS = 20


def summary(result: dict) -> str:
    """``nerfkit eval``'s printed report of its ``result`` (what eval_<split>.json holds)."""
    lines = [
        f"{result['split']}: {result['n_images']} views at step {result['step']}: "
        f"PSNR {result['psnr']:.2f} dB, SSIM {result['ssim']:.3f}"
    ]
    fitted, colour, obj = result.get("fitted"), result.get("colour_only"), result.get("object")
    if fitted:
        lines.append(
            f"  with each view's pose fitted, and each half's colour solved on the other half: "
            f"{fitted['psnr']:.2f} dB / "
            f"{fitted['ssim']:.3f}" + (f" (its colour alone: {colour['psnr']:.2f} dB)" if colour else "")
        )
    if obj and obj.get("psnr") is not None:
        lines.append(
            f"  the object's own pixels: {obj['psnr']:.2f} dB"
            + (f", {obj['psnr_fitted']:.2f} fitted" if obj.get("psnr_fitted") is not None else "")
        )
    views = result.get("per_image", [])
    columns = "(PSNR dB, SSIM" + (", fitted PSNR):" if fitted else "):")
    if len(views) > LISTED_VIEWS:
        half = LISTED_VIEWS // 2
        ranked = sorted(views, key=lambda v: v["psnr"])
        shown = ranked[:half] + ranked[-half:]
        lines.append(f"  the {half} lowest and highest of {len(views)} views {columns}")
    else:
        shown = views
        lines.append(f"  per view {columns}")
    for v in shown:
        name = v.get("name") or f"view {v['index']}"
        lines.append(
            f"    {name[:32]:32s} {v['psnr']:6.2f}  {v['ssim']:.3f}"
            + (f"  {v['psnr_fitted']:6.2f}" if v.get("psnr_fitted") is not None else "")
        )
    return "\n".join(lines)
