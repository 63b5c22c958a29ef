"""Resampling every format shares: :func:`resample_scene` resizes images and scales ``K``
so that the cameras stay exact. Below the format readers (they resample while reading)
and :mod:`.load` (which dispatches to them).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..config import MIN_DOWNSCALE, MIN_RESAMPLED_SIDE, range_problem
from ..errors import fail
from .scene import Scene, Views
from .validate import MAX_PIXELS


def output_size(width: int, height: int, size: int | None = None, downscale: float | None = None) -> tuple[int, int]:
    """Image size after resampling: ``size`` = new longest side in pixels, or ``downscale`` = divisor.

    Neither given: unchanged. Both given: an error (they would disagree).
    """
    if size is not None and downscale is not None:
        raise fail("--size/--downscale", "give one of them, not both")
    if size is not None:
        if size < 1:
            raise fail("--size", f"{size} must be a positive number of pixels")
        s = size / max(width, height)
    elif downscale is not None:
        problem = range_problem(downscale, float, min=MIN_DOWNSCALE)
        if problem:
            raise fail("--downscale", problem, "It divides the image size: 2 halves the images")
        s = 1.0 / downscale
    else:
        return width, height
    new = max(1, round(width * s)), max(1, round(height * s))
    if min(new) < MIN_RESAMPLED_SIDE <= min(width, height):
        flag = "--size" if size is not None else "--downscale"
        most = (
            f"--size {math.ceil(MIN_RESAMPLED_SIDE * max(width, height) / min(width, height))} or more"
            if size is not None
            else f"--downscale {min(width, height) / MIN_RESAMPLED_SIDE:g} or less"
        )
        raise fail(
            flag,
            f"would resample the {width}x{height} images to {new[0]}x{new[1]}, too small to hold a "
            f"scene (at least {MIN_RESAMPLED_SIDE} pixels a side)",
            f"Use {most}",
        )
    return new


def scale_intrinsics(K: np.ndarray, width: int, height: int, new_width: int, new_height: int) -> np.ndarray:
    """K (..., 3, 3) for images resampled from ``width x height`` to ``new_width x new_height``.

    Pixel edges map to pixel edges (u' = u * new_width / width), so with pixel centres at
    +0.5 the rays through corresponding image points are unchanged.
    """
    sx, sy = new_width / width, new_height / height
    out = np.array(K, dtype=np.float64, copy=True)
    out[..., 0, :] *= sx
    out[..., 1, :] *= sy
    return out.astype(np.float32)


def resize_image(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resample a (H, W, 3) uint8 image to (height, width, 3): area averaging when shrinking,
    bicubic when enlarging."""
    from PIL import Image

    if image.shape[1] == width and image.shape[0] == height:
        return image
    shrink = width <= image.shape[1] and height <= image.shape[0]
    method = Image.Resampling.BOX if shrink else Image.Resampling.BICUBIC
    return np.asarray(Image.fromarray(image).resize((width, height), method))


def resample_views(views: Views, new_width: int, new_height: int) -> Views:
    """The same cameras at another image size (images resized, K scaled)."""
    if (new_width, new_height) == (views.width, views.height):
        return views
    if views.images is not None and len(views.images) * new_width * new_height > MAX_PIXELS:
        raise fail(
            f"{new_width}x{new_height}",
            f"resampling {len(views.images)} images to this size needs more than {MAX_PIXELS:.2g} pixels",
            "Choose a smaller --size",
        )
    images = None
    if views.images is not None:
        images = (
            np.stack([resize_image(im, new_width, new_height) for im in views.images])
            if len(views.images)
            else np.zeros((0, new_height, new_width, 3), np.uint8)
        )
    K = scale_intrinsics(views.K, views.width, views.height, new_width, new_height)
    return replace(views, K=K, width=new_width, height=new_height, images=images)


def resample_scene(scene: Scene, size: int | None = None, downscale: float | None = None) -> Scene:
    """Every split resampled (see :func:`output_size`); poses, near/far unchanged."""
    if output_size(scene.train.width, scene.train.height, size, downscale) == (scene.train.width, scene.train.height):
        return scene
    new = {
        name: resample_views(v, *output_size(v.width, v.height, size, downscale)) for name, v in scene.splits.items()
    }
    return replace(scene, train=new["train"], val=new["val"], test=new["test"])
