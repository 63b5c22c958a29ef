"""The tag sheet in small steps: the sizes a page can print, the PDF, and what to do with it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

# a tag's cells (its bits and black border) narrower than this are lost: a 1 mm cell spans about
# 7 pixels of a 12-megapixel phone photo (fx ~3000 px) from 40 cm, 3 from a metre
MIN_CELL_MM = 1.0


def object_side(text: str) -> float:
    """The argparse ``type`` of ``--object-tag-size``: a printed tag's side in metres, or 0 (no page)."""
    from ...config import number, tag_side

    return 0.0 if number(float, 0.0)(text) == 0 else tag_side(text)


object_side.__name__ = "float"  # argparse names the type in its messages


def check_sizes(paper: str, cells: int, sheet_mm: float, object_mm: float) -> None:
    """Refuse tags of ``cells`` cells a side (bits and border) too small to print sharply or too
    large for ``paper``: the sheet's of ``sheet_mm``, the object's of ``object_mm`` (0: none)."""
    from ...capture.sheet import largest_sheet_tag_mm, largest_tag_mm
    from ...errors import fail

    for flag, mm in (("--tag-size", sheet_mm), ("--object-tag-size", object_mm)):
        if 0 < mm < MIN_CELL_MM * cells:
            raise fail(
                flag,
                f"a {mm:g} mm tag has {mm / cells:.2g} mm cells, too small to print sharply or for a phone to find",
                f"Use at least {MIN_CELL_MM * cells / 1000:g} (metres; a few centimetres is usual)",
            )
    if sheet_mm > largest_sheet_tag_mm(paper):
        raise fail(
            "--tag-size",
            f"a {sheet_mm:g} mm tag does not fit on {paper} paper",
            f"Use at most {int(largest_sheet_tag_mm(paper)) / 1000:.3f}",
        )
    if object_mm > largest_tag_mm(paper, cells):
        raise fail(
            "--object-tag-size",
            f"a {object_mm:g} mm tag does not fit on {paper} paper with white around it",
            f"Use at most {int(largest_tag_mm(paper, cells)) / 1000:.3f}",
        )


def write_pdf(path: Path, pages: list, dictionary: Any) -> None:
    """The ``pages`` (:func:`~nerfkit.capture.sheet.tag_sheets`) as a PDF at ``path``, whole or not at all."""
    from matplotlib.backends.backend_pdf import PdfPages

    from ...capture.sheet import draw_page
    from ...io.atomic import atomic_path

    with (
        atomic_path(path) as tmp,
        PdfPages(tmp, metadata={"Title": "nerfkit ArUco tags", "Creator": "nerfkit tags"}) as pdf,
    ):
        for page in pages:
            pdf.savefig(draw_page(page, dictionary))


def tags_report(path: Path, paper: str, dictionary: str, pages: list, tag_size: float, object_tag_size: float) -> str:
    """What was written to ``path``, and the capture command that uses the printed tags."""
    from ...capture.sheet import RULER_LENGTH_MM

    sheet = pages[0]
    lines = [
        f"wrote {path} ({paper.upper() if paper == 'a4' else paper}, {len(pages)} page{'s' * (len(pages) > 1)}):",
        f"  page 1: the calibration sheet, {len(sheet.ids)} tags of {1000 * tag_size:g} mm ({dictionary}, ids "
        f"{sheet.ids[0]}-{sheet.ids[-1]})",
    ]
    if len(pages) > 1:
        lines.append(f"  page 2: tag {pages[1].ids[0]} of {1000 * object_tag_size:g} mm, to lay flat beside the object")
    lines.append(
        f'Print at actual size (100%, not "fit to page"), check that the ruler measures {RULER_LENGTH_MM:g} mm, '
        "and measure a tag's black square. Then, with the sides you measured:"
    )
    other = "" if dictionary == "DICT_4X4_50" else f" --dict {dictionary}"
    if len(pages) > 1:
        lines.append(
            f"  nerfkit capture object_photos/ --calib sheet_photos/{other} --sheet-tag-size {tag_size:g} "
            f"--tag-size {object_tag_size:g} --out my_object/"
        )
        lines.append(f"  (the object standing on the sheet instead: --tag-size {tag_size:g}, no --sheet-tag-size)")
    else:
        lines.append(
            f"  nerfkit capture object_photos/ --calib sheet_photos/{other} --tag-size {tag_size:g} "
            "--out my_object/   (the object standing on the sheet)"
        )
    return "\n".join(lines)
