"""The error-band split of benchmarks/error_bands.py: a colour offset is all low frequency,
a pixel checkerboard all high, and the two bands' errors add up to the whole's."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np

_spec = importlib.util.spec_from_file_location(
    "error_bands", Path(__file__).resolve().parents[1] / "benchmarks" / "error_bands.py"
)
error_bands = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(error_bands)


def _photo(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.2, 0.8, (64, 48, 3)).astype(np.float32)


def test_a_colour_offset_is_all_low_frequency():
    photo = _photo()
    whole, low, high = error_bands.error_bands(photo + 0.1, photo)
    assert math.isclose(whole, 20.0, abs_tol=1e-3)  # mse 0.01
    assert math.isclose(low, whole, abs_tol=1e-3)
    assert high > 80.0


def test_a_pixel_checkerboard_is_all_high_frequency():
    photo = _photo(1)
    yy, xx = np.mgrid[:64, :48]
    board = np.where((yy + xx) % 2 == 0, 0.1, -0.1).astype(np.float32)[..., None]
    whole, low, high = error_bands.error_bands(photo + board, photo)
    assert math.isclose(whole, 20.0, abs_tol=1e-3)
    assert low > whole + 30.0
    assert math.isclose(high, whole, abs_tol=0.01)


def test_the_bands_errors_add_up_to_the_whole():
    photo, render = _photo(2), _photo(3)
    whole, low, high = error_bands.error_bands(render, photo, sigma=3.0)
    mse = [10.0 ** (-p / 10.0) for p in (whole, low, high)]
    assert math.isclose(mse[1] + mse[2], mse[0], rel_tol=0.05)
    assert mse[2] > mse[1]  # independent noise is mostly fine detail


def test_a_tag_seen_straight_on_covers_its_grown_square_about_the_principal_point():
    # a 0.1 m tag 1 m under a camera looking straight down (OpenCV axes: z forward, y down)
    side, f, w, h = 0.1, 400.0, 200, 160
    K = np.array([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])
    c2w = np.diag([1.0, -1.0, -1.0, 1.0])
    c2w[2, 3] = 1.0
    s = side / 2
    tags = np.array([[[-s, s, 0.0], [s, s, 0.0], [s, -s, 0.0], [-s, -s, 0.0]]])
    mask = error_bands.tag_mask(K, c2w, tags, w, h)
    grown = error_bands.TAG_GROWTH * side * f  # pixels a side
    assert abs(mask.sum() - grown**2) < 4 * grown  # the square, up to its edge pixels
    rows, cols = np.nonzero(mask)
    assert abs(cols.mean() + 0.5 - w / 2) < 1.0 and abs(rows.mean() + 0.5 - h / 2) < 1.0
    behind = c2w.copy()
    behind[2, 3] = -1.0  # the tag behind the camera: nothing
    assert not error_bands.tag_mask(K, behind, tags, w, h).any()


def test_masked_high_scores_the_masked_pixels_apart():
    photo = _photo(4)
    yy, xx = np.mgrid[:64, :48]
    board = np.where((yy + xx) % 2 == 0, 0.1, -0.1).astype(np.float32)[..., None]
    mask = np.zeros((64, 48), bool)
    mask[16:48, 12:36] = True
    render = photo + board * mask[..., None]  # fine detail wrong inside the mask only
    inside, outside = error_bands.masked_high(render, photo, mask)
    assert inside < 22.0 and outside > inside + 10.0
