"""Gaussian splats in the browser: viser draws them itself (``scene.add_gaussian_splats``)."""

from __future__ import annotations

import numpy as np
import torch

from ..kernels.splat_reference import covariance_3d
from ..splat_files import Gaussians, dc_to_rgb, rotation_quats


def splat_arrays(g: Gaussians) -> dict:
    """What viser's ``add_gaussian_splats`` takes: ``centers`` (n, 3), ``covariances``
    (n, 3, 3) ``R S S^T R^T``, ``rgbs`` (n, 3) the DC colour in [0, 1], ``opacities`` (n, 1)."""
    q = rotation_quats(g.quats)
    cov = covariance_3d(torch.from_numpy(g.log_scales.astype(np.float64)), torch.from_numpy(q)).numpy()
    return {
        "centers": g.means.astype(np.float32),
        "covariances": cov.astype(np.float32),
        "rgbs": np.clip(dc_to_rgb(g.sh_dc), 0, 1).astype(np.float32),
        "opacities": (1 / (1 + np.exp(-g.opacity_logits.astype(np.float64)))).reshape(-1, 1).astype(np.float32),
    }


def add_splats(server, model, name: str = "/splats"):
    """Draw a splat model's Gaussians in a viser server; returns the handle."""
    return server.scene.add_gaussian_splats(name, **splat_arrays(Gaussians.from_model(model)))
