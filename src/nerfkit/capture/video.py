"""Video in: probe a phone clip and choose the frames a careful user would keep.

Two streaming passes of the ffmpeg binary that imageio-ffmpeg ships (it decodes H.264,
HEVC and the usual containers, and turns frames upright by the clip's rotation metadata):

1. every frame, downscaled to a grey image of at most ``score_side`` pixels, is scored
   (sharpness: variance of the Laplacian; brightness; a small thumbnail to measure
   motion) and its timestamp kept: a few kilobytes a frame;
2. :func:`choose_frames` splits the clip into ``target`` windows evenly spread in time
   (or in camera travel), keeps the sharpest usable frame of each window that moved from
   the frame kept before it, and a second decode writes only those frames, at full
   resolution, as JPEG.

nerfkit holds at most one full-resolution frame; ffmpeg's decoder a few more (about
400 MB in all for 4K, whatever the clip's length: benchmarks/video_frames.py).
"""

from __future__ import annotations

import contextlib
import functools
import os
import re
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..errors import fail
from ..images import VIDEO_SUFFIXES
from ..io.paths import file_sha1

MIN_FRAMES = 10  # fewer usable frames than this cannot be posed
SCORE_SIDE = 720  # longest side (pixels) of the grey frames scored in the first pass
THUMB_SIDE = 64  # longest side of the thumbnails compared for motion
BLUR_RATIO = 0.35  # a frame below this fraction of the clip's median sharpness is blurred
BLUR_FLOOR = 8.0  # ... and any frame below this variance of the Laplacian (grey levels^2, at the scoring size)
# a clip whose lit frames' median sharpness is under this is flat, not shaken: one colour, a
# screen recording of a blank page (a clip blurred with an 8-pixel Gaussian scores about 5)
PLAIN_SHARPNESS = 1.0
DARK_LEVEL = 12.0  # mean grey level (of 255) below which a frame is too dark
DUPLICATE_MOTION = 0.2  # thumbnail pixels of apparent motion below which a frame repeats the last kept
JPEG_QUALITY = 95
SPREADS = ("time", "motion")  # what the windows are evenly spread in
FRAME_NAME = "frame_{:05d}.jpg"
REPORT_NAME = "frames.json"
_FRAME_FILE = re.compile(r"frame_\d{5}\.jpg")

# why a frame read was not kept (the keys of FrameSelection.dropped)
DARK, BLURRED, DUPLICATE, WINDOW = "too dark", "blurred", "near-duplicate", "sharper frame kept in its window"
REASONS = (DARK, BLURRED, DUPLICATE, WINDOW)
ADVICE = {
    DARK: "film with more light",
    BLURRED: "film slower, with more light, holding the phone steadier",
    DUPLICATE: "keep moving around the object rather than pausing",
}


@dataclass
class VideoInfo:
    """What the clip's header says. ``width``/``height`` are those of the upright frames
    (after the rotation metadata is applied, as the frames are decoded)."""

    path: str
    width: int
    height: int
    fps: float  # average frame rate the header gives (0 when unknown)
    duration: float  # seconds (0 when unknown): the file's, its longest stream's (the sound's, say)
    frames: int  # frame count: counted when ``exact``, else duration * fps
    exact: bool
    rotation: int  # clockwise degrees a player turns the coded frames: 0, 90, 180 or 270
    codec: str  # e.g. h264, hevc

    @property
    def portrait(self) -> bool:
        return self.height > self.width


