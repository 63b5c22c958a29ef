"""`nerfkit tags`: the printed sheet must be found by nerfkit's own detector at its stated size."""

from __future__ import annotations

import re

import numpy as np
import pytest

from nerfkit.cli import main

DPI = 100  # px per inch of the raster the pages are checked on


def raster(page, dictionary) -> np.ndarray:
    """(H, W) uint8 grey of a page drawn at DPI (what a flat scan of the print would be)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from nerfkit.capture.sheet import draw_page

    fig = draw_page(page, dictionary)
    canvas = FigureCanvasAgg(fig)
    fig.set_dpi(DPI)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., 0].copy()


@pytest.mark.parametrize(
    "paper, name, sheet_mm, object_mm", [("a4", "DICT_4X4_50", 50.0, 100.0), ("letter", "DICT_5X5_100", 30.0, 120.0)]
)
def test_printed_tags_are_detected_with_their_ids_sides_and_places(paper, name, sheet_mm, object_mm):
    from nerfkit.capture.aruco import detect, get_dictionary, make_detector
    from nerfkit.capture.sheet import PAPERS, tag_sheets

    d = get_dictionary(name)
    pages = tag_sheets(paper, name, sheet_mm, object_mm)
    assert [len(p.ids) for p in pages][1:] == [1] and pages[1].ids == [pages[0].ids[-1] + 1]
    assert pages[0].ids == list(range(len(pages[0].ids))) and len(pages[0].ids) >= 6
    px_per_mm = DPI / 25.4
    for page in pages:
        image = raster(page, d)
        w, h = PAPERS[paper]
        assert np.abs(np.subtract(image.shape, (h * px_per_mm, w * px_per_mm))).max() < 1
        found = detect(image, make_detector(name), detect_side=4000, marker_bits=d.markerSize)
        assert sorted(found.ids.tolist()) == page.ids
        for tag_id, corners in zip(found.ids, found.corners):
            sides = np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)
            np.testing.assert_allclose(sides, page.tag_mm * px_per_mm, atol=1.0)  # the stated side, to a pixel
            centre = page.centres[page.ids.index(int(tag_id))]  # mm from the lower left -> pixels from the top
            expected = np.array([centre[0], h - centre[1]]) * px_per_mm - 0.5
            np.testing.assert_allclose(corners.mean(0), expected, atol=1.0)


def test_the_largest_tags_fit_and_larger_ones_are_refused(tmp_path, capsys):
    from nerfkit.capture.sheet import grid_page, largest_sheet_tag_mm, largest_tag_mm, single_page, tag_area

    x0, y0, x1, y1 = tag_area("a4")
    big = largest_tag_mm("a4", 6)
    assert np.isclose(big * 8 / 6, min(x1 - x0, y1 - y0))  # a cell of white each side
    assert len(single_page("a4", big, 9, 6, "").ids) == 1
    assert len(grid_page("a4", largest_sheet_tag_mm("a4"), 0, 50, "").ids) == 1
    with pytest.raises(ValueError):
        grid_page("a4", largest_sheet_tag_mm("a4") + 1, 0, 50, "")
    assert main(["tags", "--out", str(tmp_path / "x.pdf"), "--object-tag-size", f"{(big + 1) / 1000:.4f}"]) == 2
    assert f"Use at most {int(big) / 1000:.3f}" in capsys.readouterr().err
    assert main(["tags", "--out", str(tmp_path / "x.pdf"), "--tag-size", "0.19"]) == 2
    assert "--tag-size: a 190 mm tag does not fit on a4 paper. Use at most 0.186" in capsys.readouterr().err
    assert not (tmp_path / "x.pdf").exists()


def test_cli_writes_a_two_page_pdf_of_the_paper_size_and_refuses_to_replace_it(tmp_path, capsys):
    out = tmp_path / "tags.pdf"
    assert (
        main(["tags", "--out", str(out), "--paper", "letter", "--tag-size", "0.04", "--object-tag-size", "0.12"]) == 0
    )
    text = capsys.readouterr().out
    assert "--sheet-tag-size 0.04 --tag-size 0.12" in text and "page 2: tag " in text
    pdf = out.read_bytes()
    boxes = re.findall(rb"/MediaBox \[ *0 0 ([\d.]+) ([\d.]+) *\]", pdf)
    assert len(boxes) == 2  # letter: 8.5 x 11 inches, in points
    for w, h in boxes:
        assert abs(float(w) - 612) < 0.5 and abs(float(h) - 792) < 0.5
    assert main(["tags", "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["tags", "--out", str(tmp_path / "one.pdf"), "--object-tag-size", "0"]) == 0
    assert len(re.findall(rb"/MediaBox", (tmp_path / "one.pdf").read_bytes())) == 1
    assert main(["tags", "--out", str(tmp_path / "t.png")]) == 2
    assert "should end in .pdf" in capsys.readouterr().err


def test_tags_too_small_to_find_are_refused(tmp_path, capsys):
    """A 0.1 mm tag (metres typed as tenths of a millimetre) has cells far under a millimetre."""
    from nerfkit.commands.tags import MIN_CELL_MM

    assert main(["tags", "--out", str(tmp_path / "t.pdf"), "--tag-size", "0.0001"]) == 2
    err = capsys.readouterr().err
    assert "--tag-size: a 0.1 mm tag has 0.017 mm cells" in err and f"Use at least {6 * MIN_CELL_MM / 1000:g}" in err
    assert main(["tags", "--out", str(tmp_path / "t.pdf"), "--object-tag-size", "0.004"]) == 2
    assert "--object-tag-size: a 4 mm tag" in capsys.readouterr().err
    assert not (tmp_path / "t.pdf").exists()
    assert main(["tags", "--out", str(tmp_path / "t.pdf"), "--tag-size", str(6 * MIN_CELL_MM / 1000)]) == 0
