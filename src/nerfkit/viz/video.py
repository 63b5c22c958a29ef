"""Videos (MP4 via imageio-ffmpeg, GIF via Pillow) and depth colour maps."""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np

from ..images import to_uint8
from ..io.atomic import atomic_path


def colorize_depth(depth: np.ndarray, acc: np.ndarray, near: float, far: float, cmap: str = "turbo",
                   unmet_is_far: bool = False) -> np.ndarray:
    """Colour-map depth (H, W) into (H, W, 3) float; near is warm, far is cool.

    The range is clipped to [near, far], a scale the caller keeps from frame to frame. The
    share ``1 - acc`` of a pixel that met nothing is black (empty), or with
    ``unmet_is_far`` the far colour (a scene closed by its surroundings: what the rays do
    not meet is infinitely far).
    """
    import matplotlib

    colours = matplotlib.colormaps[cmap]
    norm = np.clip((depth - near) / max(far - near, 1e-8), 0.0, 1.0)
    met = np.clip(acc, 0.0, 1.0)[..., None]
    out = colours(1.0 - norm)[..., :3] * met
    if unmet_is_far:
        out = out + (1.0 - met) * np.asarray(colours(0.0)[:3])
    return out.astype(np.float32)


def write_video(path: str | Path, frames: Iterable[np.ndarray], fps: int = 30) -> None:
    """Write frames (uint8 (H, W, 3)) to MP4 (H.264) or GIF, chosen by the extension, atomically."""
    import imageio.v3 as iio

    path = Path(path)
    frames = [f if f.dtype == np.uint8 else to_uint8(f) for f in frames]
    if not frames:
        raise ValueError("no frames to write")
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".gif":
            iio.imwrite(tmp, np.stack(frames), extension=".gif", duration=1000.0 / fps, loop=0)
        else:
            # H.264 wants even sizes; pad by one pixel when needed.
            h, w = frames[0].shape[:2]
            ph, pw = h % 2, w % 2
            if ph or pw:
                frames = [np.pad(f, ((0, ph), (0, pw), (0, 0)), mode="edge") for f in frames]
            iio.imwrite(tmp, np.stack(frames), extension=".mp4", plugin="FFMPEG", fps=fps,
                        codec="libx264", quality=8, macro_block_size=1, ffmpeg_log_level="error")
