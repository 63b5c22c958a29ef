"""Videos (MP4 via imageio-ffmpeg, GIF via Pillow) and depth colour maps."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..images import to_uint8
from ..io.atomic import atomic_path


def colorize_depth(
    depth: np.ndarray, acc: np.ndarray, near: float, far: float, cmap: str = "turbo", unmet_is_far: bool = False
) -> np.ndarray:
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


def depth_label(value: float, metres: bool) -> str:
    """A depth for a legend: centimetres or metres when the scene is metric, else the
    scene's units (3 significant figures)."""
    if not metres:
        return f"{value:.3g}"
    if abs(value) < 1.0:
        return f"{100 * value:.0f} cm" if abs(value) >= 0.1 else f"{100 * value:.1f} cm"
    return f"{value:.2f} m"


def depth_scale(width: int, near: float, far: float, metres: bool, cmap: str = "turbo") -> np.ndarray:
    """(h, width, 3) uint8 legend to put under a depth frame of :func:`colorize_depth`: the
    colour bar from ``near`` (left, warm) to ``far`` (right, cool) over the strip's upper
    half, the two depths written below its ends (``metres``: a tag capture's metric world;
    else scene units, marked as such)."""
    import cv2
    import matplotlib

    h = max(24, round(width / 16))
    bar = max(6, h // 2 - 2)
    strip = np.zeros((h, width, 3), np.uint8)
    ramp = matplotlib.colormaps[cmap](1.0 - np.linspace(0.0, 1.0, width))[:, :3]
    strip[1 : 1 + bar] = to_uint8(ramp)[None]
    scale = max(0.3, (h - bar - 4) / 30)
    thick = 1 if scale < 0.8 else 2
    near_s, far_s = depth_label(near, metres), depth_label(far, metres)
    # the longest labels that fit side by side (a narrow frame drops the words, then the unit)
    choices = [
        (f"near {near_s}", f"far {far_s}" + ("" if metres else " (scene units)")),
        (f"near {near_s}", f"far {far_s}"),
    ]

    def fits(left: str, right: str) -> bool:
        return sum(cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)[0][0] for t in (left, right)) + 8 <= width

    for left, right in [*choices, (near_s, far_s)]:
        if fits(left, right):
            break
    while not fits(left, right) and scale > 0.2:  # the numbers alone, smaller
        scale *= 0.85
    (rw, th), _ = cv2.getTextSize(right, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    y = min(h - 2, bar + 3 + th)
    for text, x in ((left, 2), (right, max(2, width - rw - 2))):
        cv2.putText(strip, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thick, cv2.LINE_AA)
    return strip


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
            iio.imwrite(
                tmp,
                np.stack(frames),
                extension=".mp4",
                plugin="FFMPEG",
                fps=fps,
                codec="libx264",
                quality=8,
                macro_block_size=1,
                ffmpeg_log_level="error",
            )