@dataclass
class FrameSelection:
    """The frames :func:`select_frames` kept, and why the others were dropped."""

    source: str
    out_dir: str
    info: VideoInfo
    target: int  # windows the clip was split into
    read: int  # frames decoded
    files: list[str]  # kept frames' file names in out_dir, in clip order
    frame_indices: list[int]  # their frame numbers in the clip (from 0)
    timestamps: list[float]  # their times in the clip (seconds)
    sharpness: list[float]  # their variance of the Laplacian at the scoring size
    dropped: dict[str, int]  # reason -> frames (read = kept + sum of dropped)
    median_sharpness: float
    blur_threshold: float  # frames below it counted as blurred
    empty_windows: int  # windows with no frame kept
    seconds: float = 0.0
    score_size: tuple[int, int] = (0, 0)  # (width, height) of the scored grey frames
    spread: str = "time"  # the windows are evenly spread in time or in camera travel ("motion")
    advice: list[str] = field(default_factory=list)
    source_stamp: str = ""  # the clip's size and a digest of its bytes: clip_stamp

    @property
    def kept(self) -> int:
        return len(self.files)

    @property
    def paths(self) -> list[Path]:
        return [Path(self.out_dir) / f for f in self.files]

    def to_json(self) -> dict:
        d = asdict(self)
        d["kept"] = self.kept
        d["frames"] = [
            {"file": f, "frame": i, "time": round(t, 4), "sharpness": round(s, 2)}
            for f, i, t, s in zip(self.files, self.frame_indices, self.timestamps, self.sharpness)
        ]
        for k in ("files", "frame_indices", "timestamps", "sharpness"):
            del d[k]
        return d


def clip_stamp(path: str | os.PathLike) -> str:
    """The clip ``path``'s size and a digest of its bytes: a clip replaced or edited since its
    frames were chosen (a rotation fixed in its header keeps its size) has another; one
    copied again, or touched, keeps it. Reads the whole file (about a second a gigabyte) once
    per process while its size, time and inode stay the same."""
    st = Path(path).resolve().stat()
    return _clip_stamp(str(Path(path).resolve()), st.st_size, st.st_mtime_ns, st.st_ino)


@functools.lru_cache(maxsize=8)
def _clip_stamp(path: str, size: int, mtime_ns: int, inode: int) -> str:
    return f"{size} bytes, sha1 {file_sha1(path)[:16]}"


def ffmpeg_input(path: str | os.PathLike) -> str:
    """``path`` as ffmpeg's ``-i`` reads it as a file: a name with a colon (``take:2.mp4``)
    is otherwise taken for a protocol."""
    return "file:" + str(Path(path).resolve())


