"""`nerfkit eval`: PSNR and SSIM of a trained run on a split, printed and written as JSON."""

from __future__ import annotations

import argparse

from ._common import add_run_args, run_device_options
from .stages.evaluate import LISTED_VIEWS, summary, write_contact_sheet

__all__ = ["LISTED_VIEWS", "register", "run", "summary", "write_contact_sheet"]  # the report's pieces live in stages

HELP = "evaluate a trained run on held-out images: PSNR and SSIM"
MEMORY_HINT = "Lower --chunk (rays rendered at once)"


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import add_dataclass_args
    from .options import EvalOptions

    p = sub.add_parser(
        "eval",
        help=HELP,
        description=HELP + ". Prints the means and each view's scores, and "
        "writes them to RUN/eval_<split>.json (with each view's fitted pose and colour for a capture), "
        "with a contact sheet (photos beside renders) in RUN/eval_<split>.png.",
    )
    add_run_args(p)
    add_dataclass_args(p, EvalOptions)
    p.add_argument(
        "--json",
        action="store_true",
        help="print the JSON that RUN/eval_<split>.json holds instead of the summary (for scripts)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit eval``: :func:`nerfkit.api.evaluate` with the parsed flags (unset options: the
    defaults of :class:`~nerfkit.commands.options.EvalOptions`); with ``--json``, the scores as
    JSON instead of the summary."""
    import dataclasses
    import json

    from ..config import dataclass_from_args
    from .options import EvalOptions
    from .pipeline import evaluate

    result = evaluate(
        args.run,
        **dataclasses.asdict(dataclass_from_args(EvalOptions, args)),
        **run_device_options(args),
        quiet=args.json,
    )
    if args.json:
        print(json.dumps(result.scores, indent=2))
    return 0
