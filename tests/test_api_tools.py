"""The tools around the pipeline from Python (nerfkit.api: tags, frames, convert, dataset,
fit_image, view): every flag is an argument with its default, bad input is a NerfkitError
before anything is written, and each call does the command's work on a tiny generated input,
with the command's report and files."""

from __future__ import annotations

import inspect
import re
import zlib

import numpy as np
import pytest

from nerfkit import api
from nerfkit.cli import main
from nerfkit.errors import NerfkitError

# a command's flag -> the API's argument of another name
RENAMED = {"dict": "dictionary"}


@pytest.mark.parametrize(
    ("command", "function", "argv", "given", "api_only", "options"),
    [
        ("tags", api.tags, [], set(), {"quiet"}, api.TagsOptions),
        ("frames", api.frames, ["clip.mp4", "--out", "f"], {"clip", "out"}, {"quiet"}, api.FramesOptions),
        ("convert", api.convert, ["scene.npz", "--to", "o.npz"], {"src", "to"}, {"quiet"}, api.ConvertOptions),
        ("dataset", api.dataset, ["my_object"], {"poses"}, {"quiet"}, None),
        ("view", api.view, ["scene.npz"], {"path"}, {"block", "quiet"}, api.ViewOptions),
        ("fit-image", api.fit_image, [], set(), set(), None),  # (its --quiet: no progress bar, the call's: nor report)
    ],
)
def test_every_flag_of_a_tool_is_an_argument_with_its_default(command, function, argv, given, api_only, options):
    """As test_api_capture's: a call without options does what the command line without options
    does. ``given``: the command's required arguments; ``api_only``: the API's own arguments
    (``quiet``: the command line always prints its report). The flags of a settings dataclass
    are its ``settings`` argument (None: its defaults), as the command line's unset flags are None;
    those of the command's ``options`` dataclass are arguments with its defaults, which the
    command fills in for the flags not given."""
    import argparse
    import dataclasses

    from nerfkit.cli import build_parser
    from nerfkit.config import dataclass_from_args

    args = build_parser(command).parse_args([command, *argv])
    if options is not None:  # as the command calls the function
        flagged = [f for f in dataclasses.fields(options) if f.metadata.get("cli") is not False]
        assert all(getattr(args, f.name) is None for f in flagged)  # (a field without: the command's own flag)
        args = argparse.Namespace(**{**vars(args), **dataclasses.asdict(dataclass_from_args(options, args))})
    params = inspect.signature(function).parameters
    checked = set(given)
    for dest, value in vars(args).items():
        if dest in ("command", "func", "verbose") or dest in given:
            continue
        name = RENAMED.get(dest, dest.removeprefix("no_"))
        if name not in params:  # a field of the settings dataclass: unset, so None
            assert value is None and "settings" in params, dest
            checked.add("settings")
            continue
        expected = (not value) if dest.startswith("no_") else value
        assert params[name].default == expected, (dest, params[name].default, expected)
        checked.add(name)
    assert set(params) - checked == api_only


def test_the_choices_of_the_tools_are_the_flags():
    from typing import get_args

    from nerfkit.capture.sheet import PAPERS
    from nerfkit.capture.video import SPREADS
    from nerfkit.cli import build_parser

    assert set(get_args(api.Paper)) == set(PAPERS)
    assert get_args(api.Spread) == SPREADS
    for command, flag, choices in [
        ("convert", "--format", api.ConvertFormat),
        ("frames", "--spread", api.Spread),
        ("dataset", "--pose-source", api.PoseSource),
    ]:
        parser = build_parser(command)._subparsers._group_actions[0].choices[command]
        assert tuple(parser._option_string_actions[flag].choices) == get_args(choices)


# ----------------------------------------------------------------------------- tags


