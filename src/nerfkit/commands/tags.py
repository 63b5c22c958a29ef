"""`nerfkit tags`: a printable PDF of ArUco tags for calibration and for the object."""

from __future__ import annotations

import argparse

from .stages.tags import MIN_CELL_MM

__all__ = ["MIN_CELL_MM", "register", "run"]

HELP = "printable ArUco tags (PDF): a calibration sheet and a tag to lay beside the object"

DESCRIPTION = """\
Write a PDF to print at actual size: page 1 is a calibration sheet (as many tags of
--tag-size as fit, ids from 0), page 2 one larger tag (--object-tag-size) to lay flat
beside the object, its id the one after the sheet's. Each page has a 100 mm ruler to
check that the printer kept the scale.

Printed, measure a tag's black square (printers may scale a little) and give that side in
metres to nerfkit. Then photograph the sheet 20-50 times from varied angles, and the object
beside its tag (or standing on the sheet) 50-100 times all around, at two or three heights.

example:
  nerfkit tags --out tags.pdf
  nerfkit calibrate sheet_photos/ --tag-size 0.05 --out camera.json
  nerfkit capture object_photos/ --camera camera.json --tag-size 0.1 --out my_object/
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import add_dataclass_args
    from .options import TagsOptions

    p = sub.add_parser("tags", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="tags.pdf", help="PDF to write (default: tags.pdf)")
    add_dataclass_args(p, TagsOptions)  # --paper, --dict, --tag-size, --object-tag-size
    p.add_argument("--force", action="store_true", help="replace an existing file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit tags``: :func:`nerfkit.api.tags` with the parsed flags (unset options: the defaults
    of :class:`~nerfkit.commands.options.TagsOptions`)."""
    import dataclasses

    from ..config import dataclass_from_args
    from .options import TagsOptions
    from .tools import tags

    tags(args.out, **dataclasses.asdict(dataclass_from_args(TagsOptions, args)), force=args.force)
    return 0
