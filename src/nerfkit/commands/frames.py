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
    from ..config import number

    p = sub.add_parser(
        "frames", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("clip", metavar="CLIP", help="the video file (MP4, MOV, M4V; H.264 or HEVC)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the frames (new, empty, or earlier frames)")
    p.add_argument(
        "--frames",
        type=number(int, 10, 10_000),
        default=120,
        metavar="N",
        help="frames to keep, at most (default: 120)",
    )
    p.add_argument(
        "--spread",
        choices=["time", "motion"],
        default="time",
        help="spread the windows evenly in time, or in camera motion measured between frames (a pause "
        "then takes no window; default: time)",
    )
    p.add_argument("--force", action="store_true", help="replace the frames an earlier run wrote in --out")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..capture.video import select_frames

    sel = select_frames(args.clip, args.out, args.frames, force=args.force, spread=args.spread)
    print(report_lines(sel))
    return 0


def report_lines(sel) -> str:
    """The report of a :class:`~nerfkit.capture.video.FrameSelection`, a few lines of text."""
    info = sel.info
    rot = f", turned {info.rotation} degrees upright" if info.rotation else ""
    lines = [
        f"{sel.source}: {info.width}x{info.height} {info.codec}{rot}, {info.duration:.1f} s at {info.fps:g} fps",
        f"  read {sel.read} frames, kept {sel.kept} (asked for {sel.target}), dropped {sel.read - sel.kept}"
        + (":" if sel.dropped else ""),
    ]
    lines += [f"    {n:5d} {reason}" for reason, n in sel.dropped.items()]
    lines.append(
        f"  sharpness (variance of the Laplacian at {sel.score_size[0]}x{sel.score_size[1]}): median "
        f"{sel.median_sharpness:.0f}, frames under {sel.blur_threshold:.0f} counted as blurred"
    )
    if sel.empty_windows:
        lines.append(f"  {sel.empty_windows} of the {sel.target} windows ({sel.spread}) gave no frame")
    lines += [f"  note: {a}" for a in sel.advice]
    lines.append(
        f"wrote {sel.kept} frames ({sel.files[0]} ... {sel.files[-1]}) and frames.json to {sel.out_dir} "
        f"in {sel.seconds:.1f} s"
    )
    return "\n".join(lines)
