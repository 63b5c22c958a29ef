"""The tools around the pipeline from Python (nerfkit.api: tags, frames, convert, dataset,
fit_image, view): every flag is an argument with its default, bad input is a NerfkitError
before anything is written, and each call does the command's work on a tiny generated input,
with the command's report and files."""

from __future__ import annotations

import inspect
import re
import zlib

import numpy as np
import pytest

from nerfkit import api
from nerfkit.cli import main
from nerfkit.errors import NerfkitError

# a command's flag -> the API's argument of another name
RENAMED = {"dict": "dictionary"}


@pytest.mark.parametrize(
    ("command", "function", "argv", "given", "api_only"),
    [
        ("tags", api.tags, [], set(), {"quiet"}),
    ],
)
def test_every_flag_of_a_tool_is_an_argument_with_its_default(command, function, argv, given, api_only):
    """As test_api_capture's: a call without options does what the command line without options
    does. ``given``: the command's required arguments; ``api_only``: the API's own arguments
    (``quiet``: the command line always prints its report). The flags of a settings dataclass
    are its ``settings`` argument (None: its defaults), as the command line's unset flags are None."""
    from nerfkit.cli import build_parser

    args = build_parser(command).parse_args([command, *argv])
    params = inspect.signature(function).parameters
    checked = set(given)
    for dest, value in vars(args).items():
        if dest in ("command", "func", "verbose") or dest in given:
            continue
        name = RENAMED.get(dest, dest.removeprefix("no_"))
        if name not in params:  # a field of the settings dataclass: unset, so None
            assert value is None and "settings" in params, dest
            checked.add("settings")
            continue
        expected = (not value) if dest.startswith("no_") else value
        assert params[name].default == expected, (dest, params[name].default, expected)
        checked.add(name)
    assert set(params) - checked == api_only


def test_the_choices_of_the_tools_are_the_flags():
    from typing import get_args

    from nerfkit.capture.sheet import PAPERS

    assert set(get_args(api.Paper)) == set(PAPERS)


# ----------------------------------------------------------------------------- tags


def raster_pdf(pdf: bytes, dpi: int = 100) -> list[np.ndarray]:
    """Each page of a PDF as (H, W) uint8 grey at ``dpi``: its black filled straight-edged paths
    (what matplotlib writes for the tags' cells) on white. Text and strokes are left out."""
    import cv2

    objects = {int(n): body for n, body in re.findall(rb"(\d+) 0 obj(.*?)endobj", pdf, re.S)}
    pages = []
    for box, contents in re.findall(rb"/MediaBox \[ *0 0 ([\d.]+ [\d.]+) *\]\s*/Contents (\d+) 0 R", pdf):
        w, h = map(float, box.split())
        scale = dpi / 72
        stream = re.search(rb"stream\r?\n(.*)endstream", objects[int(contents)], re.S).group(1)
        image = np.full((round(h * scale), round(w * scale)), 255, np.uint8)
        numbers, polygons, black = [], [], False
        for token in zlib.decompress(stream).split():
            try:
                numbers.append(float(token))
                continue
            except ValueError:
                pass
            if token == b"g":
                black = numbers[-1] == 0
            elif token == b"m":
                polygons.append([numbers[-2:]])
            elif token == b"l":
                polygons[-1].append(numbers[-2:])
            elif token in (b"f", b"f*"):
                if black:
                    pixels = [np.round((np.array(p) * [1, -1] + [0, h]) * scale).astype(np.int32) for p in polygons]
                    cv2.fillPoly(image, pixels, 0)
                polygons = []
            elif token in (b"S", b"n"):
                polygons = []
            numbers = []
        pages.append(image)
    return pages


def tag_ids(image: np.ndarray, dictionary: str = "DICT_4X4_50") -> list[int]:
    """The ids of the tags OpenCV finds in ``image``, in order."""
    from nerfkit.capture.aruco import detect, get_dictionary, make_detector

    bits = get_dictionary(dictionary).markerSize
    found = detect(image, make_detector(dictionary), detect_side=4000, marker_bits=bits)
    return sorted(found.ids.tolist())


def test_tags_writes_a_pdf_whose_tags_opencv_finds_as_the_command_does(tmp_path, capsys):
    result = api.tags(tmp_path / "a.pdf", paper="letter", tag_size=0.04, object_tag_size=0.12)
    by_api = capsys.readouterr().out
    assert result == api.TagsResult(tmp_path / "a.pdf", 2, result.sheet_ids, result.sheet_ids[-1] + 1)
    assert result.sheet_ids == tuple(range(len(result.sheet_ids))) and len(result.sheet_ids) >= 6
    pages = raster_pdf(result.pdf_path.read_bytes())
    assert len(pages) == 2 and pages[0].shape == (1100, 850)  # letter at 100 dpi
    assert tag_ids(pages[0]) == list(result.sheet_ids) and tag_ids(pages[1]) == [result.object_tag_id]

    argv = ["tags", "--out", str(tmp_path / "b.pdf"), "--paper", "letter", "--tag-size", "0.04"]
    assert main([*argv, "--object-tag-size", "0.12"]) == 0
    assert capsys.readouterr().out == by_api.replace("a.pdf", "b.pdf")
    assert all(np.array_equal(a, b) for a, b in zip(pages, raster_pdf((tmp_path / "b.pdf").read_bytes())))

    alone = api.tags(tmp_path / "c.pdf", object_tag_size=0, quiet=True)
    assert capsys.readouterr().out == "" and alone.pages == 1 and alone.object_tag_id is None
    assert len(raster_pdf(alone.pdf_path.read_bytes())) == 1


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"paper": "a3"}, "--paper: 'a3' is not one of a4, letter"),
        ({"tag_size": 60.0}, "--tag-size: 60.0 is not a printed tag's side in metres"),
        ({"tag_size": 0.0001}, "--tag-size: a 0.1 mm tag has 0.017 mm cells"),
        ({"object_tag_size": 0.3}, "--object-tag-size: a 300 mm tag does not fit on a4 paper"),
        ({"object_tag_size": None}, "--object-tag-size: None is not a number"),
        ({"dictionary": "DICT_9X9"}, "unknown ArUco dictionary"),
        ({"out": "tags.png"}, "--out: 'tags.png' should end in .pdf"),
    ],
)
def test_tags_refuses_what_the_command_line_refuses(tmp_path, monkeypatch, options, message):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(NerfkitError, match=message):
        api.tags(**{"out": "tags.pdf", **options})
    assert list(tmp_path.iterdir()) == []
