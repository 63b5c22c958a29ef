"""Evaluate a trained model on a split's images: PSNR and SSIM per image and mean."""

from __future__ import annotations

import numpy as np
import torch

from ..data.scene import Views
from ..models.base import NerfModel
from ..render.renderer import render_views
from .metrics import psnr, ssim


def evaluate_views(model: NerfModel, views: Views, background: torch.Tensor, chunk: int = 16384,
                   autocast_dtype: torch.dtype | None = None, progress: bool = True) -> dict:
    """Render every view and compare with its image.

    Returns ``{"psnr": mean, "ssim": mean, "n_images": N, "per_image": [{index, name,
    psnr, ssim}, ...]}``. Memory holds one image at a time.
    """
    from tqdm import tqdm

    per_image = []
    renders = render_views(model, views, background, chunk, autocast_dtype)
    for i, view in enumerate(tqdm(renders, total=len(views), desc="eval", unit="view", disable=None if progress else True)):
        target = views.images[i].astype(np.float32) / 255.0
        per_image.append({
            "index": i,
            "name": views.names[i] if views.names else None,
            "psnr": round(psnr(view.rgb, target), 4),
            "ssim": round(ssim(view.rgb, target), 5),
        })
    return {
        "psnr": round(float(np.mean([p["psnr"] for p in per_image])), 4),
        "ssim": round(float(np.mean([p["ssim"] for p in per_image])), 5),
        "n_images": len(per_image),
        "per_image": per_image,
    }
