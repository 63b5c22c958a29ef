"""Photos whose tags are not of the dictionary asked for: which dictionary to pass instead,
found from a few photos before the slow scan of them all."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from nerfkit.capture import aruco as A
from nerfkit.capture import photos as P
from nerfkit.capture import synthetic as S
from nerfkit.errors import NerfkitError


def tag_photo(dictionary: str | None, ids: list[int], k: int = 0) -> np.ndarray:
    """A 480x640 photo of white paper showing tags ``ids`` of ``dictionary`` in a row (none
    without a dictionary); ``k`` shifts the tags and paper so no two photos are copies."""
    img = np.full((480, 640, 3), 235 - k % 7, np.uint8)
    for j, tag in enumerate(ids):
        marker = cv2.aruco.generateImageMarker(A.get_dictionary(dictionary), tag, 120)
        x, y = 30 + 150 * j + 3 * (k % 5), 160 + 4 * (k % 9)
        img[y : y + 120, x : x + 120] = marker[..., None]
    return img


def folder_of(path, photos: list[np.ndarray]):
    path.mkdir()
    for k, img in enumerate(photos):
        S.write_photo(path / f"p{k:02d}.png", img)
    return path


def count_loads(monkeypatch) -> list[str]:
    """The names of the photos :mod:`nerfkit.capture.photos` loads, in order."""
    loaded: list[str] = []
    real = P.load_image_uint8
    monkeypatch.setattr(P, "load_image_uint8", lambda path, *a, **k: loaded.append(path.name) or real(path, *a, **k))
    return loaded


def run(argv):
    from nerfkit.cli import build_parser

    args = build_parser().parse_args(argv)
    return args.func(args)


@pytest.mark.parametrize(
    "dictionary, ids, smallest",
    [
        ("DICT_4X4_50", [3, 7], "DICT_4X4_50"),
        ("DICT_4X4_100", [57], "DICT_4X4_100"),
        ("DICT_5X5_100", [77], "DICT_5X5_100"),
        ("DICT_6X6_250", [120, 4], "DICT_6X6_250"),
        ("DICT_6X6_1000", [260], "DICT_6X6_1000"),
        ("DICT_APRILTAG_36h11", [5], "DICT_APRILTAG_36h11"),
    ],
)
def test_the_search_names_the_smallest_dictionary_holding_the_ids(dictionary, ids, smallest):
    search = A.DictionarySearch()
    for k in range(3):
        search.add(tag_photo(dictionary, ids, k))
    best = search.finds()[0]
    assert (best.name, best.ids, best.photos, search.photos) == (smallest, sorted(ids), 3, 3)


def test_the_dictionary_asked_for_is_not_searched_again():
    assert "DICT_4X4_1000" not in A.DictionarySearch(skip="4x4_1000").detectors
    assert "DICT_4X4_1000" in A.DictionarySearch(skip="DICT_4X4_50").detectors  # its family may hold the ids


def test_ids_seen_in_few_photos_do_not_choose_the_dictionary():
    # A _1000 dictionary reads ids in textures (the real photos' floor: 17 or 987 in one photo
    # of five beside the tag 0 in all): the suggestion is the dictionary of the tag.
    find = A._find("DICT_4X4_1000", [{0}, {0}, {0, 987}, {0}, set()])
    assert (find.name, find.ids, find.photos, find.misreads) == ("DICT_4X4_50", [0], 4, [987])
    # Tags of one sheet seen in most photos all count.
    find = A._find("DICT_4X4_1000", [{0, 60}, {0, 60}, {60}, {0}])
    assert (find.name, find.ids, find.misreads) == ("DICT_4X4_100", [0, 60], [])
    assert A._find("DICT_5X5_1000", [set(), set()]) is None


def test_the_sample_is_spread_through_the_photos():
    assert P.spread(31) == [0, 8, 15, 22, 30]
    assert P.spread(3) == [0, 1, 2] and P.spread(0) == []


def test_a_wrong_dictionary_is_named_from_a_sample_before_the_scan(tmp_path, monkeypatch, capsys):
    folder = folder_of(tmp_path / "photos", [tag_photo("DICT_5X5_100", [60, 77], k) for k in range(12)])
    loaded = count_loads(monkeypatch)
    scanned: list[str] = []
    monkeypatch.setattr(P, "_detect_one", lambda path, *a, **k: scanned.append(path.name))
    with pytest.raises(NerfkitError) as e:
        run(["poses", str(folder), "--tag-size", "0.05", "--out", str(tmp_path / "ds")])
    msg = str(e.value)
    assert msg.startswith(f"{folder}: no DICT_4X4_50 tags in 5 photos spread through the 12, but DICT_5X5_100 tags")
    assert "(ids 60, 77, in 5 of the 5 photos searched)" in msg and msg.endswith("Re-run with --dict DICT_5X5_100")
    assert loaded == ["p00.png", "p03.png", "p06.png", "p08.png", "p11.png"] and scanned == []
    assert "looking for DICT_4X4_50 and other dictionaries' tags in 5 of the 12 photos" in capsys.readouterr().err


def test_calibrate_names_the_dictionary_too(tmp_path):
    folder = folder_of(tmp_path / "photos", [tag_photo("DICT_6X6_250", [0, 1], k) for k in range(3)])
    with pytest.raises(NerfkitError) as e:
        run(
            ["calibrate", str(folder), "--tag-size", "0.05", "--dict", "DICT_4X4_50", "--out", str(tmp_path / "c.json")]
        )
    msg = str(e.value)
    assert "no DICT_4X4_50 tags in any of the 3 photos, but DICT_6X6_50 tags are there" in msg and "\n" not in msg
    assert msg.endswith("Re-run with --dict DICT_6X6_50")


def test_a_right_dictionary_costs_the_scan_one_photo(tmp_path, monkeypatch):
    folder = folder_of(tmp_path / "photos", [tag_photo("DICT_4X4_50", [0], k) for k in range(6)])
    loaded = count_loads(monkeypatch)
    records = P.scan_photos(folder, "DICT_4X4_50", jobs=1, progress=False)
    assert all(list(r.detection.ids) == [0] for r in records)
    assert sorted(loaded) == sorted(["p00.png"] + [r.name for r in records])  # the probe read one


def test_another_dictionarys_tag_in_one_sample_photo_does_not_stop_the_scan(tmp_path):
    # The sample's first photo shows a 5x5 tag, a photo outside the sample the 4x4 tag asked for.
    photos = [tag_photo(None, [], k) for k in range(7)]
    photos[0], photos[1] = tag_photo("DICT_5X5_100", [77]), tag_photo("DICT_4X4_50", [2], 1)
    records = P.scan_photos(folder_of(tmp_path / "photos", photos), "DICT_4X4_50", jobs=1, progress=False)
    assert [list(r.detection.ids) for r in records][:2] == [[], [2]]


def test_after_the_scan_the_dictionary_most_photos_show_is_named(tmp_path):
    folder = folder_of(tmp_path / "photos", [tag_photo("DICT_5X5_100", [77], k) for k in range(3)])
    empty = A.Detection(640, 480, np.zeros(0, np.int64), np.zeros((0, 4, 2)))
    records = [P.PhotoRecord(p.name, p, empty) for p in sorted(folder.iterdir())]  # a scan that found nothing
    with pytest.raises(NerfkitError) as e:
        P.require_tags(records, folder, "DICT_4X4_50", progress=False)
    msg = str(e.value)
    assert "no DICT_4X4_50 tags found in any of 3 photos, but DICT_5X5_100 tags are there (id 77, in 3 of" in msg
    assert msg.endswith("Re-run with --dict DICT_5X5_100")


def test_the_search_goes_past_the_sample_unless_most_of_it_shows_tags(tmp_path, monkeypatch, capsys):
    photos = [tag_photo(None, [], k) for k in range(7)]
    photos[5] = tag_photo("DICT_5X5_100", [77], 5)  # outside the sample (photos 0, 2, 3, 4, 6)
    folder = folder_of(tmp_path / "photos", photos)
    records = P.scan_photos(folder, "DICT_4X4_50", jobs=1, progress=False)
    loaded = count_loads(monkeypatch)
    with pytest.raises(NerfkitError) as e:
        P.require_tags(records, folder, "DICT_4X4_50")
    assert loaded == [f"p{k:02d}.png" for k in (0, 2, 3, 4, 6, 1, 5)]  # the sample first
    assert "not in most of them: looking in the other 2 photos" in capsys.readouterr().err
    # In one photo of seven: named, with the photo, but as what it may be (a texture can read as a tag).
    msg = str(e.value)
    assert msg.startswith(f"{folder}: no DICT_4X4_50 tags found in any of 7 photos (also tried DICT_4X4_*, ")
    assert "; DICT_5X5_100 reads id 77 in 1 of them (p05.png): a tag, or a pattern misread as one." in msg
    assert "If it is a tag, re-run with --dict DICT_5X5_100; else check that the tags are in focus" in msg
    photos[5] = tag_photo(None, [], 5)
    folder = folder_of(tmp_path / "blank", photos)
    with pytest.raises(NerfkitError, match=r"in any of 7 photos \(also tried DICT_4X4_\*.*\)\. Check that the tags"):
        P.require_tags(P.scan_photos(folder, "DICT_4X4_50", jobs=1, progress=False), folder, "DICT_4X4_50")
