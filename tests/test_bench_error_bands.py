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


def test_psnr_of_no_error_is_infinite():
    assert error_bands.psnr_of(0.0) == math.inf
    assert math.isclose(error_bands.psnr_of(1e-3), 30.0)