def is_video(path: str | os.PathLike) -> bool:
    """True when ``path`` names a file with a video suffix (case-insensitive)."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def ffmpeg_exe() -> str:
    import imageio_ffmpeg  # type: ignore[import-untyped]

    return imageio_ffmpeg.get_ffmpeg_exe()


# ---------------------------------------------------------------------------------------------
# probing

_STILL_FORMATS = ("image2", "png_pipe", "jpeg_pipe", "webp_pipe", "bmp_pipe", "tiff_pipe")


def parse_header(text: str, path: str = "") -> VideoInfo:
    """A :class:`VideoInfo` from ffmpeg's description of an input (its stderr for ``-i path``).
    Raises a NerfkitError when it shows no video stream."""
    streams = [ln for ln in text.splitlines() if re.match(r"\s*Stream #\d+:\d+.*: Video: ", ln)]
    streams = [ln for ln in streams if "(attached pic)" not in ln]  # an audio file's cover picture
    fmt = re.search(r"Input #0, ([^ ]+), from", text)
    if not streams:
        raise fail(path, "holds no video stream ffmpeg can read", "Pass a video file (MP4, MOV, M4V)")
    if fmt and any(f in fmt.group(1).split(",") for f in _STILL_FORMATS):
        raise fail(path, "is a still image, not a video", "Pass a video, or a folder of photos to nerfkit capture")
    line = streams[0]
    codec_match = re.search(r"Video: ([\w-]+)", line)
    codec = codec_match.group(1) if codec_match else "unknown"
    size = re.search(r", (\d{2,5})x(\d{2,5})", line)
    if size is None:
        raise fail(path, "has a video stream of unknown size", "Re-encode it (e.g. export it again from the phone)")
    w, h = int(size.group(1)), int(size.group(2))
    fps = re.search(r"([\d.]+) fps", line) or re.search(r"([\d.]+)k? tbr", line)
    fps_v = float(fps.group(1)) if fps else 0.0
    dur = re.search(r"Duration: (\d+):(\d+):([\d.]+)", text)
    duration = int(dur.group(1)) * 3600 + int(dur.group(2)) * 60 + float(dur.group(3)) if dur else 0.0
    # the stream's block (its lines up to the next stream) holds its side data
    block = text.split(line, 1)[1].split("Stream #", 1)[0]
    rot = re.search(r"display ?matrix: rotation of (-?[\d.]+) degrees", block, re.IGNORECASE) or re.search(
        r"rotate\s*:\s*(-?\d+)", block
    )
    anticlockwise = float(rot.group(1)) if rot else 0.0
    if rot and "rotate" in rot.group(0):  # the old tag counts clockwise
        anticlockwise = -anticlockwise
    rotation = round(-anticlockwise / 90.0) % 4 * 90
    if rotation in (90, 270):
        w, h = h, w
    return VideoInfo(str(path), w, h, fps_v, duration, round(duration * fps_v), False, rotation, codec)


def _check_readable(path: Path) -> None:
    from ..io.paths import path_kind, refuse_special_file

    kind = path_kind(path)
    if kind is None:
        raise fail(path, "no such file", "Check the path to the video")
    if kind == "dir":
        raise fail(path, "is a folder, not a video", "Pass a video file (MP4, MOV, M4V)")
    refuse_special_file(path, kind)
    if path.stat().st_size == 0:
        raise fail(path, "is empty", "Copy the video again from the phone")


def probe_video(path: str | os.PathLike, count: bool = False) -> VideoInfo:
    """The clip's size (upright), frame rate, duration, rotation and codec from its header;
    with ``count``, the frames are counted by demuxing the whole file (no decoding: about a
    second for a minute of 4K). A file that is not a readable video is a NerfkitError."""
    path = Path(path)
    _check_readable(path)
    if path.suffix.lower() == ".gif":  # ffmpeg decodes some GIFs' first frame only: a clip read short
        raise fail(path, "is a GIF, not a video", "Pass the video the phone recorded (MP4, MOV), or convert it to MP4")
    r = subprocess.run(
        [ffmpeg_exe(), "-hide_banner", "-nostdin", "-i", ffmpeg_input(path)], capture_output=True, check=False
    )
    text = r.stderr.decode("utf-8", "replace")
    if "Input #0" not in text:
        why = text.strip().splitlines()[-1] if text.strip() else "ffmpeg could not open it"
        raise fail(
            path,
            f"is not a video ffmpeg can read ({why.split(': ')[-1]})",
            "Pass a video file (MP4, MOV, M4V), copied whole from the phone",
        )
    info = parse_header(text, str(path))
    if count:
        frames = re.findall(r"frame=\s*(\d+)", _demux(path, "0:v:0"))
        if frames:
            info.frames, info.exact = int(frames[-1]), True
    return info


def _demux(path: str | os.PathLike, streams: str) -> str:
    """ffmpeg's log of demuxing ``streams`` (``-map``: "0:v:0", the first video stream; "0",
    all) of the clip to nowhere, without decoding: its frame count and where the data ends."""
    cmd = [ffmpeg_exe(), "-hide_banner", "-nostdin", "-i", ffmpeg_input(path), "-map", streams]
    r = subprocess.run([*cmd, "-c", "copy", "-f", "null", "-"], capture_output=True, check=False)
    return r.stderr.decode("utf-8", "replace")


def data_end(path: str | os.PathLike) -> float | None:
    """Seconds into the clip at which the data of all its streams ends, by demuxing it (no
    decoding); None when ffmpeg does not say. A file cut short ends before its header's
    duration; a clip whose sound runs on after the picture does not."""
    ends = re.findall(r"time=\s*(\d+):(\d+):([\d.]+)", _demux(path, "0"))
    return int(ends[-1][0]) * 3600 + int(ends[-1][1]) * 60 + float(ends[-1][2]) if ends else None


# ---------------------------------------------------------------------------------------------
# decoding


def score_size(width: int, height: int, side: int = SCORE_SIDE) -> tuple[int, int]:
    """(w, h) of a frame scaled so its longest side is at most ``side`` (never up), even."""
    s = min(1.0, side / max(width, height))
    return max(2, round(width * s / 2) * 2), max(2, round(height * s / 2) * 2)


def _ffmpeg_frames(path: Path, size: tuple[int, int], pix_fmt: str, filters: list[str], log):
    """Decode ``path``'s first video stream (upright, every frame as coded: no frame-rate
    conversion) through ``filters``; yield each frame as an (h, w[, 3]) uint8 array of
    ``size`` = (w, h). ffmpeg's log goes to the file ``log``."""
    w, h = size
    channels = 3 if pix_fmt == "rgb24" else 1
    nbytes = w * h * channels
    cmd = [
        ffmpeg_exe(),
        "-hide_banner",
        "-nostdin",
        "-nostats",
        # a clip whose frames change size or colour range mid-stream (two takes joined) keeps one
        # filter graph: rebuilt, it would count its frames (showinfo's and select's n) from 0 again
        "-reinit_filter",
        "0",
        "-i",
        ffmpeg_input(path),
        "-map",
        "0:v:0",
        "-an",
        "-sn",
        "-dn",
        "-fps_mode",
        "passthrough",
    ]
    if filters:
        cmd += ["-vf", ",".join(filters)]
    # one frame queued for the pipe (ffmpeg's default of 8 holds 200 MB of 4K RGB while nerfkit writes a JPEG)
    cmd += ["-thread_queue_size", "1", "-f", "rawvideo", "-pix_fmt", pix_fmt, "-"]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log, bufsize=nbytes)
    stdout = proc.stdout
    assert stdout is not None
    try:
        while True:
            buf = stdout.read(nbytes)
            if len(buf) < nbytes:
                if buf:
                    raise fail(path, "ended in the middle of a frame", "Copy the video again from the phone")
                break
            a = np.frombuffer(buf, np.uint8)
            yield a.reshape(h, w, 3) if channels == 3 else a.reshape(h, w)
    finally:
        if proc.poll() is None:
            proc.kill()
        stdout.close()
        proc.wait()