def raster_pdf(pdf: bytes, dpi: int = 100) -> list[np.ndarray]:
    """Each page of a PDF as (H, W) uint8 grey at ``dpi``: its black filled straight-edged paths
    (what matplotlib writes for the tags' cells) on white. Text and strokes are left out."""
    import cv2

    objects = {int(n): body for n, body in re.findall(rb"(\d+) 0 obj(.*?)endobj", pdf, re.S)}
    pages = []
    for box, contents in re.findall(rb"/MediaBox \[ *0 0 ([\d.]+ [\d.]+) *\]\s*/Contents (\d+) 0 R", pdf):
        w, h = map(float, box.split())
        scale = dpi / 72
        stream = re.search(rb"stream\r?\n(.*)endstream", objects[int(contents)], re.S).group(1)
        image = np.full((round(h * scale), round(w * scale)), 255, np.uint8)
        numbers, polygons, black = [], [], False
        for token in zlib.decompress(stream).split():
            try:
                numbers.append(float(token))
                continue
            except ValueError:
                pass
            if token == b"g":
                black = numbers[-1] == 0
            elif token == b"m":
                polygons.append([numbers[-2:]])
            elif token == b"l":
                polygons[-1].append(numbers[-2:])
            elif token in (b"f", b"f*"):
                if black:
                    pixels = [np.round((np.array(p) * [1, -1] + [0, h]) * scale).astype(np.int32) for p in polygons]
                    cv2.fillPoly(image, pixels, 0)
                polygons = []
            elif token in (b"S", b"n"):
                polygons = []
            numbers = []
        pages.append(image)
    return pages


def tag_ids(image: np.ndarray, dictionary: str = "DICT_4X4_50") -> list[int]:
    """The ids of the tags OpenCV finds in ``image``, in order."""
    from nerfkit.capture.aruco import detect, get_dictionary, make_detector

    bits = get_dictionary(dictionary).markerSize
    found = detect(image, make_detector(dictionary), detect_side=4000, marker_bits=bits)
    return sorted(found.ids.tolist())


def test_tags_writes_a_pdf_whose_tags_opencv_finds_as_the_command_does(tmp_path, capsys):
    result = api.tags(tmp_path / "a.pdf", paper="letter", tag_size=0.04, object_tag_size=0.12)
    by_api = capsys.readouterr().out
    assert result == api.TagsResult(tmp_path / "a.pdf", 2, result.sheet_ids, result.sheet_ids[-1] + 1)
    assert result.sheet_ids == tuple(range(len(result.sheet_ids))) and len(result.sheet_ids) >= 6
    pages = raster_pdf(result.pdf_path.read_bytes())
    assert len(pages) == 2 and pages[0].shape == (1100, 850)  # letter at 100 dpi
    assert tag_ids(pages[0]) == list(result.sheet_ids) and tag_ids(pages[1]) == [result.object_tag_id]

    argv = ["tags", "--out", str(tmp_path / "b.pdf"), "--paper", "letter", "--tag-size", "0.04"]
    assert main([*argv, "--object-tag-size", "0.12"]) == 0
    assert capsys.readouterr().out == by_api.replace("a.pdf", "b.pdf")
    assert all(np.array_equal(a, b) for a, b in zip(pages, raster_pdf((tmp_path / "b.pdf").read_bytes())))

    alone = api.tags(tmp_path / "c.pdf", object_tag_size=0, quiet=True)
    assert capsys.readouterr().out == "" and alone.pages == 1 and alone.object_tag_id is None
    assert len(raster_pdf(alone.pdf_path.read_bytes())) == 1


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"paper": "a3"}, "--paper: 'a3' is not one of a4, letter"),
        ({"tag_size": 60.0}, "--tag-size: 60.0 is not a printed tag's side in metres"),
        ({"tag_size": 0.0001}, "--tag-size: a 0.1 mm tag has 0.017 mm cells"),
        ({"object_tag_size": 0.3}, "--object-tag-size: a 300 mm tag does not fit on a4 paper"),
        ({"object_tag_size": None}, "--object-tag-size: None is not a number"),
        ({"dictionary": "DICT_9X9"}, "unknown ArUco dictionary"),
        ({"out": "tags.png"}, "--out: 'tags.png' should end in .pdf"),
    ],
)
def test_tags_refuses_what_the_command_line_refuses(tmp_path, monkeypatch, options, message):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(NerfkitError, match=message):
        api.tags(**{"out": "tags.pdf", **options})
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- frames


