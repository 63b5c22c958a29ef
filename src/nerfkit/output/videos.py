"""Orbit and depth videos of a trained model."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..data.scene import Views
from ..images import to_uint8
from ..models.base import NerfModel
from ..viz.video import depth_scale, write_video
from .images import render_views

VIDEO_FILES = ("orbit.mp4", "orbit.gif", "depth.mp4")
# the object alone (`nerfkit render --object`)
OBJECT_VIDEO_FILES = ("object.mp4", "object.gif", "object_depth.mp4")


@dataclass
class VideoPaths:
    rgb_mp4: Path
    rgb_gif: Path
    depth_mp4: Path
    seconds_per_frame: float


def render_videos(
    model: NerfModel,
    views: Views,
    out_dir: Path,
    background: torch.Tensor,
    near: float | np.ndarray,
    far: float | np.ndarray,
    fps: int = 30,
    chunk: int = 16384,
    autocast_dtype: torch.dtype | None = None,
    progress: bool = True,
    names: tuple[str, str, str] = VIDEO_FILES,
    metres: bool = False,
) -> VideoPaths:
    """Render ``views`` into ``out_dir/orbit.mp4``, ``orbit.gif`` and ``depth.mp4`` (or
    the three ``names``).

    Frames are kept as uint8 (a 60-frame 800x800 orbit is ~115 MB). Depth is coloured from
    ``near`` (warm) to ``far`` (cool), one scale for all frames or one per frame ((n,)
    each: an object's relief, :func:`~nerfkit.output.images.frame_object`), and shows
    everything the rays meet (a capture's table too, not only the object; its room lies
    beyond ``far`` and takes the far colour). Each depth frame has its scale under it
    (:func:`~nerfkit.viz.video.depth_scale`; ``metres``: the world is metric, a tag capture's).
    """
    import time

    from tqdm import tqdm

    rgb_frames, depth_frames = [], []
    nears, fars = (np.broadcast_to(np.asarray(v, np.float64), (len(views),)) for v in (near, far))
    t0 = time.perf_counter()
    for i, view in enumerate(
        tqdm(
            render_views(model, views, background, chunk, autocast_dtype),
            total=len(views),
            desc="render",
            unit="frame",
            disable=None if progress else True,
        )
    ):
        rgb_frames.append(to_uint8(view.rgb))
        depth = to_uint8(view.depth_colours(float(nears[i]), float(fars[i])))
        depth_frames.append(np.concatenate([depth, depth_scale(depth.shape[1], nears[i], fars[i], metres)]))
    per_frame = (time.perf_counter() - t0) / max(len(views), 1)
    out_dir = Path(out_dir)
    rgb_mp4, rgb_gif, depth_mp4 = (out_dir / name for name in names)
    paths = VideoPaths(rgb_mp4, rgb_gif, depth_mp4, per_frame)
    write_video(paths.rgb_mp4, rgb_frames, fps)
    write_video(paths.rgb_gif, rgb_frames[:: max(1, len(rgb_frames) // 60)], min(fps, 20))
    write_video(paths.depth_mp4, depth_frames, fps)
    return paths