_SHOWINFO = re.compile(r"\bn:\s*(\d+)\s+pts:\s*(\S+)\s+pts_time:(\S+)")


def _log_text(log) -> str:
    log.flush()
    log.seek(0)
    return log.read().decode("utf-8", "replace")


def frame_scores(grey: np.ndarray, thumb_side: int = THUMB_SIDE) -> tuple[float, float, np.ndarray]:
    """(sharpness, brightness, thumbnail) of an (h, w) uint8 grey frame: the variance of its
    Laplacian, its mean level (0-255) and an area-averaged uint8 copy of at most
    ``thumb_side`` pixels on its longest side (2.3 kB: an hour at 60 fps takes 500 MB)."""
    import cv2

    sharp = float(cv2.Laplacian(grey, cv2.CV_32F).var())
    h, w = grey.shape
    s = thumb_side / max(h, w)
    # at least 2 pixels a side: motion() takes a gradient (a 2000x16 clip's would be 64x1)
    thumb = cv2.resize(grey, (max(2, round(w * s)), max(2, round(h * s))), interpolation=cv2.INTER_AREA)
    return sharp, float(grey.mean()), thumb


def motion(a: np.ndarray, b: np.ndarray) -> float:
    """Apparent motion between two thumbnails, in thumbnail pixels: their mean absolute
    difference over their mean gradient magnitude (a shift of d pixels of a smooth image
    changes it by about d times its gradient). 0 for identical thumbnails."""
    a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
    diff = float(np.abs(a - b).mean())
    if diff == 0.0:
        return 0.0
    gy, gx = np.gradient((a + b) / 2)
    # for a texture without a preferred direction, a shift of d changes a pixel by
    # |gradient . d| = d (|gx| + |gy|) / 2 on average
    grad = float(np.abs(gx).mean() + np.abs(gy).mean()) / 2
    return diff / max(grad, 1e-3)


