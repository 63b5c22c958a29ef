"""Render whole images from a model, in chunks so memory stays bounded."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

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
    hit); it is 0 where nothing was hit. ``scene_depth`` and ``scene_acc`` are the same of
    everything the rays meet, with the surfaces a model draws behind its volume (a
    capture's table and room; see :class:`~nerfkit.models.base.RenderOutput`), or None.
    """

    rgb: np.ndarray
    depth: np.ndarray
    acc: np.ndarray
    scene_depth: np.ndarray | None = None
    scene_acc: np.ndarray | None = None

    def depth_colours(self, near: float, far: float) -> np.ndarray:
        """(H, W, 3) float depth of everything seen, coloured from ``near`` (warm) to
        ``far`` (cool) (:func:`~nerfkit.viz.video.colorize_depth`): with surfaces behind
        the volume (a capture's table and room), what the rays do not meet is infinitely
        far; else it is empty (black)."""
        from ..viz.video import colorize_depth

        if self.scene_depth is None or self.scene_acc is None:
            return colorize_depth(self.depth, self.acc, near, far)
        return colorize_depth(self.scene_depth, self.scene_acc, near, far, unmet_is_far=True)


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
    abort: Callable[[], bool] | None = None,
) -> RenderedView | None:
    """Render one view, ``chunk`` rays at a time (peak memory ~ chunk x samples); models
    that render whole views (``whole_images``, e.g. splat) render it at once. None when
    ``abort()`` turns true between chunks (a viewer's camera moved on). A model with an
    ``appearance`` (a capture's) renders in the colour of the training photos taken near
    ``c2w`` (:class:`~nerfkit.models.appearance.DirectionalColour`)."""
    device = background.device
    if getattr(model, "whole_images", False):
        return _render_whole(model, K, c2w, width, height, background)
    rays = image_rays(
        torch.as_tensor(K, dtype=torch.float32), torch.as_tensor(c2w, dtype=torch.float32).to(device), width, height
    )
    rgb, depth, acc, scene_depth, scene_acc = [], [], [], [], []
    was_training = model.training
    model.eval()
    try:
        for start in range(0, len(rays), chunk):
            if abort is not None and abort():
                return None
            with autocast(device, autocast_dtype):
                out = model.render_rays(rays[start : start + chunk], background, perturb=False)
            rgb.append(out.rgb.float())
            depth.append(out.depth.float())
            acc.append(out.acc.float())
            if out.scene_depth is not None and out.scene_acc is not None:
                scene_depth.append(out.scene_depth.float())
                scene_acc.append(out.scene_acc.float())
    finally:
        model.train(was_training)
    rgb_t = in_view_colour(model, torch.cat(rgb), c2w).clamp(0, 1).reshape(height, width, 3)
    view = RenderedView(rgb_t.cpu().numpy(), *_depth_image(torch.cat(depth), torch.cat(acc), width, height))
    if scene_depth:
        view.scene_depth, view.scene_acc = _depth_image(torch.cat(scene_depth), torch.cat(scene_acc), width, height)
    return view


def in_view_colour(model: NerfModel, rgb: torch.Tensor, c2w: np.ndarray) -> torch.Tensor:
    """(..., 3) colours ``model`` rendered at ``c2w`` (4, 4) -> in its ``appearance`` there
    (as they are without one)."""
    appearance = getattr(model, "appearance", None)
    return rgb if appearance is None else appearance.apply(rgb, c2w)


