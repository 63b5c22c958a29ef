"""benchmarks/plain_objects.py: the photos' detail on a run's learned object and on the paper beside it."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from nerfkit.errors import NerfkitError
from nerfkit.object_detail import gradient_magnitude

_spec = importlib.util.spec_from_file_location(
    "plain_objects", Path(__file__).resolve().parents[1] / "benchmarks" / "plain_objects.py"
)
od = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(od)


def test_a_flat_photo_has_no_gradient_and_a_checkerboard_a_large_one():
    flat = np.full((64, 128, 3), 0.7, np.float32)
    assert gradient_magnitude(flat).max() == pytest.approx(0.0, abs=1e-6)
    checks = ((np.indices((64, 128)).sum(0) // 4) % 2).astype(np.float32)
    board = np.repeat(checks[..., None], 3, -1)
    assert np.median(gradient_magnitude(board)) > 0.01


def test_paper_is_bright_unsaturated_and_away_from_other_pixels():
    rgb = np.full((40, 40, 3), 0.9, np.float32)
    rgb[:, :10] = (0.9, 0.2, 0.2)  # red: saturated
    rgb[30:] = 0.3  # grey: too dark
    mask = od.paper_mask(rgb, shrink=2)
    assert mask[15, 25] and not mask[15, 5] and not mask[35, 25]
    # shrunk by 2 pixels from the red columns and the dark rows, not from the border
    assert not mask[15, 11] and mask[15, 12] and not mask[28, 25] and mask[27, 25] and mask[0, 39]


def test_a_row_takes_medians_over_the_photos_and_skips_a_photo_without_paper():
    h, w = 48, 64
    smooth = np.full((h, w, 3), 230, np.uint8)
    rough = smooth.copy()
    rough[:, :32] = (((np.indices((h, 32)).sum(0) // 2) % 2) * 200 + 20)[..., None]  # an object of checks
    red = np.zeros((h, w, 3), np.uint8)
    red[...] = (200, 30, 30)  # no paper anywhere
    views = SimpleNamespace(images=np.stack([smooth, rough, red]))
    obj = np.zeros((h, w), bool)
    obj[8:40, 4:28] = True
    row = od.learned_row(views, [obj, obj, obj], np.arange(3))
    assert row["learned_share"] == pytest.approx(obj.mean())
    per_photo = [od.median_over(gradient_magnitude(im / 255.0), obj) for im in views.images]
    assert row["learned"] == pytest.approx(np.median(per_photo))
    assert per_photo[1] > 0.01 and per_photo[0] == pytest.approx(0.0, abs=1e-6)
    # the paper's figure comes from the two photos that have paper; it is flat there
    assert row["paper"] == pytest.approx(0.0, abs=1e-6)


def test_the_table_prints_a_dash_for_a_missing_figure_and_parse_rejects_a_bad_capture():
    row = {"capture": "can", "object": 0.002, "table": 0.0019, "plain": True, "learned": 0.001, "paper": None}
    line = od.table_markdown([row]).splitlines()[2]
    assert line == "| can | 0.0020 | 0.0019 | yes | 0.0010 | - | - |"
    assert od.parse_capture("can=a/b/dataset.npz:runs/x") == ("can", Path("a/b/dataset.npz"), Path("runs/x"))
    assert od.parse_capture("can=a/b/dataset.npz") == ("can", Path("a/b/dataset.npz"), None)
    with pytest.raises(NerfkitError, match="NAME=DATASET"):
        od.parse_capture("can=")
