"""Image-quality metrics."""

from __future__ import annotations

import math

import numpy as np


def psnr_from_mse(mse: float) -> float:
    """PSNR in dB for images in [0, 1]: ``10 log10(1 / mse)`` (inf for a perfect match)."""
    return float("inf") if mse <= 0 else -10.0 * math.log10(mse)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) between two float images in [0, 1] of the same shape."""
    return psnr_from_mse(float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Structural similarity of two (H, W, 3) float images in [0, 1] (scikit-image, Gaussian
    window of sigma 1.5 as in Wang et al. 2004 and the NeRF papers)."""
    from skimage.metrics import structural_similarity

    return float(structural_similarity(np.asarray(a, np.float64), np.asarray(b, np.float64), channel_axis=-1,
                                       data_range=1.0, gaussian_weights=True, sigma=1.5,
                                       use_sample_covariance=False))
