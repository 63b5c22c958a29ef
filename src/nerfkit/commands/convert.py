"""`nerfkit convert`: any dataset to a course npz, a transforms.json folder or a COLMAP project."""

from __future__ import annotations

import argparse
from typing import get_args

from .stages.convert import depth_bound
from .tools import ConvertFormat

MEMORY_HINT = "Use --size or --downscale to make the images smaller"
HELP = "convert a dataset between formats (npz, Blender, transforms.json, COLMAP; LLFF in), optionally resized"

EPILOG = """\
inputs (file or folder): a course .npz; a Blender scene (transforms_train.json + RGBA PNGs);
a nerfstudio/instant-ngp transforms.json; a COLMAP model (sparse/0 with cameras/images/points3D,
binary or text) with its photos in images/ (or --images DIR), imported without re-running SfM;
an LLFF scene (poses_bounds.npy + images/; --downscale 4 or 8 reads images_4/images_8; every
8th photo becomes the val and test views).

outputs (by --to):
  out.npz            course layout: images_*, c2ws_*, focal, K, near, far
  out_folder/        nerfstudio transforms.json + images/ (any folder name)
  out_folder/ --format colmap   COLMAP project: sparse/0 (PINHOLE cameras; the sparse points, tracked
                                in the train photos that saw them) + images/

examples:
  nerfkit convert data/nerf_synthetic/lego --to lego_200.npz --size 200
  nerfkit convert lego_200.npz --to lego_ns/
  nerfkit convert my_colmap_project/ --to scene.npz --downscale 4
  nerfkit convert lego_200.npz --to lego_course.npz --near 2 --far 6   (the course's depth range)
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import MIN_DOWNSCALE, number
    from ._common import add_outside_flag

    p = sub.add_parser(
        "convert",
        help=HELP,
        description=HELP + ".",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("src", metavar="SRC", help="dataset file or folder")
    p.add_argument("--to", required=True, metavar="OUT", help="output: a .npz file or a folder (see below)")
    p.add_argument(
        "--format",
        choices=get_args(ConvertFormat),
        default="auto",
        help="output format; auto: npz for *.npz, else transforms.json (default: auto)",
    )
    size = p.add_mutually_exclusive_group()
    size.add_argument(
        "--size",
        type=number(int, 1, 100_000),
        metavar="PX",
        help="resample so the longest image side is PX pixels (K follows)",
    )
    size.add_argument(
        "--downscale", type=number(float, MIN_DOWNSCALE), metavar="F", help="divide the image size by F (K follows)"
    )
    p.add_argument(
        "--background",
        default="black",
        help="colour under transparent pixels of RGBA inputs: black, white, grey, r,g,b in [0, 1] "
        "or #rrggbb (default: black)",
    )
    p.add_argument(
        "--near",
        type=depth_bound(number(float, 0.0)),
        help="set the depth range's near end (world "
        "units; e.g. the course's 2 for lego, where nerfkit's rule from the cameras gives 2.02)",
    )
    p.add_argument(
        "--far",
        type=depth_bound(number(float, above=0)),
        help="set the depth range's far end (the course's 6 for lego)",
    )
    p.add_argument("--images", metavar="DIR", help="photo folder of a COLMAP model (default: the project's images/)")
    p.add_argument("--text", action="store_true", help="with --format colmap: write the text model instead of binary")
    p.add_argument("--force", action="store_true", help="replace an existing output (never an input)")
    add_outside_flag(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit convert``: :func:`nerfkit.api.convert` with the parsed flags."""
    from .tools import convert

    convert(
        args.src,
        args.to,
        format=args.format,
        size=args.size,
        downscale=args.downscale,
        background=args.background,
        near=args.near,
        far=args.far,
        images=args.images,
        text=args.text,
        force=args.force,
        allow_outside_paths=args.allow_outside_paths,
    )
    return 0
