"""`nerfkit render`: orbit video, GIF and depth video of a trained run."""

from __future__ import annotations

import argparse
from typing import get_args

from ._common import add_run_args, run_device_options
from .pipeline import VideoPath

HELP = "render a trained run to MP4/GIF and a depth video"
MEMORY_HINT = "Lower --chunk (rays rendered at once)"


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import number

    p = sub.add_parser(
        "render",
        help=HELP,
        description=HELP + ". Uses the dataset's test poses when they are "
        "a camera path (as in the course's lego file), else LLFF's spiral for a forward-facing "
        "capture, else an orbit around the object.",
    )
    add_run_args(p)
    p.add_argument(
        "--path",
        choices=get_args(VideoPath),
        default="auto",
        help="camera path: the dataset's test poses, an orbit around the object, a spiral across a "
        "forward-facing capture's view, or auto (chosen as described above)",
    )
    p.add_argument(
        "--frames",
        type=number(int, 1, 100_000),
        default=None,
        help="frames of a generated orbit or spiral (default: 120, 4 s at 30 fps); the test path "
        "has the dataset's own poses",
    )
    p.add_argument("--fps", type=number(int, 1, 1000), default=30, help="frames per second (default: 30)")
    p.add_argument(
        "--object",
        action="store_true",
        help="render the object alone into object.mp4, object.gif and object_depth.mp4: a capture's "
        "table, floor and room left out, the table's paint and the specks apart from the object "
        "cleared from the density (as export --mesh does), on white, centred and framed whole (one zoom for the "
        "whole path: an object that already fills the frame is drawn smaller)",
    )
    p.add_argument(
        "--background",
        help="override the run's background colour (with --object: white): black, "
        "white, grey, r,g,b in [0, 1] or #rrggbb",
    )
    p.add_argument("--out", help="output folder (default: RUN/videos)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace videos already in --out (without --out, RUN/videos is replaced: it belongs to the run)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit render``: :func:`nerfkit.api.render` with the parsed flags."""
    from .pipeline import render

    render(
        args.run,
        out=args.out,
        path=args.path,
        frames=args.frames,
        fps=args.fps,
        object=args.object,
        background=args.background,
        **run_device_options(args),
        force=args.force,
    )
    return 0
