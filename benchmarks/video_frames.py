"""Frame selection from a video: time and peak memory on a synthetic 4K clip.

Generates (once) a 3840x2160 30-fps H.264 clip of a textured plane passing under a moving
camera, with a few blurred frames and a pause, then runs ``select_frames`` on it in a fresh
process and prints a table: size, frames read, kept, seconds, peak memory of the Python
process and of the ffmpeg decoder it runs (maximum resident set sizes). CPU seconds (the
Python process and ffmpeg together) tell the cost on a machine shared with other work.

    python benchmarks/video_frames.py --dir runs/video_bench [--seconds 20] [--frames 100]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def write_clip(path: Path, width: int, height: int, seconds: float, fps: int = 30, seed: int = 0) -> None:
    """A clip of ``seconds`` at ``fps``: a crop of a large smooth-noise texture with discs,
    sliding and bobbing; frames 10-12 and 100-102 blurred, the camera paused for one second
    at a third of the clip. Encoded with x264 ultrafast (yuv420p)."""
    import cv2
    import imageio_ffmpeg

    rng = np.random.default_rng(seed)
    th, tw = int(height * 1.5), width * 2
    tex = cv2.resize(rng.random((th // 16, tw // 16, 3), dtype=np.float32), (tw, th), interpolation=cv2.INTER_CUBIC)
    tex = (np.clip(tex, 0, 1) * 255).astype(np.uint8)
    for _ in range(2000):
        c = tuple(int(x) for x in rng.integers(0, 255, 3))
        cv2.circle(tex, (int(rng.integers(0, tw)), int(rng.integers(0, th))), int(rng.integers(5, 60)), c, -1)
    n = int(seconds * fps)
    pause = set(range(n // 3, n // 3 + fps))
    blur = {10, 11, 12, 100, 101, 102}
    writer = imageio_ffmpeg.write_frames(
        str(path),
        (width, height),
        fps=fps,
        codec="libx264",
        pix_fmt_out="yuv420p",
        macro_block_size=8,
        output_params=["-preset", "ultrafast", "-crf", "20"],
        ffmpeg_log_level="error",
    )
    writer.send(None)
    k = 0
    for i in range(n):
        k += i not in pause
        x = int(k / n * (tw - width - 1))
        y = int((th - height) / 2 * (1 + 0.9 * np.sin(2 * np.pi * k / n)))
        frame = tex[y : y + height, x : x + width]
        if i in blur:
            frame = cv2.GaussianBlur(frame, (0, 0), 8)
        writer.send(np.ascontiguousarray(frame))
    writer.close()


RUN = """
import json, resource, sys, time
from nerfkit.capture.video import select_frames
t = time.perf_counter()
s = select_frames(sys.argv[1], sys.argv[2], int(sys.argv[3]), force=True, progress=False)
secs = time.perf_counter() - t
own, child = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"read": s.read, "kept": s.kept, "dropped": s.dropped, "seconds": secs,
                  "cpu": own.ru_utime + own.ru_stime + child.ru_utime + child.ru_stime,
                  "python_mb": own.ru_maxrss / 1024, "ffmpeg_mb": child.ru_maxrss / 1024,
                  "size": [s.info.width, s.info.height]}))
"""


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dir", default="runs/video_bench", help="where the clip and the frames go")
    p.add_argument("--width", type=int, default=3840)
    p.add_argument("--height", type=int, default=2160)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--frames", type=int, default=100, help="frames to select")
    args = p.parse_args()
    out = Path(args.dir)
    out.mkdir(parents=True, exist_ok=True)
    clip = out / f"clip_{args.width}x{args.height}_{args.seconds:g}s.mp4"
    if not clip.exists():
        t = time.perf_counter()
        tmp = clip.with_name(".tmp_" + clip.name)
        write_clip(tmp, args.width, args.height, args.seconds)
        tmp.rename(clip)
        print(f"wrote {clip} ({clip.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t:.0f} s", file=sys.stderr)
    r = subprocess.run(
        [sys.executable, "-c", RUN, str(clip), str(out / "frames"), str(args.frames)],
        capture_output=True,
        text=True,
        check=True,
    )
    m = json.loads(r.stdout.strip().splitlines()[-1])
    print("| clip | frames read | kept | dropped | seconds | CPU seconds | peak MB (python) | peak MB (ffmpeg) |")
    print("|---|---|---|---|---|---|---|---|")
    dropped = ", ".join(f"{v} {k}" for k, v in m["dropped"].items())
    print(
        f"| {m['size'][0]}x{m['size'][1]} {args.seconds:g} s | {m['read']} | {m['kept']} | {dropped} | "
        f"{m['seconds']:.1f} | {m['cpu']:.1f} | {m['python_mb']:.0f} | {m['ffmpeg_mb']:.0f} |"
    )


if __name__ == "__main__":
    main()
