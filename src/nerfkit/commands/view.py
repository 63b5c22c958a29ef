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
    from ..config import add_dataclass_args
    from ._common import add_outside_flag
    from .options import ViewOptions

    p = sub.add_parser("view", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("path", metavar="DATASET", help="dataset file or folder (or a run folder)")
    add_dataclass_args(p, ViewOptions)
    p.add_argument(
        "--host",
        default=ViewOptions.host,
        help="address to listen on (default: %(default)s, this machine only; 0.0.0.0 exposes the viewer to "
        "the network)",
    )
    p.add_argument("--png", metavar="FILE", help="write a static PNG (matplotlib) instead of serving, then exit")
    p.add_argument("--force", action="store_true", help="replace an existing --png file")
    add_outside_flag(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit view``: :func:`nerfkit.api.view` with the parsed flags (unset options: the defaults
    of :class:`~nerfkit.commands.options.ViewOptions`), serving until Ctrl-C."""
    import dataclasses

    from ..config import dataclass_from_args
    from .options import ViewOptions
    from .tools import view

    view(
        args.path,
        **dataclasses.asdict(dataclass_from_args(ViewOptions, args)),
        png=args.png,
        force=args.force,
        allow_outside_paths=args.allow_outside_paths,
        block=True,
    )
    return 0