def _depth_image(depth: torch.Tensor, acc: torch.Tensor, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(n,) expected depth (unnormalised) and opacity -> (H, W) depth of what was hit (0
    where nothing was) and (H, W) opacity."""
    acc = acc.reshape(height, width)
    depth = torch.where(acc > 1e-3, depth.reshape(height, width) / acc.clamp_min(1e-6), torch.zeros_like(acc))
    return depth.cpu().numpy(), acc.cpu().numpy()


@torch.no_grad()
def probe_renders(
    model: NerfModel,
    views: Views,
    n_views: int,
    width: int,
    background: torch.Tensor,
    chunk: int = 16384,
    autocast_dtype: torch.dtype | None = None,
    zoom: float = 1.0,
) -> Iterator[tuple[int, np.ndarray, RenderedView]]:
    """Small renders of up to ``n_views`` views spread along ``views``: ``(index, K, view)``
    with the intrinsics they were rendered with, ``width`` pixels wide (the height in
    proportion) and the focal length times ``zoom`` about the principal point (below 1:
    more of the scene than the view holds)."""
    from ..data.resample import scale_intrinsics

    h = max(round(views.height * width / views.width), 1)
    for i in np.unique(np.linspace(0, len(views) - 1, min(n_views, len(views))).round().astype(int)):
        K = scale_intrinsics(views.K[i], views.width, views.height, width, h)
        K[0, 0] *= zoom
        K[1, 1] *= zoom
        view = render_image(model, K, views.c2w[i], width, h, background, chunk, autocast_dtype)
        assert view is not None  # None only when aborted
        yield int(i), K, view


def object_aim(
    model: NerfModel,
    views: Views,
    up: np.ndarray,
    background: torch.Tensor,
    chunk: int = 16384,
    autocast_dtype: torch.dtype | None = None,
    n_views: int = 16,
    width: int = 64,
    min_points: int = 64,
) -> np.ndarray | None:
    """(3,) where the trained object is, to aim an orbit at, from the points where the model
    stops the rays of up to ``n_views`` training views (rendered ``width`` pixels wide;
    rays with accumulated opacity above 0.5 only, so thin haze and what the table or room
    explain do not count): across ``up`` their median, along ``up`` their lower quartile
    (floaters gather high up, near the cameras, not under the object). None with fewer
    than ``min_points`` such rays. Models that render whole views answer with their own
    ``object_center()``."""

    if getattr(model, "whole_images", False):
        return model.object_center()
    if len(views) == 0:
        return None
    points = []
    for i, K, view in probe_renders(model, views, n_views, width, background, chunk, autocast_dtype):
        h, w = view.acc.shape
        rays = image_rays(
            torch.as_tensor(K, dtype=torch.float32), torch.as_tensor(views.c2w[i], dtype=torch.float32), w, h
        )
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


@dataclass
class Framing:
    """An object-only video's cameras: ``views`` zoomed ``zoom`` times and centred on the
    object, and the depth range ``near``-``far`` (n_views,) each frame of its depth video is
    coloured over."""

    views: Views
    zoom: float
    near: np.ndarray
    far: np.ndarray


def frame_object(
    model: NerfModel,
    views: Views,
    background: torch.Tensor,
    chunk: int = 16384,
    autocast_dtype: torch.dtype | None = None,
    fill: float = 0.8,
    n_probe: int = 12,
    width: int = 128,
    zoom_range: tuple[float, float] = (0.5, 4.0),
    aim: np.ndarray | None = None,
) -> Framing | None:
    """Frame what ``model`` holds (an object alone, :func:`~nerfkit.surroundings.isolate_object`) in
    every view of a path: one zoom and one shift of the principal point for the whole path
    (so the object turns in place), chosen so the box around the object's pixels
    (opacity > 0.5) in up to ``n_probe`` views spans ``fill`` of the frame, centred. The
    probes are rendered ``width`` pixels wide at ``zoom_range[0]`` times the focal length,
    so an object that the path's own views cut off is measured whole. The zoom stays
    within ``zoom_range``. The depth range is that of those pixels (2% to 98%), widened by
    5%; with ``aim`` (3,), the point the path looks at, it is their depth less the camera's
    distance to ``aim``, added back per view: every frame shows the object's relief on the
    same scale, however far its camera is. None when no view sees anything.
    """
    if len(views) == 0:
        return None
    wide = zoom_range[0]
    lo, hi, depths = np.array([np.inf, np.inf]), np.array([-np.inf, -np.inf]), []
    offset = (
        np.zeros(len(views))
        if aim is None
        else np.linalg.norm(views.c2w[:, :3, 3].astype(np.float64) - np.asarray(aim, np.float64).reshape(1, 3), axis=1)
    )
    for i, K, view in probe_renders(model, views, n_probe, width, background, chunk, autocast_dtype, wide):
        solid = view.acc > 0.5
        if not solid.any():
            continue
        rows, cols = np.nonzero(solid)
        # pixel edges (x right, y down) relative to the principal point, in the full-size view's pixels
        scale = np.array([views.K[i][0, 0] / K[0, 0], views.K[i][1, 1] / K[1, 1]])
        lo = np.minimum(lo, scale * [cols.min() - K[0, 2], rows.min() - K[1, 2]])
        hi = np.maximum(hi, scale * [cols.max() + 1 - K[0, 2], rows.max() + 1 - K[1, 2]])
        depths.append(view.depth[solid] - offset[i])
    if not depths:
        return None
    zoom = fill * min(views.width / (hi[0] - lo[0]), views.height / (hi[1] - lo[1]))
    zoom = float(np.clip(zoom, *zoom_range))
    mid = (lo + hi) / 2
    K = views.K.copy()
    K[:, 0, 0] *= zoom
    K[:, 1, 1] *= zoom
    K[:, 0, 2] = views.width / 2 - zoom * mid[0]
    K[:, 1, 2] = views.height / 2 - zoom * mid[1]
    d = np.concatenate(depths)
    near, far = np.quantile(d, 0.02), np.quantile(d, 0.98)
    pad = 0.05 * max(far - near, 1e-6)
    return Framing(
        Views(views.c2w, K.astype(views.K.dtype), views.width, views.height),
        zoom,
        offset + near - pad,
        offset + far + pad,
    )


def _render_whole(model, K, c2w, width: int, height: int, background: torch.Tensor) -> RenderedView:
    was_training = model.training
    model.eval()
    try:
        out = model.render_view(K, c2w, width, height, background)
    finally:
        model.train(was_training)
    return RenderedView(
        in_view_colour(model, out.rgb.float(), c2w).clamp(0, 1).cpu().numpy(),
        *_depth_image(out.depth.float(), out.acc.float(), width, height),
    )


def render_views(
    model: NerfModel,
    views: Views,
    background: torch.Tensor,
    chunk: int = 16384,
    autocast_dtype: torch.dtype | None = None,
) -> Iterator[RenderedView]:
    """Render every view of a split, one at a time (a generator: memory holds one image)."""
    for i in range(len(views)):
        view = render_image(
            model, views.K[i], views.c2w[i], views.width, views.height, background, chunk, autocast_dtype
        )
        assert view is not None  # None only when aborted
        yield view
