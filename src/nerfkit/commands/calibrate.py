"""`nerfkit calibrate`: camera intrinsics and distortion from photos of printed ArUco tags."""

from __future__ import annotations

import argparse

HELP = "calibrate a camera from photos of printed ArUco tags"
MEMORY_HINT = "Lower --detect-size or --jobs"

DESCRIPTION = """\
Estimate the camera matrix K and lens distortion from 20-50 photos of a printed sheet of
ArUco tags taken from varied angles (tilted 20-60 degrees, the sheet in different parts of
the frame). Writes a camera file (JSON) with K, the distortion coefficients, the image
size, the RMS reprojection error ("rms"), each photo's error and whether it was used or
skipped (and why), and sanity checks.

The sheet layout: give it with --layout (a JSON layout file, or an OpenCV GridBoard or
ChArUco description), or leave it out: nerfkit then estimates where the tags sit on the
sheet (all tags on one flat sheet), and never treats different tags as the same points; a
tag of another size (its side over 1.4 times the others' in the same photos) is left out,
and a sheet that repeats an id is refused. Copies of a photo are skipped; photos of the same
shape at another size are resized to the common size. Detections are cached beside the
output, so re-running is quick.

The camera is chosen whole by cross-validation over photos: every combination of a
distortion model (none, k1, k1k2, k1k2p1p2, k1k2p1p2k3), a centred or fitted principal
point and square or free pixels is fitted on its own; the camera file lists each one
("model_selection" -> "candidates": held-out error, its error at the photos' edges, how
much its folds disagree at the frame's edges, and the verdict) and the one chosen. A
fitted principal point more than 15% of the frame off centre, or pixels more than 10% from
square, is no lens's and not chosen (unless --principal-point free / --aspect free).

example:
  nerfkit calibrate calib_photos/ --dict DICT_4X4_50 --tag-size 0.06 --out camera.json
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..capture.calibrate import CalibrateConfig
    from ..config import add_dataclass_args, tag_side
    from .options import CalibrateOptions

    p = sub.add_parser(
        "calibrate", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("photos", metavar="PHOTOS_DIR", help="folder of photos of the tag sheet")
    p.add_argument("--dict", default="DICT_4X4_50", help="ArUco dictionary of the tags (default: DICT_4X4_50)")
    p.add_argument(
        "--tag-size",
        type=tag_side,
        help="side of one tag's black square in metres, e.g. 0.06 (needed unless the layout file gives sizes)",
    )
    p.add_argument("--layout", help="sheet layout JSON (tag id -> corners/centre, or a GridBoard/ChArUco board)")
    p.add_argument("--out", default="camera.json", help="camera file to write (default: camera.json)")
    add_dataclass_args(p, CalibrateOptions)  # --detect-size, --jobs
    p.add_argument("--no-cache", action="store_true", help="ignore cached detections")
    p.add_argument("--all-photos", action="store_true", help="list every photo in the summary, not only skipped ones")
    p.add_argument("--force", action="store_true", help="replace an existing camera file")
    add_dataclass_args(p, CalibrateConfig, "calibration")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit calibrate``: :func:`nerfkit.api.calibrate` with the parsed flags (unset options: the
    defaults of :class:`~nerfkit.commands.options.CalibrateOptions`)."""
    import dataclasses

    from ..capture.calibrate import CalibrateConfig
    from ..config import dataclass_from_args
    from .options import CalibrateOptions
    from .pipeline import calibrate

    calibrate(
        args.photos,
        args.out,
        tag_size=args.tag_size,
        dictionary=args.dict,
        layout=args.layout,
        **dataclasses.asdict(dataclass_from_args(CalibrateOptions, args)),
        cache=not args.no_cache,
        settings=dataclass_from_args(CalibrateConfig, args),
        all_photos=args.all_photos,
        force=args.force,
    )
    return 0
