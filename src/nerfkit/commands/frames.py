"""`nerfkit frames`: choose sharp, evenly spread frames from a phone video."""

from __future__ import annotations

import argparse

HELP = "choose sharp, evenly spread frames from a video (MP4/MOV) and write them as JPEG"

DESCRIPTION = """\
Read a clip filmed around an object and keep the frames a careful user would: the clip is
split into --frames windows evenly spread in time, and each window gives its sharpest
frame (variance of the Laplacian), unless that frame is blurred or too dark compared with
the rest of the clip, or repeats the frame kept before it (the camera paused). The frames
are written upright (the phone's rotation applied) at full resolution as JPEG, with
frames.json, the report: frames read, kept, dropped and why.

example:
  nerfkit frames clip.mp4 --out my_object_frames/
  nerfkit frames clip.mov --out frames/ --frames 80
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import add_dataclass_args
    from .options import FramesOptions

    p = sub.add_parser(
        "frames", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("clip", metavar="CLIP", help="the video file (MP4, MOV, M4V; H.264 or HEVC)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the frames (new, empty, or earlier frames)")
    add_dataclass_args(p, FramesOptions)
    p.add_argument("--force", action="store_true", help="replace the frames an earlier run wrote in --out")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit frames``: :func:`nerfkit.api.frames` with the parsed flags (unset options: the
    defaults of :class:`~nerfkit.commands.options.FramesOptions`)."""
    import dataclasses

    from ..config import dataclass_from_args
    from .options import FramesOptions
    from .tools import frames

    frames(args.clip, args.out, **dataclasses.asdict(dataclass_from_args(FramesOptions, args)), force=args.force)
    return 0