@dataclass
class ClipScores:
    """Per-frame scores of a whole clip (n frames): times (n,) in seconds, sharpness (n,),
    brightness (n,), thumbs (n, th, tw) uint8 (or float)."""

    times: np.ndarray
    sharpness: np.ndarray
    brightness: np.ndarray
    thumbs: np.ndarray


def score_clip(path: Path, info: VideoInfo, side: int = SCORE_SIDE, progress: bool = True) -> ClipScores:
    """First pass: every frame of the clip scored at ``score_size``."""
    from tqdm import tqdm

    size = score_size(info.width, info.height, side)
    sharp, bright, thumbs = [], [], []
    filters = ["showinfo=checksum=0", f"scale={size[0]}:{size[1]}:flags=area"]
    with (
        tempfile.TemporaryFile() as log,
        tqdm(total=info.frames or None, desc="reading frames", unit="frame", disable=None if progress else True) as bar,
    ):
        for grey in _ffmpeg_frames(path, size, "gray", filters, log):
            s, b, t = frame_scores(grey)
            sharp.append(s)
            bright.append(b)
            thumbs.append(t)
            bar.update()
        text = _log_text(log)
    if not sharp:
        if re.search(r"Unrecognized option|Option not found|No such filter", text):
            raise fail(
                ffmpeg_exe(),
                "this ffmpeg is too old to read video for nerfkit (it lacks -fps_mode or "
                "-thread_queue_size for outputs)",
                "Use ffmpeg 6 or newer: unset IMAGEIO_FFMPEG_EXE to use the one imageio-ffmpeg ships",
            )
        last = [ln for ln in text.strip().splitlines() if ln.strip()][-1:] or ["no frames decoded"]
        raise fail(
            path,
            f"no frame could be decoded ({last[0].strip()[:200]})",
            "The file may be damaged or cut short: copy the video again from the phone",
        )
    n = len(sharp)
    times = np.arange(n, dtype=np.float64) / (info.fps or 30.0)  # when the log gives no time
    base = re.search(r"config in time_base: (\d+)/(\d+)", text)
    tick = int(base.group(1)) / int(base.group(2)) if base and int(base.group(2)) else None
    for m in _SHOWINFO.finditer(text):
        i = int(m.group(1))
        if i < n:
            # pts in time_base ticks is exact; pts_time is rounded to 6 digits (NOPTS: ValueError, kept as is)
            with contextlib.suppress(ValueError):
                times[i] = int(m.group(2)) * tick if tick else float(m.group(3))
    return ClipScores(times, np.asarray(sharp), np.asarray(bright), np.stack(thumbs))


# ---------------------------------------------------------------------------------------------
# choosing


def windows_of(times: np.ndarray, target: int) -> np.ndarray:
    """(n,) window index (0..target-1) of each frame time (n,), for ``target`` windows of
    equal duration from the first frame's time to the end of the last frame (its time plus
    the median frame interval)."""
    t0, t1 = float(times.min()), float(times.max())
    step = float(np.median(np.diff(np.sort(times)))) if len(times) > 1 else 1.0
    span = max(t1 - t0 + step, 1e-9)
    # (a frame on a boundary, up to rounding, opens the next window)
    return np.minimum(np.floor((times - t0) / span * target + 1e-6).astype(np.int64), target - 1)


def travel(thumbs: np.ndarray) -> np.ndarray:
    """(n,) apparent camera travel from the first frame to each frame: the running sum of
    the :func:`motion` between consecutive thumbnails (n, th, tw), in thumbnail pixels."""
    steps = [motion(thumbs[i], thumbs[i + 1]) for i in range(len(thumbs) - 1)]
    return np.concatenate([[0.0], np.cumsum(steps)])


