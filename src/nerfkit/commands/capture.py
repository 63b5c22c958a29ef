"""`nerfkit capture`: a phone video or photos to a trained NeRF and/or Gaussian splat in one
command (frames, calibrate, poses, train, eval, render, export), each step's output kept for
the next run."""

from __future__ import annotations

import argparse

# the capture's own steps live in the stage; tests and older code import these from here
from .stages.capture import _check_posed as _check_posed
from .stages.capture import _inputs as _inputs
from .stages.capture import _larger_budget as _larger_budget
from .stages.capture import _route as _route
from .stages.capture import _same_inputs as _same_inputs
from .stages.capture import scene_kind_text as scene_kind_text
from .stages.capture import summary as summary

HELP = "a phone video or photos of an object -> poses, NeRF and/or Gaussian splat, videos, mesh (in one go)"

DESCRIPTION = """\
Run the whole capture flow into one folder, as the README's steps do one by one:

  OUT/frames/       nerfkit frames CLIP             (a video: sharp frames spread along it, --clip-frames)
  OUT/camera.json   nerfkit calibrate CALIB_DIR     (only with --calib; --camera gives one)
  OUT/dataset/      nerfkit poses OBJECT_DIR        (posed, undistorted, split; see "poses" below)
  OUT/run/          nerfkit train --minutes 3       (--model fast or both, the default: capture settings: table,
                                                     room, pose and colour refinement; one resume
                                                     checkpoint kept beside model.pt)
                    nerfkit eval --split val        (run/eval_val.json and the contact sheet run/eval_val.png)
                    nerfkit render                  (run/videos: orbit.mp4, orbit.gif, depth.mp4)
                    nerfkit render --object         (run/videos: object.mp4, object.gif, object_depth.mp4,
                                                     the object alone on white)
  OUT/run/mesh.ply  nerfkit export --mesh           (the object, without the table)
  OUT/splat_run/    nerfkit train --model splat     (--model splat or both, the default: 3D Gaussians from the SfM
                                                     points, then its eval and orbit video)
  OUT/splat.ply     nerfkit export --splat          (the standard 3DGS PLY: SuperSplat, Brush, Polycam,
                                                     Postshot, nerfstudio; and OUT/splat.splat for
                                                     antimatter15-style web viewers)
  OUT/splat_object.ply                              (the Gaussians in the object's box: the object alone)

poses: without --tag-size the photos (or frames) are posed by structure-from-motion
(pycolmap): focal length and radial distortion are refined on the photos themselves, and
the table (or ground) the object stands on is found in the sparse points and becomes
z = 0; when none is found the scene keeps the cameras' up and trains without a table.
The scale is then arbitrary (mean camera distance 4). With --tag-size and a tag beside
the object, the tag fixes metric scale and up: photos are posed from the tag and by
structure-from-motion in its frame (--method auto), or from the tag alone (--method
tags, as the course does); a video's frames, which carry no focal length, are posed by
structure-from-motion with the tag fixing scale and up. Calibration (--calib or --camera)
is optional in every route.

Each stage is headed [k/N] (N: the stages this route runs; structure-from-motion's features,
matching and mapping are parts of the poses stage) and prints its own report and progress
as it goes, and the capture ends with a summary: the frames used, the photos posed, each
model's held-out scores and the files made. OUT/capture.json records what the capture was
made from.

Run it again with the same inputs and the steps whose results are there are kept: a
training run cut short (Ctrl-C, a crash) goes on from its last checkpoint; a larger
--minutes (or --steps, the unit the NeRF was trained with) trains it on from its checkpoint,
its learning rate back up to where the longer schedule has it; the eval, videos and mesh
are made again when they are older than the NeRF (--frames renders the videos again).
Results made from other inputs are refused, never mixed with new ones (photos added,
removed or replaced count too); a step that failed may be run again with its input mended.
--force redoes every step, replacing the frames, the camera file, the dataset and the runs.

examples:
  nerfkit capture clip.mp4 --out my_object/
  nerfkit capture clip.mov --out my_object/ --model both --minutes 5
  nerfkit capture object_photos/ --out my_object/ --model splat
  nerfkit capture object_photos/ --calib sheet_photos/ --tag-size 0.06 --out my_object/
  nerfkit capture object_photos/ --camera camera.json --tag-size 0.10 --out my_object/ --minutes 5
  nerfkit capture object_photos/ --calib sheet_photos/ --sheet-tag-size 0.03 --tag-size 0.12 --out my_object/
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import add_dataclass_args
    from .options import CaptureOptions

    p = sub.add_parser(
        "capture", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "photos",
        metavar="OBJECT_DIR|CLIP",
        help="folder of photos of the object, or a video filmed slowly around it (MP4, MOV, M4V; H.264 or HEVC)",
    )
    p.add_argument("--out", required=True, help="folder for everything the capture makes")
    add_dataclass_args(p, CaptureOptions)  # --tag-size to --device; --calib | --camera, --minutes | --steps
    p.add_argument(
        "--force",
        action="store_true",
        help="redo every step, replacing the frames, the camera file, the dataset and the runs of an earlier capture",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit capture``: :func:`nerfkit.api.capture` with the parsed flags (unset options: the
    defaults of :class:`~nerfkit.commands.options.CaptureOptions`)."""
    import dataclasses

    from ..config import dataclass_from_args
    from .options import CaptureOptions
    from .pipeline import capture

    capture(
        args.photos,
        args.out,
        **dataclasses.asdict(dataclass_from_args(CaptureOptions, args)),
        force=args.force,
        verbose=bool(getattr(args, "verbose", False)),
    )
    return 0
