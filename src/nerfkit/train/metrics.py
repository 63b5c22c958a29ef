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


def masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float | None:
    """PSNR (dB) of two (H, W, 3) float images in [0, 1] over the pixels where ``mask``
    (H, W) is True; None when it holds none."""
    if not np.any(mask):
        return None
    diff = np.asarray(a, np.float64)[mask] - np.asarray(b, np.float64)[mask]
    return psnr_from_mse(float(np.mean(diff**2)))


# scikit-image's Gaussian window of sigma 1.5, truncated at 3.5 sigma: 11 pixels a side
SSIM_WINDOW = 11


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Structural similarity of two (H, W, 3) float images in [0, 1] (scikit-image, Gaussian
    window of sigma 1.5 as in Wang et al. 2004 and the NeRF papers). Images narrower than
    that window get the largest odd uniform window that fits, and below 3 pixels a side a
    single window over the whole image."""
    from skimage.metrics import structural_similarity

    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    side = min(a.shape[:2])
    if side >= SSIM_WINDOW:
        return float(
            structural_similarity(
                a, b, channel_axis=-1, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False
            )
        )
    if side >= 3:
        return float(
            structural_similarity(
                a, b, channel_axis=-1, data_range=1.0, win_size=side - 1 + side % 2, use_sample_covariance=False
            )
        )
    c1, c2 = 0.01**2, 0.03**2
    mu_a, mu_b = a.mean((0, 1)), b.mean((0, 1))
    cov = ((a - mu_a) * (b - mu_b)).mean((0, 1))
    s = (2 * mu_a * mu_b + c1) * (2 * cov + c2) / ((mu_a**2 + mu_b**2 + c1) * (a.var((0, 1)) + b.var((0, 1)) + c2))
    return float(s.mean())
