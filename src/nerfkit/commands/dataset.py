"""`nerfkit dataset`: (re)build a NeRF dataset from the poses `nerfkit poses` found."""

from __future__ import annotations

import argparse
from typing import get_args

from .tools import PoseSource

MEMORY_HINT = "Lower --max-side or --jobs"
HELP = "undistort, resize and split posed photos into a NeRF dataset (npz + transforms.json)"

DESCRIPTION = """\
Build the dataset from DATASET_DIR/poses.json (written by `nerfkit poses`): undistort each
photo (keeping the calibrated focal length, cropped to the largest rectangle of valid
pixels, K updated), downscale it, split the views into train/val/test, estimate near/far
from the cameras and the tag size, and write images/, transforms.json (nerfstudio layout,
OpenGL axes) and dataset.npz (the course layout plus K, near, far, center, up and each
view's photo name), and say how closely the photos surround the object (the widest gap
among the view directions, charted in coverage.png) and how well the training photos agree
on the table around it (a rough ceiling for held-out scores).
`nerfkit poses` runs this step itself; run it again with --out to build another size or
split (or with --force to rebuild it in place: runs trained on the old dataset then refuse
the new one). It keeps the poses `nerfkit poses` gave the dataset: when those came
from structure-from-motion (DATASET_DIR/sfm_report.json and colmap/sparse/0), the dataset
is rebuilt from that model, else from the tag poses in poses.json (transforms.json says
which; --pose-source chooses).

example:
  nerfkit dataset my_object/ --max-side 800 --out my_object_800/
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..capture.dataset import DatasetConfig
    from ..config import add_dataclass_args, number
    from ._common import add_outside_flag

    p = sub.add_parser(
        "dataset", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("poses", metavar="DATASET_DIR", help="folder with poses.json from `nerfkit poses` (or the file)")
    p.add_argument("--out", help="folder to write (default: the same folder)")
    p.add_argument(
        "--pose-source",
        choices=get_args(PoseSource),
        default="auto",
        help="auto (default): the poses the folder's dataset was built from (transforms.json says): "
        "the structure-from-motion model that `nerfkit poses` left (sfm_report.json, colmap/), or "
        "the tag poses of poses.json",
    )
    p.add_argument(
        "--jobs", type=number(int, 0, 256), default=0, help="photos processed in parallel (default: up to 4 cores)"
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace an existing dataset (dataset.npz, transforms.json, images/, coverage.png) in the output folder",
    )
    add_outside_flag(p)
    add_dataclass_args(p, DatasetConfig, "dataset")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit dataset``: :func:`nerfkit.api.dataset` with the parsed flags."""
    from ..capture.dataset import DatasetConfig
    from ..config import dataclass_from_args
    from .tools import dataset

    dataset(
        args.poses,
        out=args.out,
        pose_source=args.pose_source,
        jobs=args.jobs,
        force=args.force,
        allow_outside_paths=args.allow_outside_paths,
        settings=dataclass_from_args(DatasetConfig, args),
    )
    return 0
