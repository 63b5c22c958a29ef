"""`nerfkit render`: orbit video, GIF and depth video of a trained run."""

from __future__ import annotations

import argparse

from ._common import add_run_args, run_device_options

HELP = "render a trained run to MP4/GIF and a depth video"
MEMORY_HINT = "Lower --chunk (rays rendered at once)"


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import add_dataclass_args
    from .options import RenderOptions

    p = sub.add_parser(
        "render",
        help=HELP,
        description=HELP + ". Uses the dataset's test poses when they are "
        "a camera path (as in the course's lego file), else LLFF's spiral for a forward-facing "
        "capture, else an orbit around the object.",
    )
    add_run_args(p)
    add_dataclass_args(p, RenderOptions)
    p.add_argument("--out", help="output folder (default: RUN/videos)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace videos already in --out (without --out, RUN/videos is replaced: it belongs to the run)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit render``: :func:`nerfkit.api.render` with the parsed flags (unset options: the
    defaults of :class:`~nerfkit.commands.options.RenderOptions`)."""
    import dataclasses

    from ..config import dataclass_from_args
    from .options import RenderOptions
    from .pipeline import render

    render(
        args.run,
        out=args.out,
        **dataclasses.asdict(dataclass_from_args(RenderOptions, args)),
        **run_device_options(args),
        force=args.force,
    )
    return 0