def spread_axis(scores: ClipScores, spread: str) -> np.ndarray:
    """(n,) where each frame lies along the clip for spreading the windows: its time
    (``"time"``) or the camera's travel to it (``"motion"``: a pause takes no window)."""
    if spread not in SPREADS:
        raise fail("spread", f"'{spread}' is not one of {', '.join(SPREADS)}")
    return scores.times if spread == "time" else travel(scores.thumbs)


def choose_frames(
    scores: ClipScores,
    target: int,
    blur_ratio: float = BLUR_RATIO,
    blur_floor: float = BLUR_FLOOR,
    dark_level: float = DARK_LEVEL,
    duplicate_motion: float = DUPLICATE_MOTION,
    spread: str = "time",
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The frames to keep: per window (``target`` windows evenly spread in time or in
    camera travel, see :func:`spread_axis`), the sharpest usable frame that moved at least
    ``duplicate_motion`` thumbnail pixels from the frame kept before it.

    Returns (kept (k,) frame indices in clip order, reason (n,) str array: '' for a kept
    frame else one of REASONS, median sharpness of the bright frames, blur threshold).
    """
    n = len(scores.sharpness)
    reason = np.full(n, WINDOW, dtype=object)
    dark = scores.brightness < dark_level
    lit = scores.sharpness[~dark]
    median = float(np.median(lit)) if lit.size else 0.0
    threshold = max(blur_ratio * median, blur_floor)
    blurred = ~dark & (scores.sharpness < threshold)
    reason[dark] = DARK
    reason[blurred] = BLURRED
    usable = ~dark & ~blurred
    window = windows_of(spread_axis(scores, spread), target)
    kept: list[int] = []
    last = None
    for w in range(target):
        members = np.flatnonzero((window == w) & usable)
        if members.size == 0:
            continue
        for i in members[np.argsort(-scores.sharpness[members], kind="stable")]:
            if last is None or motion(scores.thumbs[i], scores.thumbs[last]) >= duplicate_motion:
                kept.append(int(i))
                last = int(i)
                break
        else:  # every usable frame of the window repeats the last kept one
            reason[members] = DUPLICATE
    reason[kept] = ""
    return np.asarray(kept, dtype=np.int64), reason, median, threshold


# ---------------------------------------------------------------------------------------------
# writing


def _check_out_dir(out_dir: Path, source: Path, force: bool) -> list[Path]:
    """Refuse an out_dir that is the clip, holds it, or holds files other than earlier frames
    (and those without ``force``). Returns the earlier frames' files (to be replaced)."""
    from ..io.atomic import is_temporary
    from ..io.paths import guard_outputs, path_kind

    guard_outputs([out_dir], [source], force=True)
    kind = path_kind(out_dir)
    if kind is None:
        return []
    if kind != "dir":
        raise fail(out_dir, "is a file, not a folder", "Choose a folder for the frames")
    ours: list[Path] = []
    other: list[Path] = []
    for p in out_dir.iterdir():
        (
            ours
            if (_FRAME_FILE.fullmatch(p.name) or p.name == REPORT_NAME or is_temporary(p.name)) and p.is_file()
            else other
        ).append(p)
    if other:
        raise fail(
            out_dir,
            f"holds other files than frames (e.g. {min(other).name})",
            "Choose a new or empty folder for the frames",
        )
    if ours and not force:
        raise fail(out_dir, "already holds frames", "Pass --force to replace them, or choose another folder")
    return ours


def _write_jpeg(path: Path, rgb: np.ndarray, quality: int = JPEG_QUALITY) -> None:
    import cv2

    from ..io.atomic import atomic_path

    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality]):
            raise OSError(f"could not write {path}")


def select_expression(indices: list[int]) -> str:
    """An ffmpeg ``select`` expression true for frame numbers ``indices``: a balanced sum of
    ``eq(n,i)`` terms (ffmpeg refuses a flat sum of more than 100 terms)."""
    if len(indices) <= 8:
        return "+".join(f"eq(n,{i})" for i in indices)
    half = len(indices) // 2
    return f"({select_expression(indices[:half])})+({select_expression(indices[half:])})"


