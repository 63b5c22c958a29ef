"""`nerfkit convert`: any dataset to a course npz, a transforms.json folder or a COLMAP project."""

from __future__ import annotations

import argparse

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
    from ..config import add_dataclass_args
    from ._common import add_outside_flag
    from .options import ConvertOptions

    p = sub.add_parser(
        "convert",
        help=HELP,
        description=HELP + ".",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("src", metavar="SRC", help="dataset file or folder")
    p.add_argument("--to", required=True, metavar="OUT", help="output: a .npz file or a folder (see below)")
    add_dataclass_args(p, ConvertOptions)  # --format, --size | --downscale, --background, --near, --far
    p.add_argument("--images", metavar="DIR", help="photo folder of a COLMAP model (default: the project's images/)")
    p.add_argument("--text", action="store_true", help="with --format colmap: write the text model instead of binary")
    p.add_argument("--force", action="store_true", help="replace an existing output (never an input)")
    add_outside_flag(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit convert``: :func:`nerfkit.api.convert` with the parsed flags (unset options: the
    defaults of :class:`~nerfkit.commands.options.ConvertOptions`)."""
    import dataclasses

    from ..config import dataclass_from_args
    from .options import ConvertOptions
    from .tools import convert

    convert(
        args.src,
        args.to,
        **dataclasses.asdict(dataclass_from_args(ConvertOptions, args)),
        images=args.images,
        text=args.text,
        force=args.force,
        allow_outside_paths=args.allow_outside_paths,
    )
    return 0