def sliding_clip(path, n: int = 40, size=(160, 120)) -> None:
    """An MP4 of ``n`` sharp frames of a camera sliding over a textured plane."""
    import cv2

    from conftest import write_mp4

    w, h = size
    rng = np.random.default_rng(0)
    texture = (cv2.resize(rng.random((h // 4, w // 2, 3)), (w * 2, h), interpolation=cv2.INTER_CUBIC) * 255).astype(
        np.uint8
    )
    for _ in range(60):
        centre = (int(rng.integers(0, 2 * w)), int(rng.integers(0, h)))
        cv2.circle(texture, centre, int(rng.integers(3, 15)), tuple(int(c) for c in rng.integers(0, 255, 3)), -1)
    write_mp4(path, [texture[:, round(i * w / n) :][:, :w].copy() for i in range(n)], fps=10)


def without_times(report: str, folder) -> str:
    return re.sub(r"in [\d.]+ s", "in T s", report.replace(str(folder), "OUT"))


def test_frames_writes_the_frames_it_reports_as_the_command_does(tmp_path, capsys):
    import json

    sliding_clip(tmp_path / "clip.mp4")
    result = api.frames(tmp_path / "clip.mp4", tmp_path / "a", frames=10)
    by_api = capsys.readouterr().out
    report = json.loads((tmp_path / "a" / "frames.json").read_text())
    assert result.out == tmp_path / "a" and result.report_path == tmp_path / "a" / "frames.json"
    assert result.read == report["read"] == 40 and 8 <= len(result.files) == report["kept"] <= 10
    assert [p.name for p in result.files] == [f["file"] for f in report["frames"]]
    assert all(p.is_file() for p in result.files)
    assert f"read 40 frames, kept {len(result.files)} (asked for 10)" in by_api

    assert main(["frames", str(tmp_path / "clip.mp4"), "--out", str(tmp_path / "b"), "--frames", "10"]) == 0
    assert without_times(capsys.readouterr().out, tmp_path / "b") == without_times(by_api, tmp_path / "a")
    assert [p.read_bytes() for p in result.files] == [(tmp_path / "b" / p.name).read_bytes() for p in result.files]

    with pytest.raises(NerfkitError, match="already holds frames"):
        api.frames(tmp_path / "clip.mp4", tmp_path / "a", frames=12, quiet=True)
    again = api.frames(tmp_path / "clip.mp4", tmp_path / "a", frames=12, spread="motion", force=True, quiet=True)
    assert capsys.readouterr().out == "" and again.read == 40


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"frames": 5}, "--frames: 5 is below the minimum 10"),
        ({"frames": 12.5}, "--frames: 12.5 is not a whole number"),
        ({"spread": "space"}, "--spread: 'space' is not one of time, motion"),
        ({"out": None}, "out: None is not a path"),
        ({"out": " "}, "--out: is empty"),
    ],
)
def test_frames_refuses_what_the_command_line_refuses(tmp_path, options, message):
    (tmp_path / "clip.mp4").write_bytes(b"not looked at")
    with pytest.raises(NerfkitError, match=message):
        api.frames(**{"clip": tmp_path / "clip.mp4", "out": tmp_path / "f", **options})
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]


# ----------------------------------------------------------------------------- convert