def extract_frames(
    path: Path, info: VideoInfo, indices: list[int], out_dir: Path, names: list[str], progress: bool = True
) -> None:
    """Second pass: write frames ``indices`` (clip order) of the clip at full resolution as
    JPEG files ``names`` in ``out_dir``."""
    from tqdm import tqdm

    if not indices:
        return
    expr = select_expression(indices)
    out_dir.mkdir(parents=True, exist_ok=True)
    done = 0
    with (
        tempfile.TemporaryFile() as log,
        tqdm(total=len(indices), desc="writing frames", unit="frame", disable=None if progress else True) as bar,
    ):
        for rgb in _ffmpeg_frames(path, (info.width, info.height), "rgb24", [f"select='{expr}'"], log):
            _write_jpeg(out_dir / names[done], rgb)
            done += 1
            bar.update()
            if done == len(indices):
                break
        if done < len(indices):
            raise fail(
                path,
                f"gave {done} of the {len(indices)} chosen frames on the second read ({_log_text(log).strip()[-200:]})",
                "The file may be damaged: copy it again from the phone",
            )


def cut_short(info: VideoInfo, times: np.ndarray, data_end: float | None = None) -> list[str]:
    """Advice (a list of one line, or none) when the frames decoded at ``times`` (seconds) end
    before 90% of the duration the header gives: a file cut short decodes its start only.
    ``data_end``: where the data of all its streams ends (:func:`data_end`); when that
    reaches the header's duration the file is whole, its sound running on after the picture."""
    if info.duration <= 0 or not len(times):
        return []
    reached = float(times.max()) + (1.0 / info.fps if info.fps > 0 else 0.0)
    if reached >= 0.9 * info.duration or (data_end is not None and data_end >= 0.9 * info.duration):
        return []
    return [
        f"the clip could be read to {reached:.1f} s of the {info.duration:.1f} s its header gives: the file looks "
        "cut short (a copy or download that did not finish?), and the frames come from its start only"
    ]


