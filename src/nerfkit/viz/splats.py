"""Gaussian splats in the browser: viser draws them itself (``scene.add_gaussian_splats``)."""

from __future__ import annotations

import numpy as np

from ..splat_files import SH_C0, Gaussians


def splat_arrays(g: Gaussians) -> dict:
    """What viser's ``add_gaussian_splats`` takes: ``centers`` (n, 3), ``covariances``
    (n, 3, 3) ``R S S^T R^T``, ``rgbs`` (n, 3) the DC colour in [0, 1], ``opacities`` (n, 1)."""
    q = g.quats.astype(np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True).clip(1e-12)
    w, x, y, z = q.T
    R = np.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        1,
    ).reshape(-1, 3, 3)
    M = R * np.exp(g.log_scales.astype(np.float64))[:, None, :]
    return {
        "centers": g.means.astype(np.float32),
        "covariances": (M @ M.transpose(0, 2, 1)).astype(np.float32),
        "rgbs": np.clip(0.5 + SH_C0 * g.sh_dc.reshape(-1, 3), 0, 1).astype(np.float32),
        "opacities": (1 / (1 + np.exp(-g.opacity_logits.astype(np.float64)))).reshape(-1, 1).astype(np.float32),
    }


def add_splats(server, model, name: str = "/splats"):
    """Draw a splat model's Gaussians in a viser server; returns the handle."""
    return server.scene.add_gaussian_splats(name, **splat_arrays(Gaussians.from_model(model)))
