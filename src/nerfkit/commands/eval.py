"""`nerfkit eval`: PSNR and SSIM of a trained run on a split, printed and written as JSON."""

from __future__ import annotations

import argparse
from typing import get_args

from ._common import add_run_args, run_device_options
from .pipeline import Split
from .stages.evaluate import LISTED_VIEWS, summary, write_contact_sheet

__all__ = ["LISTED_VIEWS", "register", "run", "summary", "write_contact_sheet"]  # the report's pieces live in stages

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
    p.add_argument("--split", choices=get_args(Split), default="val", help="which images (default: val)")
    p.add_argument(
        "--fit-views",
        type=number(int, 0, 100_000),
        default=None,
        metavar="STEPS",
        help="also score each view after fitting its pose to its photo with the scene frozen, for this "
        "many steps, and then each half of the photo with a gain and offset per channel solved on "
        "the other half (least squares; NeRF-W's protocol, both ways) (default: 100 for runs "
        "trained with --capture, else 0: off; a model that renders whole views, such as splat, fits "
        "from whole renders)",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print the JSON that RUN/eval_<split>.json holds instead of the summary (for scripts)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit eval``: :func:`nerfkit.api.evaluate` with the parsed flags; with ``--json``,
    the scores as JSON instead of the summary."""
    import json

    from .pipeline import evaluate

    result = evaluate(
        args.run,
        split=args.split,
        fit_views=args.fit_views,
        **run_device_options(args),
        quiet=args.json,
    )
    if args.json:
        print(json.dumps(result.scores, indent=2))
    return 0