def test_convert_writes_a_dataset_that_reads_back_as_the_command_does(tmp_path, sphere_npz, capsys):
    import json

    from nerfkit.data.load import load_scene

    result = api.convert(sphere_npz, tmp_path / "a", size=16, near=1.0)
    by_api = capsys.readouterr().out
    assert result == api.ConvertResult(
        tmp_path / "a",
        "transforms",
        "npz",
        (tmp_path / "a" / "transforms.json",),
        {"train": 20, "val": 2, "test": 4},
        16,
        16,
    )
    back, resized = load_scene(tmp_path / "a"), load_scene(sphere_npz, size=16)
    assert (back.near, back.far) == (1.0, resized.far) and back.train.images.shape == (20, 16, 16, 3)
    np.testing.assert_allclose(back.train.c2w, resized.train.c2w, atol=1e-6)
    np.testing.assert_allclose(back.train.images, resized.train.images, atol=1 / 255)  # (8-bit PNG)

    assert main(["convert", str(sphere_npz), "--to", str(tmp_path / "b"), "--size", "16", "--near", "1"]) == 0
    assert capsys.readouterr().out == by_api.replace(str(tmp_path / "a"), str(tmp_path / "b"))
    written = [json.loads((tmp_path / f / "transforms.json").read_text()) for f in "ab"]
    assert written[0] == written[1]

    npz = api.convert(sphere_npz, tmp_path / "c.npz", quiet=True)
    assert capsys.readouterr().out == "" and npz.format == "npz" and npz.files == (tmp_path / "c.npz",)
    np.testing.assert_array_equal(load_scene(npz.out).val.images, load_scene(sphere_npz).val.images)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"format": "ply"}, "--format: 'ply' is not one of auto, npz, transforms, colmap"),
        ({"size": 16, "downscale": 2.0}, "--downscale: not allowed with --size"),
        ({"size": 0}, "--size: 0 is below the minimum 1"),
        ({"far": 1e308}, "--far: 1e\\+308 is larger than a dataset file holds"),
        ({"to": "o.ply"}, "looks like a .ply file"),
        ({"to": "o.npz", "format": "transforms"}, "--format transforms writes a folder, not an .npz file"),
        ({"format": "colmap", "near": 1.0}, "--near/--far: a COLMAP model keeps no depth range"),
        ({"background": "purple"}, "--background: 'purple' is not a colour"),
        ({"images": "photos"}, "--images: only applies to COLMAP inputs"),
        ({"images": ""}, "--images: is empty"),
        ({"to": ""}, "to: is empty"),
        ({"text": "yes"}, "--text: 'yes' is not True or False"),
    ],
)
def test_convert_refuses_what_the_command_line_refuses(tmp_path, sphere_npz, options, message):
    with pytest.raises(NerfkitError, match=message):
        api.convert(**{"src": sphere_npz, "to": tmp_path / "out", **options})
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- dataset


@pytest.fixture(scope="module")
def posed(tmp_path_factory):
    """A folder with the poses.json of 10 synthetic photos of an object beside a tag (no dataset yet)."""
    import json

    from nerfkit.capture import synthetic as S

    cap, folder = S.cached_capture("object", 10, 1), tmp_path_factory.mktemp("posed")
    (folder / "photos").mkdir()
    for name, img in zip(cap.names, cap.images):
        S.write_photo(folder / "photos" / name, img)
    camera = {"K": cap.K.tolist(), "dist": cap.dist.tolist(), "width": cap.width, "height": cap.height}
    (folder / "camera.json").write_text(json.dumps({**camera, "dictionary": "DICT_4X4_50"}))
    api.pose(folder / "photos", folder / "poses", tag_size=0.06, camera=folder / "camera.json", build_dataset=False)
    return folder / "poses"


def steady(report: str) -> str:
    """``report`` without its counts of sparse points: pycolmap's triangulation (on all cores)
    finds a point more or fewer from one run to the next."""
    return "\n".join(re.sub(r"\d+", "N", line) if "sparse points" in line else line for line in report.splitlines())


