"""Printable ArUco tags: a calibration sheet and a tag to lay beside the object.

Pages are drawn in millimetres on the paper (origin at its lower left), each tag's black
cells as one vector path, so a PDF printed at actual size gives tags of exactly the side
asked for. Each page carries a 100 mm ruler to check the printer's scale.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# paper sizes in mm, portrait (width, height)
PAPERS = {"a4": (210.0, 297.0), "letter": (215.9, 279.4)}
# blank border (printers do not print their outer 3-6 mm) and the bands for the title and the ruler
MARGIN_MM = 12.0
TITLE_MM = 16.0
RULER_MM = 22.0
RULER_LENGTH_MM = 100.0
# white between tags, as a share of a tag's side: more than the one cell of quiet zone
# the detector needs around a tag (a 4x4 tag with its border is 6 cells wide)
GAP_SHARE = 0.25


@dataclass
class SheetPage:
    """One page: tags ``ids`` of side ``tag_mm`` whose centres are ``centres`` (n, 2), mm
    from the paper's lower left, and the text above them."""

    paper: str
    tag_mm: float
    ids: list[int]
    centres: np.ndarray
    title: str
    subtitle: str = ""

    @property
    def size_mm(self) -> tuple[float, float]:
        return PAPERS[self.paper]


def tag_area(paper: str) -> tuple[float, float, float, float]:
    """``(x0, y0, x1, y1)`` mm: where tags may go, inside the margins, between the ruler
    band (bottom) and the title band (top)."""
    w, h = PAPERS[paper]
    return MARGIN_MM, MARGIN_MM + RULER_MM, w - MARGIN_MM, h - MARGIN_MM - TITLE_MM


def largest_sheet_tag_mm(paper: str) -> float:
    """The largest side (mm) of a sheet's tags: one tag filling the tag area's short side."""
    x0, y0, x1, y1 = tag_area(paper)
    return min(x1 - x0, y1 - y0)


def largest_tag_mm(paper: str, cells: int) -> float:
    """The largest side (mm) of a tag ``cells`` wide (border included) that one page
    holds, with a cell of white around it."""
    return largest_sheet_tag_mm(paper) * cells / (cells + 2)


