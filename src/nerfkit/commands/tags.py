"""`nerfkit tags`: a printable PDF of ArUco tags for calibration and for the object."""

from __future__ import annotations

import argparse

# a tag's cells (its bits and black border) narrower than this are lost: a 1 mm cell spans about
# 7 pixels of a 12-megapixel phone photo (fx ~3000 px) from 40 cm, 3 from a metre
MIN_CELL_MM = 1.0
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
    from ..capture.sheet import PAPERS
    from ..config import number, tag_side

    p = sub.add_parser("tags", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="tags.pdf", help="PDF to write (default: tags.pdf)")
    p.add_argument("--paper", choices=sorted(PAPERS), default="a4", help="paper size (default: a4)")
    p.add_argument("--dict", default="DICT_4X4_50", help="ArUco dictionary (default: DICT_4X4_50, nerfkit's)")
    p.add_argument(
        "--tag-size",
        type=tag_side,
        default=0.05,
        help="side of the sheet's tags' black squares in metres (default: 0.05)",
    )

    def object_side(text: str) -> float:
        return 0.0 if number(float, 0.0)(text) == 0 else tag_side(text)

    object_side.__name__ = "float"
    p.add_argument(
        "--object-tag-size",
        type=object_side,
        default=0.1,
        help="side of the tag beside the object in metres (default: 0.1; 0: no such page)",
    )
    p.add_argument("--force", action="store_true", help="replace an existing file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..capture.aruco import get_dictionary
    from ..capture.sheet import RULER_LENGTH_MM, draw_page, largest_sheet_tag_mm, largest_tag_mm, tag_sheets
    from ..errors import fail
    from ..io.atomic import atomic_path
    from ..io.paths import guard_outputs

    out = Path(args.out)
    if out.suffix.lower() != ".pdf":
        raise fail("--out", f"'{out}' should end in .pdf")
    d = get_dictionary(args.dict)
    cells = d.markerSize + 2
    sheet_mm, object_mm = 1000 * args.tag_size, 1000 * (args.object_tag_size or 0)
    for flag, mm in (("--tag-size", sheet_mm), ("--object-tag-size", object_mm)):
        if 0 < mm < MIN_CELL_MM * cells:
            raise fail(
                flag,
                f"a {mm:g} mm tag has {mm / cells:.2g} mm cells, too small to print sharply or for a phone to find",
                f"Use at least {MIN_CELL_MM * cells / 1000:g} (metres; a few centimetres is usual)",
            )
    if sheet_mm > largest_sheet_tag_mm(args.paper):
        raise fail(
            "--tag-size",
            f"a {sheet_mm:g} mm tag does not fit on {args.paper} paper",
            f"Use at most {int(largest_sheet_tag_mm(args.paper)) / 1000:.3f}",
        )
    if object_mm > largest_tag_mm(args.paper, cells):
        raise fail(
            "--object-tag-size",
            f"a {object_mm:g} mm tag does not fit on {args.paper} paper with white around it",
            f"Use at most {int(largest_tag_mm(args.paper, cells)) / 1000:.3f}",
        )
    guard_outputs([out], [], args.force)
    pages = tag_sheets(args.paper, args.dict, sheet_mm, object_mm or None)
    from matplotlib.backends.backend_pdf import PdfPages

    with (
        atomic_path(out) as tmp,
        PdfPages(tmp, metadata={"Title": "nerfkit ArUco tags", "Creator": "nerfkit tags"}) as pdf,
    ):
        for page in pages:
            pdf.savefig(draw_page(page, d))
    sheet = pages[0]
    print(
        f"wrote {out} ({args.paper.upper() if args.paper == 'a4' else args.paper}, {len(pages)} "
        f"page{'s' * (len(pages) > 1)}):"
    )
    print(
        f"  page 1: the calibration sheet, {len(sheet.ids)} tags of {sheet_mm:g} mm ({args.dict}, ids "
        f"{sheet.ids[0]}-{sheet.ids[-1]})"
    )
    if len(pages) > 1:
        print(f"  page 2: tag {pages[1].ids[0]} of {object_mm:g} mm, to lay flat beside the object")
    print(
        f'Print at actual size (100%, not "fit to page"), check that the ruler measures {RULER_LENGTH_MM:g} mm, '
        "and measure a tag's black square. Then, with the sides you measured:"
    )
    other = "" if args.dict == "DICT_4X4_50" else f" --dict {args.dict}"
    if len(pages) > 1:
        print(
            f"  nerfkit capture object_photos/ --calib sheet_photos/{other} --sheet-tag-size {args.tag_size:g} "
            f"--tag-size {args.object_tag_size:g} --out my_object/"
        )
        print(f"  (the object standing on the sheet instead: --tag-size {args.tag_size:g}, no --sheet-tag-size)")
    else:
        print(
            f"  nerfkit capture object_photos/ --calib sheet_photos/{other} --tag-size {args.tag_size:g} "
            "--out my_object/   (the object standing on the sheet)"
        )
    return 0
