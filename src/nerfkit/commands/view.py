"""`nerfkit view`: look at a dataset's cameras, rays and samples (browser or PNG)."""

from __future__ import annotations

import argparse

from .stages.view import dataset_tag_size

__all__ = ["dataset_tag_size", "register", "run"]  # (the tag size a capture records: stages.view)

HELP = (
    "view a dataset's cameras, rays and samples, or a trained run live, in the browser (viser); or a dataset as a PNG"
)

DESCRIPTION = """\
Shows each camera as a frustum textured with its image, the world axes, the tag plane and
the scene centre; --rays N adds N random training rays with their samples between near
and far (as training samples them); --rays-from V draws them from training view V only
(100 of them unless --rays says). DATASET is anything `nerfkit train --data` reads.
The server listens on 127.0.0.1 only, unless you pass --host explicitly.
A run folder (from `nerfkit train`, finished or still training: it follows each new
checkpoint) opens the live viewer of its model instead: the model rendered from the
browser's camera, in colour or depth, the whole scene or (the "Object alone" switch) a
capture's object without its table and room. The options that draw a dataset are refused there.

examples:
  nerfkit view my_object/ --rays 50              then open http://127.0.0.1:8080
  nerfkit view my_object/dataset.npz --rays 30 --png cameras.png
  nerfkit view lego.npz --rays-from 0 --png rays.png   (the course's rays of one camera)
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import MIN_DOWNSCALE, number
    from ._common import add_outside_flag

    p = sub.add_parser("view", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("path", metavar="DATASET", help="dataset file or folder (or a run folder)")
    p.add_argument(
        "--rays",
        type=number(int, 0, 100_000),
        help="training rays to draw with their samples (default: none; 100 with --rays-from)",
    )
    p.add_argument("--samples", type=number(int, 1, 4096), help="samples per drawn ray (default: 64, as the course)")
    p.add_argument(
        "--rays-from",
        type=number(int, 0),
        metavar="N",
        help="draw the rays of training view N only (the "
        "course's check that u and v are not swapped: they fill that camera's frustum)",
    )
    p.add_argument("--png", metavar="FILE", help="write a static PNG (matplotlib) instead of serving, then exit")
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default: 127.0.0.1, this machine only; 0.0.0.0 exposes the viewer to the network)",
    )
    p.add_argument(
        "--port",
        type=number(int, 1, 65535),
        default=8080,
        help="first port to try (default: 8080; taken: the next free one)",
    )
    p.add_argument("--force", action="store_true", help="replace an existing --png file")
    p.add_argument(
        "--downscale",
        type=number(float, MIN_DOWNSCALE),
        help="divide the dataset's image size by this (an LLFF scene's 4 or 8 reads its images_4 or images_8)",
    )
    add_outside_flag(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit view``: :func:`nerfkit.api.view` with the parsed flags, serving until Ctrl-C."""
    from .tools import view

    view(
        args.path,
        rays=args.rays,
        samples=args.samples,
        rays_from=args.rays_from,
        png=args.png,
        host=args.host,
        port=args.port,
        force=args.force,
        downscale=args.downscale,
        allow_outside_paths=args.allow_outside_paths,
        block=True,
    )
    return 0