def grid_page(paper: str, tag_mm: float, first_id: int, max_tags: int, title: str, subtitle: str = "") -> SheetPage:
    """As many tags of ``tag_mm`` as fit (up to ``max_tags``), in a grid centred in the
    page's tag area, ``GAP_SHARE`` of a side apart; ids from ``first_id``, row by row from
    the top left (as read)."""
    x0, y0, x1, y1 = tag_area(paper)
    pitch = tag_mm * (1 + GAP_SHARE)
    cols = int((x1 - x0 + tag_mm * GAP_SHARE) // pitch)
    rows = int((y1 - y0 + tag_mm * GAP_SHARE) // pitch)
    if cols < 1 or rows < 1:
        raise ValueError(f"a {tag_mm:g} mm tag does not fit on {paper}")
    rows = min(rows, -(-max_tags // cols))
    n = min(cols * rows, max_tags)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    centres = [
        (cx + (c - (cols - 1) / 2) * pitch, cy - (r - (rows - 1) / 2) * pitch) for r in range(rows) for c in range(cols)
    ][:n]
    return SheetPage(paper, tag_mm, list(range(first_id, first_id + n)), np.array(centres), title, subtitle)


def single_page(paper: str, tag_mm: float, tag_id: int, cells: int, title: str, subtitle: str = "") -> SheetPage:
    """One tag of ``tag_mm`` (``cells`` wide), centred in the page's tag area."""
    if tag_mm > largest_tag_mm(paper, cells) + 1e-9:
        raise ValueError(f"a {tag_mm:g} mm tag does not fit on {paper}")
    x0, y0, x1, y1 = tag_area(paper)
    return SheetPage(paper, tag_mm, [tag_id], np.array([[(x0 + x1) / 2, (y0 + y1) / 2]]), title, subtitle)


def tag_cells(dictionary, tag_id: int) -> np.ndarray:
    """(k, k) bool, True where the tag (with its one-cell black border) is black; row 0 is
    the printed tag's top."""
    import cv2

    k = dictionary.markerSize + 2
    return cv2.aruco.generateImageMarker(dictionary, tag_id, k, borderBits=1) < 128


def cells_path(cells: np.ndarray, centre: np.ndarray, side: float):
    """A matplotlib Path of the black ``cells`` of a tag of ``side`` centred at ``centre``
    (mm, y up): one rectangle per black cell, reaching a hair into each black neighbour so
    that no seam shows between them (edges beside white stay exact)."""
    from matplotlib.path import Path

    k = cells.shape[0]
    cell = side / k
    hair = 0.01 * cell
    black = np.pad(cells, 1)  # white outside the tag
    left, top = centre[0] - side / 2, centre[1] + side / 2
    verts, codes = [], []
    for r, c in zip(*np.nonzero(cells)):
        x0, x1 = left + c * cell - hair * black[r + 1, c], left + (c + 1) * cell + hair * black[r + 1, c + 2]
        y0, y1 = top - (r + 1) * cell - hair * black[r + 2, c + 1], top - r * cell + hair * black[r, c + 1]
        verts += [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (0, 0)]
        codes += [Path.MOVETO, Path.LINETO, Path.LINETO, Path.LINETO, Path.CLOSEPOLY]
    return Path(verts, codes)


def draw_page(page: SheetPage, dictionary):
    """The page as a matplotlib Figure at the paper's size (1 unit = 1 mm)."""
    from matplotlib.figure import Figure
    from matplotlib.patches import PathPatch

    w, h = page.size_mm
    fig = Figure(figsize=(w / 25.4, h / 25.4))
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, w)
    ax.set_ylim(0, h)
    ax.set_axis_off()
    for tag_id, centre in zip(page.ids, page.centres):
        ax.add_patch(
            PathPatch(
                cells_path(tag_cells(dictionary, tag_id), centre, page.tag_mm),
                facecolor="black",
                edgecolor="none",
                antialiased=False,
            )
        )
        ax.text(
            centre[0], centre[1] - page.tag_mm / 2 - 1.5, f"{tag_id}", ha="center", va="top", fontsize=6, color="0.45"
        )
    ax.text(MARGIN_MM, h - MARGIN_MM, page.title, ha="left", va="top", fontsize=10)
    ax.text(MARGIN_MM, h - MARGIN_MM - 6, page.subtitle, ha="left", va="top", fontsize=8)
    # the ruler, a tick each 10 mm (longer each 50), to check that the printer kept the scale
    y = MARGIN_MM + RULER_MM - 8
    x0 = MARGIN_MM
    ax.plot([x0, x0 + RULER_LENGTH_MM], [y, y], color="black", linewidth=0.8)
    for mm in np.arange(0, RULER_LENGTH_MM + 1e-9, 10):
        tick = 3.0 if mm % 50 == 0 else 1.8
        ax.plot([x0 + mm, x0 + mm], [y, y + tick], color="black", linewidth=0.6)
    ax.text(
        x0,
        y - 2,
        f'Print at actual size (100%, not "fit to page"): this line is {RULER_LENGTH_MM:g} mm. Then '
        f"measure a tag's black square: {page.tag_mm:g} mm is --tag-size {page.tag_mm / 1000:g}",
        ha="left",
        va="top",
        fontsize=7,
    )
    return fig


def tag_sheets(paper: str, dictionary_name: str, sheet_mm: float, object_mm: float | None) -> list[SheetPage]:
    """The calibration sheet (as many ``sheet_mm`` tags as fit, ids from 0) and, with
    ``object_mm``, a page with one larger tag to lay beside the object, whose id follows
    the sheet's."""
    from .aruco import get_dictionary

    d = get_dictionary(dictionary_name)
    n_ids = len(d.bytesList)
    sheet = grid_page(
        paper,
        sheet_mm,
        0,
        n_ids - (1 if object_mm else 0),
        f"nerfkit calibration sheet: {dictionary_name}, {sheet_mm:g} mm tags",
        "Lay it flat and photograph it 20-50 times from varied angles, the sheet in every part of "
        "the frame (nerfkit calibrate)",
    )
    pages = [sheet]
    if object_mm:
        tag_id = sheet.ids[-1] + 1
        pages.append(
            single_page(
                paper,
                object_mm,
                tag_id,
                d.markerSize + 2,
                f"nerfkit object tag: {dictionary_name} tag {tag_id}, {object_mm:g} mm",
                "Lay it flat beside the object and photograph both 50-100 times all around, at two "
                "or three heights (nerfkit capture)",
            )
        )
    return pages
