"""Render whole images from a model, in chunks so memory stays bounded."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np
import torch

from ..cameras import image_rays
from ..data.scene import Views
from ..models.base import NerfModel
from ..precision import autocast


@dataclass
class RenderedView:
    """One rendered image: rgb (H, W, 3) float32 in [0, 1], depth and acc (H, W).

    ``depth`` is the expected depth divided by the opacity (the depth of what the ray
    hit); it is 0 where nothing was hit.
    """

    rgb: np.ndarray
    depth: np.ndarray
    acc: np.ndarray


@torch.no_grad()
def render_image(
    model: NerfModel,
    K: np.ndarray,
    c2w: np.ndarray,
    width: int,
    height: int,
    background: torch.Tensor,
    chunk: int = 16384,
    autocast_dtype: torch.dtype | None = None,
) -> RenderedView:
    """Render one view, ``chunk`` rays at a time (peak memory ~ chunk x samples); models
    that render whole views (``whole_images``, e.g. splat) render it at once."""
    device = background.device
    if getattr(model, "whole_images", False):
        return _render_whole(model, K, c2w, width, height, background)
    rays = image_rays(torch.as_tensor(K, dtype=torch.float32), torch.as_tensor(c2w, dtype=torch.float32).to(device),
                      width, height)
    rgb, depth, acc = [], [], []
    was_training = model.training
    model.eval()
    try:
        for start in range(0, len(rays), chunk):
            with autocast(device, autocast_dtype):
                out = model.render_rays(rays[start:start + chunk], background, perturb=False)
            rgb.append(out.rgb.float())
            depth.append(out.depth.float())
            acc.append(out.acc.float())
    finally:
        model.train(was_training)
    rgb_t = torch.cat(rgb).clamp(0, 1).reshape(height, width, 3)
    acc_t = torch.cat(acc).reshape(height, width)
    depth_t = torch.cat(depth).reshape(height, width) / acc_t.clamp_min(1e-6)
    depth_t = torch.where(acc_t > 1e-3, depth_t, torch.zeros_like(depth_t))
    return RenderedView(rgb_t.cpu().numpy(), depth_t.cpu().numpy(), acc_t.cpu().numpy())


@torch.no_grad()
def object_aim(model: NerfModel, views: Views, up: np.ndarray, background: torch.Tensor, chunk: int = 16384,
               autocast_dtype: torch.dtype | None = None, n_views: int = 16, width: int = 64,
               min_points: int = 64) -> np.ndarray | None:
    """(3,) where the trained object is, to aim an orbit at, from the points where the model
    stops the rays of up to ``n_views`` training views (rendered ``width`` pixels wide;
    rays with accumulated opacity above 0.5 only, so thin haze and what the table or room
    explain do not count): across ``up`` their median, along ``up`` their lower quartile
    (floaters gather high up, near the cameras, not under the object). None with fewer
    than ``min_points`` such rays. Models that render whole views answer with their own
    ``object_center()``."""
    from ..data.load import scale_intrinsics

    if getattr(model, "whole_images", False):
        return model.object_center()
    if len(views) == 0:
        return None
    h = max(round(views.height * width / views.width), 1)
    points = []
    for i in np.unique(np.linspace(0, len(views) - 1, min(n_views, len(views))).round().astype(int)):
        K = scale_intrinsics(views.K[i], views.width, views.height, width, h)
        view = render_image(model, K, views.c2w[i], width, h, background, chunk, autocast_dtype)
        rays = image_rays(torch.as_tensor(K, dtype=torch.float32), torch.as_tensor(views.c2w[i], dtype=torch.float32),
                          width, h)
        solid = torch.from_numpy(view.acc.reshape(-1) > 0.5)
        depth = torch.from_numpy(view.depth.reshape(-1, 1))
        points.append((rays.origins + rays.directions * depth)[solid])
    pts = torch.cat(points).double()
    if len(pts) < min_points:
        return None
    u = torch.as_tensor(np.asarray(up, np.float64) / np.linalg.norm(up))
    height = pts @ u
    across = (pts - height[:, None] * u).median(dim=0).values
    return (across + torch.quantile(height, 0.25) * u).numpy()


def _render_whole(model, K, c2w, width: int, height: int, background: torch.Tensor) -> RenderedView:
    was_training = model.training
    model.eval()
    try:
        out = model.render_view(K, c2w, width, height, background)
    finally:
        model.train(was_training)
    acc = out.acc.float()
    depth = torch.where(acc > 1e-3, out.depth.float() / acc.clamp_min(1e-6), torch.zeros_like(acc))
    return RenderedView(out.rgb.float().clamp(0, 1).cpu().numpy(), depth.cpu().numpy(), acc.cpu().numpy())


def render_views(
    model: NerfModel,
    views: Views,
    background: torch.Tensor,
    chunk: int = 16384,
    autocast_dtype: torch.dtype | None = None,
) -> Iterator[RenderedView]:
    """Render every view of a split, one at a time (a generator: memory holds one image)."""
    for i in range(len(views)):
        yield render_image(model, views.K[i], views.c2w[i], views.width, views.height, background, chunk, autocast_dtype)
