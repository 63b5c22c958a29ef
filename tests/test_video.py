"""Video in: probing, frame selection and `nerfkit frames`, on clips generated here."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")
imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")

from conftest import write_mp4 as write_mp4_file  # noqa: E402
from nerfkit.capture.video import (
    BLURRED,
    DUPLICATE,
    REASONS,
    ClipScores,
    choose_frames,
    motion,
    parse_header,
    probe_video,
    select_expression,
    select_frames,
    travel,
    windows_of,
)
from nerfkit.cli import main
from nerfkit.errors import NerfkitError

FPS = 30


def texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    """(h, w, 3) uint8: smooth colour noise with discs (sharp edges at every scale)."""
    rng = np.random.default_rng(seed)
    img = cv2.resize(rng.random((h // 8, w // 8, 3)), (w, h), interpolation=cv2.INTER_CUBIC)
    img = (np.clip(img, 0, 1) * 255).astype(np.uint8)
    for _ in range(80):
        colour = tuple(int(c) for c in rng.integers(0, 255, 3))
        cv2.circle(img, (int(rng.integers(0, w)), int(rng.integers(0, h))), int(rng.integers(3, 20)), colour, -1)
    return img


def render_frames(n: int = 120, size=(160, 120), blur=(), pause=(), sigma: float = 3.0, seed: int = 0) -> list:
    """n frames of a camera sliding and bobbing over a textured plane; the camera stands
    still during the frames in ``pause``; frames in ``blur`` get a gaussian blur."""
    w, h = size
    tex = texture(h * 3, w * 4, seed)
    frames, k = [], 0
    for i in range(n):
        k += i not in pause
        x = int(k * (tex.shape[1] - w - 2) / n)
        y = int(h + 0.5 * h * np.sin(2 * np.pi * k / n))
        f = tex[y : y + h, x : x + w].copy()
        frames.append(cv2.GaussianBlur(f, (0, 0), sigma) if i in blur else f)
    return frames


def write_mp4(path, frames, fps: int = FPS) -> None:
    write_mp4_file(path, frames, fps=fps, macro_block_size=8)


def with_rotation(src, dst, degrees: int, hevc: bool = False) -> None:
    """Copy ``src`` to ``dst`` with a display matrix turning it ``degrees`` anticlockwise
    (as ffmpeg counts; an iPhone filmed upright records -90); with ``hevc``, re-encoded as
    an iPhone does: 10-bit HEVC tagged hvc1."""
    ffmpeg = [imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-y"]
    if hevc:  # (re-encoding would apply the rotation to the pixels: encode first, then tag)
        hevc_copy = dst.with_name("hevc_" + dst.name)
        subprocess.run(
            [
                *ffmpeg,
                "-i",
                str(src),
                "-c:v",
                "libx265",
                "-pix_fmt",
                "yuv420p10le",
                "-tag:v",
                "hvc1",
                "-crf",
                "12",
                "-x265-params",
                "log-level=error",
                str(hevc_copy),
            ],
            check=True,
        )
        src = hevc_copy
    subprocess.run([*ffmpeg, "-display_rotation:v", str(degrees), "-i", str(src), "-c", "copy", str(dst)], check=True)


BLUR = {10, 11, 12, 50, 51, 95}
PAUSE = set(range(60, 80))  # frames 59..79 are the same view


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    frames = render_frames(blur=BLUR, pause=PAUSE)
    path = tmp_path_factory.mktemp("clip") / "orbit.mp4"
    write_mp4(path, frames)
    return path, frames


@pytest.fixture(scope="module")
def selection(clip, tmp_path_factory):
    path, _ = clip
    return select_frames(path, tmp_path_factory.mktemp("sel") / "frames", target=30, progress=False)


def mad(a, b) -> float:
    return float(np.abs(a.astype(np.float32) - b.astype(np.float32)).mean())


def test_probe_reads_the_header(clip):
    info = probe_video(clip[0], count=True)
    assert (info.width, info.height, info.rotation, info.codec) == (160, 120, 0, "h264")
    assert info.fps == pytest.approx(30) and info.duration == pytest.approx(4.0, abs=0.05)
    assert info.frames == 120 and info.exact and not info.portrait


def test_selection_counts_add_up(selection):
    s = selection
    assert s.read == 120
    assert s.read == s.kept + sum(s.dropped.values())
    assert set(s.dropped) <= set(REASONS)
    assert s.frame_indices == sorted(s.frame_indices) and len(set(s.frame_indices)) == s.kept
    assert s.timestamps == pytest.approx([i / FPS for i in s.frame_indices], abs=1e-3)


def test_kept_frames_are_spread(selection):
    # 30 windows of 4 frames: every window outside the pause keeps a frame
    windows = {i // 4 for i in selection.frame_indices}
    paused = {w for w in range(30) if all(i in PAUSE or i == 59 for i in range(4 * w, 4 * w + 4))}
    assert set(range(30)) - paused <= windows
    gaps = np.diff([0, *selection.frame_indices, 119])
    assert gaps.max() <= len(PAUSE) + 8  # the pause, plus at most two windows around it
    assert np.sort(gaps)[-2] <= 8  # elsewhere at most two windows apart


def test_blurred_frames_are_not_kept(selection, clip):
    assert not BLUR & set(selection.frame_indices)  # each blurred frame has sharp ones in its window
    assert selection.dropped[BLURRED] == len(BLUR)
    # the kept frame is the sharpest in its window (the sharpness report says which)
    assert min(selection.sharpness) > selection.blur_threshold


def test_pause_is_dropped_as_near_duplicates(selection):
    in_pause = [i for i in selection.frame_indices if 59 <= i <= 79]
    assert len(in_pause) <= 1
    assert selection.dropped[DUPLICATE] >= len(PAUSE) - 8


def test_written_frames_are_the_chosen_ones(selection, clip):
    _, frames = clip
    out = selection.paths
    assert [p.name for p in out] == [f"frame_{k:05d}.jpg" for k in range(1, selection.kept + 1)]
    for p, i in zip(out, selection.frame_indices):
        rgb = cv2.imread(str(p))[..., ::-1]
        assert rgb.shape == (120, 160, 3)
        near = mad(rgb, frames[i])
        assert near < 6  # JPEG and H.264 losses only
        other = i + 2 if i + 2 < len(frames) and i + 2 not in PAUSE else i - 2
        assert near < mad(rgb, frames[other]) / 2  # the second read wrote the frame the first chose
    report = json.loads((out[0].parent / "frames.json").read_text())
    assert report["kept"] == selection.kept and report["read"] == 120
    assert [f["frame"] for f in report["frames"]] == selection.frame_indices


@pytest.mark.parametrize("degrees, clockwise, hevc", [(-90, 90, True), (90, 270, False)])
def test_rotation_metadata_gives_upright_portrait_frames(tmp_path, degrees, clockwise, hevc):
    frames = render_frames(n=30)
    plain, rotated = tmp_path / "plain.mp4", tmp_path / "rotated.mov"
    write_mp4(plain, frames)
    with_rotation(plain, rotated, degrees, hevc)
    info = probe_video(rotated)
    assert (info.width, info.height, info.rotation, info.portrait) == (120, 160, clockwise, True)
    assert info.codec == ("hevc" if hevc else "h264")
    s = select_frames(rotated, tmp_path / "frames", target=10, progress=False)
    rgb = cv2.imread(str(s.paths[0]))[..., ::-1]
    assert rgb.shape == (160, 120, 3)
    src = frames[s.frame_indices[0]]
    upright = np.rot90(src, k=-clockwise // 90)  # np.rot90 turns anticlockwise
    assert mad(rgb, upright) < 6 < mad(rgb, np.rot90(upright, 2))


def test_parse_header_old_and_new_rotation_tags():
    stream = (
        "  Stream #0:0[0x1](und): Video: hevc (Main 10) (hvc1 / 0x31637668), yuv420p10le(tv, bt2020nc), "
        "3840x2160, 40000 kb/s, 29.97 fps, 29.97 tbr, 600 tbn (default)\n"
    )
    head = "Input #0, mov,mp4,m4a,3gp,3g2,mj2, from 'IMG_0001.MOV':\n  Duration: 00:01:00.05, start: 0.0\n" + stream
    new = parse_header(head + "    Side data:\n      displaymatrix: rotation of -90.00 degrees\n")
    old = parse_header(head + "    Metadata:\n      rotate          : 90\n")
    none = parse_header(
        head + "  Stream #0:1: Audio: aac\n    Side data:\n      displaymatrix: rotation of -90.00 degrees\n"
    )
    for info in (new, old):
        assert (info.width, info.height, info.rotation, info.codec) == (2160, 3840, 90, "hevc")
        assert info.fps == pytest.approx(29.97) and info.frames == round(60.05 * 29.97)
    assert (none.width, none.rotation) == (3840, 0)  # another stream's side data is not the video's


def test_choose_frames_picks_the_sharpest_moving_frame_per_window():
    rng = np.random.default_rng(1)
    n, target = 40, 10
    base = cv2.GaussianBlur(rng.random((48, 64)).astype(np.float32) * 255, (0, 0), 2)
    thumbs = np.stack([np.roll(base, 2 * i, axis=1) for i in range(n)])
    thumbs[16:28] = thumbs[16]  # the camera stands still in windows 4 to 6
    sharp = rng.uniform(80, 120, n)
    sharp[[5, 6]] = 5.0  # blurred: far below the median
    bright = np.full(n, 100.0)
    bright[32:36] = 3.0  # window 8 is dark
    scores = ClipScores(np.arange(n) / 30.0, sharp, bright, thumbs)
    kept, reason, median, threshold = choose_frames(scores, target)
    expect = []
    for w in range(target):
        idx = [i for i in range(4 * w, 4 * w + 4) if i not in (5, 6)]
        if w in (5, 6) or w == 8:
            continue
        expect.append(max(idx, key=lambda i: sharp[i]))
    assert kept.tolist() == expect
    assert set(reason[[5, 6]]) == {BLURRED} and set(reason[32:36]) == {"too dark"}
    assert set(reason[20:28]) == {DUPLICATE}
    assert (reason[kept] == "").all() and len(kept) + (reason != "").sum() == n
    assert threshold == pytest.approx(0.35 * median)


def test_windows_and_motion():
    assert windows_of(np.arange(10) / 10, 5).tolist() == [0, 0, 1, 1, 2, 2, 3, 3, 4, 4]
    assert windows_of(np.arange(3) * 1.0, 10).tolist() == [0, 3, 6]
    assert windows_of(np.array([0.0, 0.1, 0.2, 0.9]), 4).tolist() == [0, 0, 0, 3]  # by time, not by count
    img = cv2.GaussianBlur(np.random.default_rng(0).random((64, 96)).astype(np.float32) * 255, (0, 0), 3)
    assert motion(img, img) == 0.0
    one = motion(img[:, 1:-1], img[:, 2:])
    assert 0.5 < one < 1.5 and motion(img[:, 2:-2], img[:, 4:]) > 1.5 * one


def test_a_gif_is_refused_as_a_clip(tmp_path):
    from PIL import Image

    frames = [Image.fromarray(np.full((16, 16, 3), 8 * k, np.uint8)) for k in range(20)]
    frames[0].save(tmp_path / "anim.gif", save_all=True, append_images=frames[1:], duration=40)
    with pytest.raises(NerfkitError, match="anim.gif: is a GIF, not a video. Pass the video the phone recorded"):
        probe_video(tmp_path / "anim.gif")


def test_a_clip_read_to_well_short_of_its_header_is_called_cut_short():
    """A file cut in half decodes its first half only: the header's 3 s against 1.3 s read is
    said (frames would come from the start only); a whole clip, or one a frame short, is not."""
    from nerfkit.capture.video import VideoInfo, cut_short

    info = VideoInfo("clip.mp4", 320, 240, 30.0, 3.0, 90, False, 0, "h264")
    (line,) = cut_short(info, np.arange(38) / 30.0)
    assert "read to 1.3 s of the 3.0 s its header gives" in line and "cut short" in line
    assert cut_short(info, np.arange(90) / 30.0) == [] and cut_short(info, np.arange(89) / 30.0) == []
    assert cut_short(VideoInfo("clip.mp4", 320, 240, 0.0, 0.0, 0, False, 0, "h264"), np.arange(5.0)) == []
    # the file's data reaching its header's end (the sound running on after the picture): whole
    assert cut_short(info, np.arange(38) / 30.0, data_end=3.0) == []
    assert cut_short(info, np.arange(38) / 30.0, data_end=1.4) == [line]


def test_a_clip_whose_sound_runs_on_is_whole_and_one_cut_in_half_is_not(tmp_path):
    from nerfkit.capture.video import data_end

    write_mp4(tmp_path / "picture.mp4", render_frames(n=30), fps=10)  # 3 s of picture
    ffmpeg = [imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-y"]
    sound = ["-f", "lavfi", "-i", "anullsrc=r=8000:cl=mono", "-t", "8", "-c:v", "copy", "-c:a", "aac"]
    for name, faststart in (("sound.mp4", []), ("fast.mp4", ["-movflags", "+faststart"])):
        subprocess.run(
            [*ffmpeg, "-i", str(tmp_path / "picture.mp4"), *sound, *faststart, str(tmp_path / name)], check=True
        )
    assert probe_video(tmp_path / "sound.mp4").duration == pytest.approx(8.0, abs=0.1)  # the file's: the sound's
    assert data_end(tmp_path / "sound.mp4") == pytest.approx(8.0, abs=0.1)
    sel = select_frames(tmp_path / "sound.mp4", tmp_path / "frames", 12, progress=False)
    assert sel.read == 30 and not any("cut short" in a for a in sel.advice)
    whole = (tmp_path / "fast.mp4").read_bytes()  # (its index first: the first half still opens)
    (tmp_path / "half.mp4").write_bytes(whole[: len(whole) // 2])
    assert data_end(tmp_path / "half.mp4") < 0.9 * probe_video(tmp_path / "half.mp4").duration


def test_select_expression_is_balanced():
    expr = select_expression(list(range(150)))
    assert expr.count("eq(n,") == 150 and expr.count("(") == expr.count(")")
    assert select_expression([3, 7]) == "eq(n,3)+eq(n,7)"


def frames_cli(capsys, *argv) -> tuple[int, str, str]:
    code = main(["frames", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_prints_the_report_and_guards_the_folder(clip, tmp_path, capsys):
    out = tmp_path / "frames"
    code, text, _ = frames_cli(capsys, clip[0], "--out", out, "--frames", 30)
    assert code == 0
    assert "read 120 frames, kept" in text and "blurred" in text and "near-duplicate" in text and str(out) in text
    first = sorted(out.glob("frame_*.jpg"))
    code, _, err = frames_cli(capsys, clip[0], "--out", out, "--frames", 12)
    assert code == 2 and "already holds frames" in err and "--force" in err
    assert sorted(out.glob("frame_*.jpg")) == first
    code, _, _ = frames_cli(capsys, clip[0], "--out", out, "--frames", 12, "--force")
    kept = json.loads((out / "frames.json").read_text())["kept"]
    assert code == 0 and len(list(out.glob("frame_*.jpg"))) == kept <= 12  # no frame of the first run is left
    (out / "notes.txt").write_text("mine")
    code, _, err = frames_cli(capsys, clip[0], "--out", out, "--force")
    assert code == 2 and "other files" in err and (out / "notes.txt").exists()


def test_cli_errors_say_what_to_do(tmp_path, capsys):
    text = tmp_path / "notes.mp4"
    text.write_text("not a video\n" * 50)
    code, _, err = frames_cli(capsys, text, "--out", tmp_path / "a")
    assert code == 2 and "notes.mp4: is not a video" in err and "Pass a video file" in err
    short = tmp_path / "short.mp4"
    write_mp4(short, render_frames(n=3))
    code, _, err = frames_cli(capsys, short, "--out", tmp_path / "b")
    assert code == 2 and "too short: 3 frames" in err and "longer clip" in err
    blurred = tmp_path / "blurred.mp4"
    write_mp4(blurred, render_frames(n=30, blur=set(range(30)), sigma=8))
    code, _, err = frames_cli(capsys, blurred, "--out", tmp_path / "c", "--frames", 10)
    assert code == 2 and "every one of its 30 frames is blurred" in err and "steadier" in err
    plain = tmp_path / "plain.mp4"  # no detail at all: no steadier hand mends it
    write_mp4(plain, [np.full((120, 160, 3), 128, np.uint8)] * 30)
    code, _, err = frames_cli(capsys, plain, "--out", tmp_path / "d", "--frames", 10)
    assert code == 2 and "shows no detail in 30 of its 30 frames" in err and "in focus" in err
    for out in ("a", "b", "c", "d"):
        assert not (tmp_path / out).exists()  # nothing written for a clip refused


def test_still_camera_is_refused(tmp_path):
    still = tmp_path / "still.mp4"
    write_mp4(still, render_frames(n=40, pause=set(range(1, 40))))
    with pytest.raises(NerfkitError, match="near-duplicates.*Move slowly around the object"):
        select_frames(still, tmp_path / "f", target=20, progress=False)


def test_a_failed_write_leaves_the_earlier_frames(clip, tmp_path, monkeypatch):
    from nerfkit.capture import video

    out = tmp_path / "frames"
    first = select_frames(clip[0], out, target=12, progress=False)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    real, calls = video._write_jpeg, []

    def failing(path, rgb, quality=95):
        calls.append(path)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        real(path, rgb, quality)

    monkeypatch.setattr(video, "_write_jpeg", failing)
    with pytest.raises(OSError):
        select_frames(clip[0], out, target=30, force=True, progress=False)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before and len(before) == first.kept + 1
    calls.clear()
    with pytest.raises(OSError):
        select_frames(clip[0], tmp_path / "new", target=30, progress=False)
    assert not (tmp_path / "new").exists()


def test_spreading_by_motion_gives_the_pause_no_windows(clip, tmp_path):
    by_time = select_frames(clip[0], tmp_path / "t", target=30, progress=False)
    by_motion = select_frames(clip[0], tmp_path / "m", target=30, spread="motion", progress=False)
    assert by_motion.spread == "motion" and by_motion.read == by_motion.kept + sum(by_motion.dropped.values())
    assert len([i for i in by_motion.frame_indices if 59 <= i <= 79]) <= 1
    assert by_motion.kept > by_time.kept and by_motion.kept >= 28  # the pause's windows go to the moving parts
    assert not BLUR & set(by_motion.frame_indices)
    position = [i - sum(p <= i for p in PAUSE) for i in by_motion.frame_indices]  # the camera's, in frames moved
    assert np.diff([0, *position, 100]).max() <= 8


def test_travel_adds_up_consecutive_motion():
    img = cv2.GaussianBlur(np.random.default_rng(0).random((48, 200)).astype(np.float32) * 255, (0, 0), 3)
    thumbs = np.stack([img[:, s : s + 64] for s in (0, 1, 2, 2, 2, 3)])  # one pixel a frame, a pause of two frames
    t = travel(thumbs)
    assert t[0] == 0 and t[3] == t[4] == t[2] and np.all(np.diff(t) >= 0)
    assert t[-1] == pytest.approx(3.0, rel=0.5) and t[5] - t[4] == pytest.approx(t[1], rel=0.3)


def test_two_takes_of_other_sizes_joined_are_read_whole_in_order(tmp_path):
    """ffmpeg rebuilds a filter graph when the frames change size mid-stream, and would count
    them from 0 again: the second take's frames taken for the first's, half the clip lost."""
    frames = render_frames(n=40)
    write_mp4(tmp_path / "a.mp4", frames[:20], fps=10)
    write_mp4(tmp_path / "b.mp4", [cv2.resize(f, (200, 152)) for f in frames[20:]], fps=10)
    ffmpeg = [imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-y"]
    annexb = ["-c", "copy", "-bsf:v", "h264_mp4toannexb", "-f", "mpegts"]
    for take in ("a", "b"):
        subprocess.run(
            [*ffmpeg, "-i", str(tmp_path / f"{take}.mp4"), *annexb, str(tmp_path / f"{take}.ts")], check=True
        )
    joined = ["-i", f"concat:{tmp_path / 'a.ts'}|{tmp_path / 'b.ts'}", "-c", "copy", str(tmp_path / "joined.mp4")]
    subprocess.run([*ffmpeg, *joined], check=True)
    sel = select_frames(tmp_path / "joined.mp4", tmp_path / "frames", 40, progress=False, duplicate_motion=0.0)
    assert sel.read == 40 and sel.frame_indices == list(range(40))  # every frame, each its own
    assert sel.timestamps[-1] == pytest.approx(3.9, abs=0.15)  # the second take's last frame
    last = cv2.imread(str(tmp_path / "frames" / sel.files[-1]))[..., ::-1]
    assert last.shape == (120, 160, 3)  # at the first take's size
    truth = cv2.resize(cv2.resize(frames[sel.frame_indices[-1]], (200, 152)), (160, 120))
    assert np.abs(last.astype(float) - truth).mean() < 12  # that frame, not another


def test_a_clip_named_with_a_colon_is_read_as_a_file(tmp_path):
    write_mp4(tmp_path / "take:2.mp4", render_frames(n=20), fps=10)  # ffmpeg would take "take:" for a protocol
    assert probe_video(tmp_path / "take:2.mp4").frames == 20
    assert select_frames(tmp_path / "take:2.mp4", tmp_path / "frames", 12, progress=False).read == 20


def test_a_very_wide_frame_gets_a_thumbnail_motion_can_measure():
    from nerfkit.capture.video import frame_scores

    grey = texture(48, 720)[20:26, :, 0]  # a 2000x16 clip scored at 720x6
    _, _, thumb = frame_scores(grey)
    assert thumb.shape == (2, 64)
    assert motion(thumb, thumb) == 0.0
    # shifts of 1, 2 and 3 thumbnail pixels measure as growing, finite motions. Not asserted:
    # the calibration; on this strip one pixel measures 1.87 (motion() averages |gx| and |gy|
    # as for a texture without a preferred direction, and a 2-row strip has little |gy|)
    shifts = [motion(thumb[:, d:], thumb[:, :-d]) for d in (1, 2, 3)]
    assert np.isfinite(shifts).all() and 0 < shifts[0] < shifts[1] < shifts[2]