def select_frames(
    path: str | os.PathLike,
    out_dir: str | os.PathLike,
    target: int,
    *,
    force: bool = False,
    progress: bool = True,
    score_side: int = SCORE_SIDE,
    blur_ratio: float = BLUR_RATIO,
    duplicate_motion: float = DUPLICATE_MOTION,
    min_frames: int = MIN_FRAMES,
    spread: str = "time",
) -> FrameSelection:
    """Choose about ``target`` frames of the clip at ``path`` (see the module's docstring) and
    write them to ``out_dir`` as frame_00001.jpg... (JPEG quality 95, full resolution,
    upright) with ``frames.json``, the report. ``out_dir`` is the frames' own folder: it
    must be new, empty or hold only earlier frames (replaced, with ``force``).

    ``target`` has no default here: the commands' (``nerfkit frames --frames``, ``nerfkit capture
    --clip-frames``) is :class:`~nerfkit.commands.options.FramesOptions`' ``frames``, the one
    place it is written (this module is below the commands and cannot read it).

    A clip that is not a video, has fewer than ``min_frames`` frames, or too few sharp,
    lit, moving ones is a NerfkitError saying what to film differently.
    """
    from ..io.atomic import write_json

    start = time.perf_counter()
    path, out_dir = Path(path), Path(out_dir)
    if target < min_frames:
        raise fail("target", f"{target} frames are too few to pose", f"Ask for at least {min_frames}")
    if spread not in SPREADS:
        raise fail("spread", f"'{spread}' is not one of {', '.join(SPREADS)}")
    info = probe_video(path)
    earlier = _check_out_dir(out_dir, path, force)
    scores = score_clip(path, info, score_side, progress)
    n = len(scores.sharpness)
    secs = f"{float(scores.times.max() - scores.times.min()):.1f} s" if n > 1 else "a single frame"
    if n < min_frames:
        raise fail(
            path,
            f"is too short: {n} frame{'s' * (n != 1)} ({secs})",
            f"Film a longer clip (at least {min_frames} frames; 20-60 s around the object is typical)",
        )
    kept, reason, median, threshold = choose_frames(
        scores, target, blur_ratio, duplicate_motion=duplicate_motion, spread=spread
    )
    counts = {r: int(np.sum(reason == r)) for r in REASONS}
    if len(kept) < min_frames:
        raise _too_few(path, n, len(kept), counts, min_frames, plain=median < PLAIN_SHARPNESS)
    names = [FRAME_NAME.format(k + 1) for k in range(len(kept))]
    windows = windows_of(spread_axis(scores, spread), target)
    short = cut_short(info, scores.times)
    if short:  # read short of the header: unless the sound alone runs on, the file was cut
        short = cut_short(info, scores.times, data_end=data_end(path))
    sel = FrameSelection(
        source=str(path.resolve()),
        source_stamp=clip_stamp(path),
        out_dir=str(out_dir),
        info=info,
        target=target,
        read=n,
        files=names,
        frame_indices=kept.tolist(),
        timestamps=[float(scores.times[i]) for i in kept],
        sharpness=[float(scores.sharpness[i]) for i in kept],
        dropped={r: c for r, c in counts.items() if c},
        median_sharpness=median,
        blur_threshold=threshold,
        empty_windows=int(target - len(set(windows[kept].tolist()))),
        score_size=score_size(info.width, info.height, score_side),
        spread=spread,
        advice=[f"{c} frames {r}: {ADVICE[r]}" for r, c in counts.items() if r in ADVICE and c > n // 4] + short,
    )
    with _frames_folder(out_dir, replace=bool(earlier)) as folder:
        extract_frames(path, info, sel.frame_indices, folder, names, progress)
        sel.seconds = time.perf_counter() - start
        write_json(folder / REPORT_NAME, sel.to_json())
    return sel


@contextlib.contextmanager
def _frames_folder(out_dir: Path, replace: bool) -> Iterator[Path]:
    """``out_dir`` to write a selection into. ``replace``: it holds only an earlier
    selection, replaced as a whole when the body succeeds and kept when it fails; else
    it is new or empty, and a failure removes what the body wrote there."""
    from ..io.atomic import replacing_folder

    if replace:
        with replacing_folder(out_dir) as folder:
            yield folder
        return
    existed = out_dir.exists()
    try:
        yield out_dir
    except BaseException:
        if existed:
            for p in out_dir.iterdir():
                if p.is_file() and (_FRAME_FILE.fullmatch(p.name) or p.name == REPORT_NAME):
                    p.unlink()
        else:
            shutil.rmtree(out_dir, ignore_errors=True)
        raise


def _too_few(path: Path, read: int, kept: int, counts: dict[str, int], need: int, plain: bool = False):
    """The NerfkitError for a clip with fewer than ``need`` frames worth keeping: named by
    the main reason the others were dropped. ``plain``: the lit frames' median sharpness is
    under :data:`PLAIN_SHARPNESS`: the clip shows no detail at all, which no steadier hand mends."""
    worst = max((DARK, BLURRED, DUPLICATE), key=lambda r: counts[r])
    if worst == BLURRED and plain:
        return fail(
            path,
            f"shows no detail in {counts[BLURRED]} of its {read} frames (one flat colour); at least {need} frames "
            "with detail are needed",
            "Film the object with its table and surroundings in view, in focus",
        )
    what = {DARK: "too dark", BLURRED: "blurred", DUPLICATE: "near-duplicates (the camera barely moves)"}[worst]
    if counts[worst] == read:
        head = f"every one of its {read} frames is {what}"
    else:
        head = f"only {kept} of its {read} frames are worth keeping ({counts[worst]} {what})"
    fix = {
        DARK: "Film with more light",
        BLURRED: "Film slower, with more light, and hold the phone steadier (or film a longer clip)",
        DUPLICATE: "Move slowly around the object while filming (or film a longer clip)",
    }[worst]
    return fail(path, f"{head}; at least {need} are needed", fix)