def test_dataset_builds_from_the_poses_and_reads_back_as_the_command_does(tmp_path, posed, capsys):
    import json

    from nerfkit.capture.dataset import DatasetConfig
    from nerfkit.data.load import load_scene

    capsys.readouterr()
    result = api.dataset(posed, out=tmp_path / "a", settings=DatasetConfig(max_side=160))
    by_api = capsys.readouterr().out
    assert result.dataset_path == tmp_path / "a" / "dataset.npz" and result.pose_source == "tags"
    scene = load_scene(result.dataset_path)
    assert result.views == {k: len(v) for k, v in scene.splits.items()} and result.views["train"] >= 5
    assert sum(result.views.values()) == json.loads((posed / "poses.json").read_text())["photos_posed"]
    assert max(scene.train.width, scene.train.height) == 160 and (tmp_path / "a" / "transforms.json").is_file()
    assert f"dataset: {result.views['train']} train, {result.views['val']} val" in by_api

    assert main(["dataset", str(posed), "--out", str(tmp_path / "b"), "--max-side", "160"]) == 0
    by_command = capsys.readouterr().out
    assert steady(by_command) == steady(by_api.replace(str(tmp_path / "a"), str(tmp_path / "b")))
    again = load_scene(tmp_path / "b" / "dataset.npz")
    np.testing.assert_array_equal(again.train.images, scene.train.images)
    np.testing.assert_array_equal(again.train.c2w, scene.train.c2w)

    with pytest.raises(NerfkitError, match="already exists|--force"):
        api.dataset(posed, out=tmp_path / "a", quiet=True)
    assert api.dataset(posed / "poses.json", out=tmp_path / "a", force=True, quiet=True).views == result.views
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"pose_source": "exif"}, "--pose-source: 'exif' is not one of auto, tags, sfm"),
        ({"jobs": -1}, "--jobs: -1 is below the minimum 0"),
        ({"settings": {"max_side": 160}}, "settings: .* is not a DatasetConfig"),
        ({"out": ""}, "--out: is empty"),
        ({"force": 1}, "--force: 1 is not True or False"),
    ],
)
def test_dataset_refuses_what_the_command_line_refuses(tmp_path, posed, options, message):
    with pytest.raises(NerfkitError, match=message):
        api.dataset(posed, **{"out": tmp_path / "out", **options})
    assert list(tmp_path.iterdir()) == []


def test_dataset_settings_are_checked_as_their_flags(tmp_path, posed):
    from nerfkit.capture.dataset import DatasetConfig

    with pytest.raises(NerfkitError, match="--max-side"):
        api.dataset(posed, out=tmp_path / "out", settings=DatasetConfig(max_side=3))
    assert not (tmp_path / "out").exists()


# ----------------------------------------------------------------------------- fit_image


def pattern_png(path, h: int = 12, w: int = 12):
    """A smooth colour pattern as an 8-bit PNG at ``path``."""
    import cv2

    y, x = (np.mgrid[0:h, 0:w] + 0.5) / [[[h]], [[w]]]
    rgb = np.stack([0.5 + 0.4 * np.sin(2 * np.pi * x), 0.5 + 0.4 * np.cos(2 * np.pi * (x + y)), 0.1 + 0.8 * x * y], -1)
    cv2.imwrite(str(path), (rgb[..., ::-1] * 255 + 0.5).astype(np.uint8))
    return path


SMALL = {"L": 2, "width": 16, "depth": 1, "batch": 64, "steps": 10, "precision": "fp32", "device": "cpu"}


def without_speeds(report: str, folder) -> str:
    report = re.sub(r"[\d.]+ steps/s", "N steps/s", report.replace(str(folder), "OUT"))
    return re.sub(r"[\d.]+ s (training|evaluation)", r"T s \1", report)


