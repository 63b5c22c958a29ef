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


def ramps(height: int, paper_slope: float, object_slope: float, base) -> np.ndarray:
    """(H, 512, 3) grey levels 0..255 (float: slopes below a level a pixel): brightness rising
    by ``object_slope`` a pixel over the columns 96..415 and by ``paper_slope`` elsewhere
    (continuous), on ``base`` (3,) in [0, 1]. At width 512 the gradient is in levels a pixel."""
    x = np.arange(512, dtype=np.float64)
    inside = np.clip(x - 96, 0, 320)
    ramp = paper_slope * (x - inside) + object_slope * inside
    return (255 * (np.asarray(base) + ramp[None, :, None])).repeat(height, 0).astype(np.float32)


def test_a_row_takes_medians_over_the_photos_and_skips_a_photo_without_paper():
    h = 48
    white, red = (0.7, 0.7, 0.7), (0.6, 0.1, 0.1)  # red: saturated, no paper anywhere
    # (paper slope, object slope) of each photo: the object's medians are 2, 8 and 4 (x 1e-4)
    views = SimpleNamespace(
        images=np.stack([ramps(h, 1e-4, 2e-4, white), ramps(h, 3e-4, 8e-4, white), ramps(h, 9e-4, 4e-4, red)])
    )
    obj = np.zeros((h, 512), bool)
    obj[:, 104:408] = True  # the object's columns (most of the photo), 8 px clear of the ramp's kinks
    row = od.learned_row(views, [obj, obj, obj], np.arange(3))
    assert row["learned_share"] == pytest.approx(304 / 512)
    # the median of 2, 8, 4 (not the mean 4.67, nor the middle photo's 8)
    assert row["learned"] == pytest.approx(4e-4, rel=1e-2)
    # the paper's figure: the median of the two photos with paper, 1 and 3 -> 2 (with the red
    # photo's 9 it would be 3; counting the red photo as 0 would give 1; taking the object's
    # pixels for paper, 5)
    assert row["paper"] == pytest.approx(2e-4, rel=1e-2)


def test_the_table_prints_a_dash_for_a_missing_figure_and_parse_rejects_a_bad_capture():
    row = {"capture": "can", "object": 0.002, "table": 0.0019, "plain": True, "learned": 0.001, "paper": None}
    line = od.table_markdown([row]).splitlines()[2]
    assert line == "| can | 0.0020 | 0.0019 | yes | 0.0010 | - | - |"
    assert od.parse_capture("can=a/b/dataset.npz:runs/x") == ("can", Path("a/b/dataset.npz"), Path("runs/x"))
    assert od.parse_capture("can=a/b/dataset.npz") == ("can", Path("a/b/dataset.npz"), None)
    with pytest.raises(NerfkitError, match="NAME=DATASET"):
        od.parse_capture("can=")