def test_fit_image_fits_and_writes_its_run_as_the_command_does(tmp_path, capsys):
    import json

    from nerfkit.fit_image import FitImageConfig

    image = pattern_png(tmp_path / "p.png")
    result = api.fit_image(image, out=tmp_path / "a", settings=FitImageConfig(**SMALL))
    by_api = capsys.readouterr().out
    metrics = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert result.out == tmp_path / "a" and not result.interrupted and result.metrics == metrics
    assert result.final_psnr == metrics["final_psnr_db"] > 10 and metrics["steps"] == 10
    assert (metrics["image_width"], metrics["image_height"]) == (12, 12)
    assert all((tmp_path / "a" / name).is_file() for name in ("psnr.png", "progression.png", "final.png"))
    assert f"final PSNR {result.final_psnr:.2f} dB (every pixel, 12x12) after 10 steps" in by_api

    flags = [x for k, v in SMALL.items() for x in (f"--{k.replace('_', '-')}", str(v))]
    assert main(["fit-image", str(image), "--out", str(tmp_path / "b"), *flags, "--quiet"]) == 0
    assert without_speeds(capsys.readouterr().out, tmp_path / "b") == without_speeds(by_api, tmp_path / "a")
    assert json.loads((tmp_path / "b" / "metrics.json").read_text())["final_psnr_db"] == result.final_psnr

    swept = api.fit_image(image, out=tmp_path / "s", sweep=["L=0,2"], settings=FitImageConfig(**SMALL), quiet=True)
    assert capsys.readouterr().out == "" and swept.final_psnr is None
    assert (
        [r["L"] for r in swept.sweep]
        == [0, 2]
        == [r["L"] for r in json.loads((tmp_path / "s" / "sweep.json").read_text())["runs"]]
    )
    assert swept.sweep[1]["final_psnr_db"] == result.final_psnr  # the same fit as L=2 alone


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"sweep": []}, "--sweep: no KEY=V1,V2 items"),
        ({"sweep": ["L=100"]}, "--sweep L=100: 100 is above the maximum 30"),
        ({"sweep": ["colour=1"]}, "--sweep: cannot sweep 'colour'"),
        ({"sweep": "L=2"}, "--sweep: 'L=2' is not"),
        ({"settings": {"L": 2}}, "settings: .* is not a FitImageConfig"),
        ({"out": ""}, "--out: is empty"),
        ({"quiet": "yes"}, "--quiet: 'yes' is not True or False"),
    ],
)
def test_fit_image_refuses_what_the_command_line_refuses(tmp_path, options, message):
    image = pattern_png(tmp_path / "p.png")
    with pytest.raises(NerfkitError, match=message):
        api.fit_image(image, **{"out": tmp_path / "out", **options})
    assert [p.name for p in tmp_path.iterdir()] == ["p.png"]


def test_fit_image_settings_are_checked_as_their_flags(tmp_path):
    from nerfkit.fit_image import FitImageConfig

    with pytest.raises(NerfkitError, match="--L: 100 is above the maximum 30"):
        api.fit_image(pattern_png(tmp_path / "p.png"), out=tmp_path / "out", settings=FitImageConfig(L=100))
    with pytest.raises(NerfkitError, match="--precision: 'fp8' is not one of auto, bf16, fp32"):
        api.fit_image(tmp_path / "p.png", out=tmp_path / "out", settings=FitImageConfig(precision="fp8"))
    assert not (tmp_path / "out").exists()


# ----------------------------------------------------------------------------- view


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_view_draws_a_dataset_as_the_command_does(tmp_path, sphere_npz, capsys):
    import cv2

    result = api.view(sphere_npz, rays_from=2, rays=10, png=tmp_path / "a.png")
    assert result == api.ViewResult(tmp_path / "a.png", None) and capsys.readouterr().out == f"wrote {result.png}\n"
    picture = cv2.imread(str(result.png))
    assert picture.shape[0] > 200 and picture.std() > 5  # a figure, not a blank
    argv = ["view", str(sphere_npz), "--rays-from", "2", "--rays", "10", "--png", str(tmp_path / "b.png")]
    assert main(argv) == 0 and capsys.readouterr().out == f"wrote {tmp_path / 'b.png'}\n"
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "b.png")), picture)


def test_view_serves_a_dataset_and_returns_its_server(sphere_npz, capsys):
    from urllib.request import urlopen

    from nerfkit.viz.viewer import viewer_url

    result = api.view(sphere_npz, port=free_port(), rays=4, samples=8)
    try:
        assert result.url == viewer_url("127.0.0.1", result.server.get_port()) and result.png is None
        assert "20 train, 2 val, 4 test cameras" in capsys.readouterr().out
        with urlopen(result.url, timeout=10) as page:
            assert page.status == 200
    finally:
        result.server.stop()


def test_view_of_a_run_serves_its_live_viewer_only_when_it_may_block(tmp_path, monkeypatch):
    import sys
    import types

    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "config.json").write_text("{}")
    with pytest.raises(NerfkitError, match="renders on the calling thread until Ctrl-C. Pass block=True"):
        api.view(run)
    calls = []
    fake = types.ModuleType("nerfkit.commands.live")
    fake.serve_run = lambda run_dir, host, port, **kw: calls.append((run_dir, host, port, kw))
    monkeypatch.setitem(sys.modules, "nerfkit.commands.live", fake)
    assert api.view(run, port=9123, block=True, quiet=True) == api.ViewResult(None, None)
    assert calls == [(run, "127.0.0.1", 9123, {"allow_outside_paths": False, "quiet": True})]
    with pytest.raises(NerfkitError, match="--rays: the live viewer of a trained run draws its cameras"):
        api.view(run, rays=5, block=True)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"rays": -1}, "--rays: -1 is below the minimum 0"),
        ({"samples": 0}, "--samples: 0 is below the minimum 1"),
        ({"port": 70000}, "--port: 70000 is above the maximum 65535"),
        ({"rays_from": 20}, "--rays-from: the dataset has 20 training views"),
        ({"png": "scene.jpg"}, "--png: 'scene.jpg' should end in .png"),
        ({"png": ""}, "--png: is empty"),
        ({"host": None}, "--host: None is not text"),
        ({"downscale": 0.5}, "--downscale: 0.5 is below the minimum"),
    ],
)
def test_view_refuses_what_the_command_line_refuses(tmp_path, sphere_npz, monkeypatch, options, message):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(NerfkitError, match=message):
        api.view(sphere_npz, **{"png": "scene.png", **options})
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "kwargs, flag", [({"model": "splat"}, "--model"), ({"minutes": 0}, "--minutes"), ({"seed": -1}, "--seed")]
)
def test_the_demo_refuses_what_its_command_line_refuses_before_writing_anything(tmp_path, kwargs, flag):
    with pytest.raises(NerfkitError, match=re.escape(flag)):
        api.demo(tmp_path / "demo", quiet=True, **kwargs)
    assert not (tmp_path / "demo").exists()


def test_nerfkit_demo_is_api_demo_with_its_flags(monkeypatch, capsys, tmp_path):
    """The command is the API function: its flags become the call's arguments, and it prints the
    summary and the files the function returns."""
    from nerfkit.commands import tools

    calls = []

    def fake(out, **kw):
        calls.append((out, kw))
        return tools.DemoResult(tmp_path, {"val_psnr": 1.5}, {"orbit video": tmp_path / "v.mp4"})

    monkeypatch.setattr(tools, "demo", fake)
    assert main(["demo", "--out", "x", "--minutes", "2", "--seed", "3"]) == 0
    assert calls == [("x", {"model": "fast", "minutes": 2.0, "device": "auto", "seed": 3})]
    out = capsys.readouterr().out
    assert '"val_psnr": 1.5' in out and str(tmp_path / "v.mp4") in out


@pytest.mark.slow
def test_the_demo_trains_renders_and_scores_lego_into_a_fresh_folder(tmp_path):
    """Seconds of training: the summary agrees with the run's own evaluation, every file it
    names exists, and a second demo into the same folder goes to a fresh one beside it."""
    import json

    first = api.demo(tmp_path / "demo", minutes=0.1, quiet=True)
    assert first.run_dir == tmp_path / "demo"
    assert all(p.is_file() for p in first.outputs.values()), first.outputs
    saved = json.loads((first.run_dir / "summary.json").read_text())
    assert saved == first.summary and saved["steps"] > 0
    scored = json.loads((first.run_dir / "eval_val.json").read_text())
    assert saved["val_psnr"] == pytest.approx(scored["psnr"]) and saved["val_psnr"] > 12
    second = api.demo(tmp_path / "demo", minutes=0.02, quiet=True)
    assert second.run_dir == tmp_path / "demo-2"
