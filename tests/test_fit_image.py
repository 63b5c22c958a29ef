"""Tests of ``nerfkit fit-image``: model, PSNR, fitting, sweep, files, bad input (the encoding: test_rendering_math)."""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from nerfkit.cli import main
from nerfkit.errors import NerfkitError
from nerfkit.fields.image_field import ImageField, grid_xy, pixel_xy
from nerfkit.fit_image import (
    FitImageConfig,
    default_image_path,
    fit_image,
    load_target,
    parse_background,
    parse_sweep,
    render_image,
    run_fit,
    run_sweep,
)
from nerfkit.train.metrics import psnr_from_mse  # (the one fit-image uses)


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """Tiny models gain nothing from threads, and on a busy machine OpenMP threads waiting
    for each other make them many times slower; one thread keeps these tests fast."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


# A small, fast configuration for tests (the defaults are the course's).
TINY = FitImageConfig(
    L=4, width=64, depth=2, batch=512, steps=250, eval_every=50, progress_steps="0,50", precision="fp32", device="cpu"
)


def smooth_image(h: int = 32, w: int = 32) -> np.ndarray:
    """(h, w, 3) float32 smooth colour pattern in [0.1, 0.9]."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    x, y = (x + 0.5) / w, (y + 0.5) / h
    r = 0.5 + 0.4 * np.sin(2 * np.pi * x) * np.cos(np.pi * y)
    g = 0.5 + 0.4 * np.cos(2 * np.pi * (x + y))
    b = 0.1 + 0.8 * x * y
    return np.stack([r, g, b], axis=-1).astype(np.float32)


def save_png(path: Path, image: np.ndarray) -> Path:
    Image.fromarray((np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8)).save(path)
    return path


def decode(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path))


# --- model ---------------------------------------------------------------------------


def test_image_field_is_the_course_model():
    m = ImageField(L=10, width=256, depth=3)
    linears = [mod for mod in m.modules() if isinstance(mod, torch.nn.Linear)]
    assert [(lin.in_features, lin.out_features) for lin in linears] == [(42, 256), (256, 256), (256, 256), (256, 3)]
    n_params = sum(p.numel() for p in m.parameters())
    assert n_params == 42 * 256 + 256 + 2 * (256 * 256 + 256) + 256 * 3 + 3
    rgb = m(torch.rand(100, 2))
    assert rgb.shape == (100, 3) and rgb.dtype == torch.float32
    assert bool(((rgb > 0) & (rgb < 1)).all())


def test_output_is_float32_under_bf16_autocast():
    m = ImageField(L=4, width=16, depth=1)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        rgb = m(torch.rand(10, 2))
    assert rgb.dtype == torch.float32


def test_pixel_coordinates_are_pixel_centres():
    xy = pixel_xy(torch.tensor([0, 1, 4, 11]), height=3, width=4)
    # index 11 = row 2, col 3 -> ((3 + 0.5) / 4, (2 + 0.5) / 3)
    np.testing.assert_allclose(xy.numpy(), [[0.125, 1 / 6], [0.375, 1 / 6], [0.125, 0.5], [0.875, 2.5 / 3]], rtol=1e-6)
    np.testing.assert_array_equal(grid_xy(torch.arange(3), 3, 4).numpy(), pixel_xy(torch.arange(12), 3, 4).numpy())


# --- PSNR and rendering ---------------------------------------------------------------


def test_psnr_formula():
    assert psnr_from_mse(1.0) == 0.0
    assert psnr_from_mse(0.01) == pytest.approx(20.0)
    assert psnr_from_mse(1e-3) == pytest.approx(30.0)
    assert psnr_from_mse(0.0) == math.inf
    # A uniform error of 0.1 everywhere is MSE 0.01, i.e. 20 dB.
    a = smooth_image(8, 8)
    assert psnr_from_mse(float(np.mean((a - (a + 0.1)) ** 2))) == pytest.approx(20.0, abs=1e-4)


def test_render_in_chunks_matches_one_pass_and_its_mse():
    torch.manual_seed(0)
    m = ImageField(L=3, width=16, depth=1)
    target = smooth_image(9, 13)
    whole, _ = render_image(m, 9, 13, chunk=10_000)
    rows, mse = render_image(m, 9, 13, chunk=5, target=target)  # one row (13 px) per chunk
    np.testing.assert_allclose(rows, whole, atol=1e-6)
    assert mse == pytest.approx(float(np.mean((whole.astype(np.float64) - target) ** 2)), rel=1e-6)
    with torch.no_grad():
        direct = m(pixel_xy(torch.arange(9 * 13), 9, 13)).reshape(9, 13, 3).numpy()
    np.testing.assert_allclose(whole, direct, atol=1e-6)


# --- fitting --------------------------------------------------------------------------


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_short_fit_beats_constant_colour_by_far(precision):
    target = smooth_image()
    # The best constant colour is the per-channel mean; its PSNR is what a broken model reaches.
    constant_psnr = psnr_from_mse(float(np.mean((target - target.mean(axis=(0, 1))) ** 2)))
    result = fit_image(target, dataclasses.replace(TINY, precision=precision), progress=False)
    assert constant_psnr < 16
    assert result.final_psnr > 30.0
    assert result.final_psnr > constant_psnr + 15
    # The reported PSNR is the PSNR of the returned image, on every pixel.
    mse = float(np.mean((result.final_image.astype(np.float64) - target) ** 2))
    assert result.final_psnr == pytest.approx(psnr_from_mse(mse), abs=1e-6)
    # The curve starts near the constant-colour level and rises.
    assert result.curve_steps[0] == 0 and result.curve_steps[-1] == TINY.steps
    assert result.curve_psnr[-1] > result.curve_psnr[0] + 10
    assert [s for s, _, _ in result.progression] == [0, 50, TINY.steps]


def test_same_seed_same_result_other_seed_differs():
    target = smooth_image(16, 16)
    cfg = dataclasses.replace(TINY, steps=40, eval_every=20)
    a = fit_image(target, cfg, progress=False)
    b = fit_image(target, cfg, progress=False)
    c = fit_image(target, dataclasses.replace(cfg, seed=1), progress=False)
    assert a.final_psnr == b.final_psnr
    np.testing.assert_array_equal(a.final_image, b.final_image)
    assert a.curve_psnr == b.curve_psnr
    assert c.final_psnr != a.final_psnr


def test_big_image_path_subsamples_curve_and_previews_but_final_uses_every_pixel():
    target = smooth_image(40, 60)
    cfg = dataclasses.replace(TINY, steps=30, eval_every=10, eval_pixels=500, preview_size=20, chunk=128)
    r = fit_image(target, cfg, progress=False)
    assert "500" in r.eval_note and "2,400" in r.eval_note
    assert r.final_image.shape == (40, 60, 3)
    assert all(img.shape == (13, 20, 3) for _, img, _ in r.progression)
    mse = float(np.mean((r.final_image.astype(np.float64) - target) ** 2))
    assert r.final_psnr == pytest.approx(psnr_from_mse(mse), abs=1e-6)
    # The subset estimate is close to the every-pixel value for a smooth error.
    assert abs(r.curve_psnr[-1] - r.final_psnr) < 1.0


# --- files and figures ----------------------------------------------------------------


def test_run_writes_figures_metrics_and_config(tmp_path):
    img = save_png(tmp_path / "pattern.png", smooth_image(24, 40))
    cfg = dataclasses.replace(TINY, steps=60, eval_every=20, progress_steps="0,20")
    r = run_fit(img, tmp_path / "run", cfg, progress=False)
    out = tmp_path / "run"
    assert decode(out / "final.png").shape == (24, 40, 3)
    for name in ("psnr.png", "progression.png"):
        fig = decode(out / name)
        assert fig.ndim == 3 and fig.shape[0] > 200 and fig.shape[1] > 300
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["final_psnr_db"] == pytest.approx(r.final_psnr)
    assert metrics["curve"]["step"] == [0, 20, 40, 60] and len(metrics["curve"]["psnr_db"]) == 4
    config = json.loads((out / "config.json").read_text())
    assert config["L"] == 4 and config["width"] == 64 and config["image"].endswith("pattern.png")


def test_ctrl_c_keeps_what_was_fitted(tmp_path, monkeypatch, capsys):
    """Ctrl-C during a 60-step fit: the run folder holds the fit of the steps done (its curve and
    progression end there, its config says so) and the command exits 130; before any step,
    nothing is written."""
    import nerfkit.fit_image as F

    img = save_png(tmp_path / "pattern.png", smooth_image(24, 40))
    real, calls = F.autocast, {"n": 0}

    def stops_at(step):
        def autocast(*args):
            calls["n"] += 1
            if calls["n"] == step:
                raise KeyboardInterrupt
            return real(*args)

        return autocast

    monkeypatch.setattr(F, "autocast", stops_at(37))
    argv = ["fit-image", str(img), "--steps", "60", "--eval-every", "20", "--progress-steps", "0,20"]
    assert main([*argv, "--L", "4", "--width", "32", "--out", str(tmp_path / "run"), "--quiet"]) == 130
    said = re.search(r"interrupted at step (\d+): what was fitted is written", capsys.readouterr().out)
    assert said is not None
    done = int(said.group(1))  # (autocast also wraps the evaluations: fewer steps than calls)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert 20 < done < 37 and metrics["curve"]["step"] == [0, 20, done] and metrics["final_psnr_db"] > 15
    assert json.loads((tmp_path / "run" / "config.json").read_text())["steps"] == done
    calls["n"] = 0
    monkeypatch.setattr(F, "autocast", stops_at(1))
    assert main([*argv, "--out", str(tmp_path / "none"), "--quiet"]) == 130
    assert not (tmp_path / "none").exists()


def test_ctrl_c_stops_a_sweep_after_writing_the_run_it_interrupted(tmp_path, monkeypatch):
    import nerfkit.fit_image as F

    img = save_png(tmp_path / "pattern.png", smooth_image(16, 16))
    real, calls = F.autocast, {"n": 0}

    def autocast(*args):
        calls["n"] += 1
        if calls["n"] == 12:  # in the first run's training steps
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(F, "autocast", autocast)
    cfg = dataclasses.replace(TINY, steps=30, eval_every=10, progress_steps="0")
    with pytest.raises(KeyboardInterrupt):
        run_sweep(img, tmp_path / "sweep", cfg, parse_sweep(["width=16,32"]), progress=False)
    runs = json.loads((tmp_path / "sweep" / "sweep.json").read_text())["runs"]
    assert [r["width"] for r in runs] == [16]  # the second run never started
    config = json.loads((tmp_path / "sweep" / runs[0]["folder"] / "config.json").read_text())
    assert 0 < config["steps"] < 30


@pytest.mark.slow
def test_sweep_writes_grid_curves_and_one_entry_per_combination(tmp_path):
    img = save_png(tmp_path / "pattern.png", smooth_image(16, 16))
    combos = parse_sweep(["L=0,4", "width=16,32"])
    cfg = dataclasses.replace(TINY, steps=30, eval_every=10, progress_steps="0")
    entries = run_sweep(img, tmp_path / "sweep", cfg, combos, progress=False)
    out = tmp_path / "sweep"
    grid, curves = decode(out / "sweep_grid.png"), decode(out / "sweep_psnr.png")
    assert grid.shape[0] > 200 and grid.shape[1] > 500  # 5 tiles (original + 4 runs)
    assert curves.shape[0] > 200 and curves.shape[1] > 300
    summary = json.loads((out / "sweep.json").read_text())
    runs = summary["runs"]
    assert json.loads(json.dumps(entries)) == runs
    assert [(e["L"], e["width"]) for e in runs] == [(0, 16), (0, 32), (4, 16), (4, 32)]
    assert all(math.isfinite(e["final_psnr_db"]) and e["final_psnr_db"] > 5 for e in runs)
    for e in runs:
        assert (out / e["folder"] / "final.png").is_file()
        assert json.loads((out / e["folder"] / "config.json").read_text())["width"] == e["width"]


def test_parse_sweep_and_background():
    assert parse_sweep(["L=3,10", "lr=1e-2,0.001"]) == [
        {"L": 3, "lr": 0.01},
        {"L": 3, "lr": 0.001},
        {"L": 10, "lr": 0.01},
        {"L": 10, "lr": 0.001},
    ]
    for bad, message in (
        (["seed=1,2"], "--sweep: cannot sweep 'seed'"),
        (["L"], "--sweep: cannot read 'L'"),
        (["L=a"], "--sweep L=a: 'a' is not a whole number"),
        (["L=1", "L=2"], "--sweep: 'L' is given twice"),
        (["L=3,3"], "--sweep: L=3 is given twice"),
        (["lr=0.001,0.0010000001"], "--sweep: lr=0.001 is given twice .or as values that print alike."),
        ([], "--sweep: no KEY=V1,V2 items"),
    ):
        with pytest.raises(NerfkitError, match=message):
            parse_sweep(bad)
    assert parse_background("white") == (1.0, 1.0, 1.0)
    assert parse_background("#ff0080") == pytest.approx((1.0, 0.0, 128 / 255))
    assert parse_background("0,0.5,1") == (0.0, 0.5, 1.0)
    with pytest.raises(NerfkitError, match="--background"):
        parse_background("sky")


# --- the images people have -----------------------------------------------------------


def test_rgba_is_composited_on_the_background(tmp_path):
    rgba = np.zeros((8, 8, 4), np.uint8)
    rgba[:, :4] = (0, 255, 0, 255)  # opaque green left half, transparent right half
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    img, _ = load_target(tmp_path / "a.png", "1,0,0")
    np.testing.assert_allclose(img[:, :4], np.broadcast_to([0, 1, 0], (8, 4, 3)))
    np.testing.assert_allclose(img[:, 4:], np.broadcast_to([1, 0, 0], (8, 4, 3)))


def test_16bit_greyscale_keeps_precision(tmp_path):
    values = np.array([[0, 1000, 1001, 65535]], np.uint16).repeat(3, axis=0)
    Image.fromarray(values).save(tmp_path / "g16.png")
    img, _ = load_target(tmp_path / "g16.png", "black")
    assert img.shape == (3, 4, 3)
    np.testing.assert_allclose(img[0, :, 0], values[0] / 65535.0, atol=1e-6)
    assert img[0, 2, 0] > img[0, 1, 0]  # 1000 and 1001 stay distinct (8-bit would merge them)
    np.testing.assert_array_equal(img[..., 0], img[..., 2])


def test_16bit_colour_keeps_precision_and_its_transparency(tmp_path):
    import cv2

    rgb = np.array([[[0, 1000, 65535], [1001, 30000, 7]]], np.uint16)
    cv2.imwrite(str(tmp_path / "c16.png"), rgb[..., ::-1])  # (OpenCV writes BGR)
    img, _ = load_target(tmp_path / "c16.png", "black")
    np.testing.assert_allclose(img, rgb / 65535.0, atol=1e-6)  # 1000 and 1001 stay apart (8 bits: 3 and 3)
    rgba = np.concatenate([rgb, np.array([[[65535], [0]]], np.uint16)], -1)
    cv2.imwrite(str(tmp_path / "c16a.tif"), rgba[..., [2, 1, 0, 3]])
    img, _ = load_target(tmp_path / "c16a.tif", "1,1,1")
    np.testing.assert_allclose(img[0, 0], rgb[0, 0] / 65535.0, atol=1e-6)
    np.testing.assert_allclose(img[0, 1], [1, 1, 1], atol=1e-6)  # transparent: the background


def test_a_floating_point_tiff_is_refused_as_such(tmp_path):
    import cv2

    from nerfkit.errors import NerfkitError

    cv2.imwrite(str(tmp_path / "f.tif"), np.full((4, 6, 3), 0.5, np.float32))
    with pytest.raises(NerfkitError, match=r"f.tif: a TIFF whose samples nerfkit cannot read \(floating-point"):
        load_target(tmp_path / "f.tif", "black")
    (tmp_path / "t.tif").write_text("not an image")
    with pytest.raises(NerfkitError, match="t.tif: not an image nerfkit can read"):
        load_target(tmp_path / "t.tif", "black")


def test_exif_rotated_jpeg_is_fitted_upright(tmp_path):
    stored = np.zeros((10, 20, 3), np.uint8)  # landscape as stored
    stored[:, :10] = 255
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 CW to view": the photo is portrait
    Image.fromarray(stored).save(tmp_path / "phone.jpg", exif=exif, quality=95)
    img, _ = load_target(tmp_path / "phone.jpg", "black")
    assert img.shape == (20, 10, 3)
    assert img[:8].mean() > 0.9 and img[12:].mean() < 0.1  # white half on top after rotation
    r = run_fit(tmp_path / "phone.jpg", tmp_path / "run", dataclasses.replace(TINY, steps=5), progress=False)
    assert decode(tmp_path / "run" / "final.png").shape == (20, 10, 3) and r.height == 20


def test_default_image_is_shipped_small_and_licensed():
    path = default_image_path()
    assert path.is_file() and path.stat().st_size < 300_000
    img, _ = load_target(None, "white")
    assert img.shape == (512, 512, 3) and 0.2 < img.mean() < 0.8
    note = (path.parent / "README.md").read_text()
    assert "astronaut.jpg" in note and "public domain" in note.lower()


# --- the command line -----------------------------------------------------------------


@pytest.mark.slow
def test_cli_runs_and_sweeps(tmp_path, capsys):
    img = save_png(tmp_path / "p.png", smooth_image(12, 12))
    small = [
        "--L",
        "2",
        "--width",
        "16",
        "--depth",
        "1",
        "--batch",
        "64",
        "--steps",
        "10",
        "--quiet",
        "--precision",
        "fp32",
    ]
    assert main(["fit-image", str(img), "--out", str(tmp_path / "one"), *small]) == 0
    assert (tmp_path / "one" / "metrics.json").is_file()
    assert "final PSNR" in capsys.readouterr().out
    # The image may also follow --sweep's items.
    assert main(["fit-image", "--out", str(tmp_path / "sw"), *small, "--sweep", "L=0,2", str(img)]) == 0
    assert len(json.loads((tmp_path / "sw" / "sweep.json").read_text())["runs"]) == 2
    # a sweep's run folders are outputs too: an earlier run there, or the image itself, is kept
    assert main(["fit-image", str(img), "--out", str(tmp_path / "sw2" / "L2"), *small]) == 0
    before = (tmp_path / "sw2" / "L2" / "final.png").read_bytes()
    capsys.readouterr()
    assert main(["fit-image", str(img), "--out", str(tmp_path / "sw2"), *small, "--sweep", "L=2"]) == 2
    assert "L2/psnr.png: already exists" in capsys.readouterr().err
    inside = tmp_path / "sw3" / "L2" / "final.png"
    inside.parent.mkdir(parents=True)
    inside.write_bytes(img.read_bytes())
    assert main(["fit-image", str(inside), "--out", str(tmp_path / "sw3"), *small, "--sweep", "L=2", "--force"]) == 2
    assert "is an input of this command" in capsys.readouterr().err
    assert (tmp_path / "sw2" / "L2" / "final.png").read_bytes() == before and inside.read_bytes() == img.read_bytes()


@pytest.mark.parametrize("content,expect", [(b"this is not an image", "not an image"), (b"", "not an image")])
def test_cli_non_image_file_exits_2_with_one_line(tmp_path, capsys, content, expect):
    bad = tmp_path / "notes.png"
    bad.write_bytes(content)
    assert main(["fit-image", str(bad), "--out", str(tmp_path / "r"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "notes.png" in err and expect in err and "Traceback" not in err and len(err.splitlines()) == 1
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    "item, message",
    [
        ("L=3,100", "--sweep L=3,100: 100 is above the maximum 30 (allowed: 0 to 30)"),
        ("lr=0.01,inf", "--sweep lr=0.01,inf: 'inf' is not a finite number"),
        ("batch=0,64", "--sweep batch=0,64: 0 is below the minimum 1 (allowed: 1 to 16777216)"),
        ("depth=2,x", "--sweep depth=2,x: 'x' is not a whole number"),
    ],
)
def test_sweep_values_keep_the_bounds_of_their_flags(item, message):
    with pytest.raises(NerfkitError) as e:
        parse_sweep(["width=16,32", item])
    assert str(e.value) == message


def test_cli_sweep_out_of_bounds_is_refused_as_the_flag_is(tmp_path, capsys):
    # --sweep L=100 once trained with 100 octaves, which --L 100 refuses
    assert main(["fit-image", "--L", "100", "--out", str(tmp_path / "r"), "--quiet"]) == 2
    flag_err = capsys.readouterr().err.strip()
    assert main(["fit-image", "--sweep", "L=100", "--out", str(tmp_path / "r"), "--quiet"]) == 2
    sweep_err = capsys.readouterr().err.strip()
    problem = "100 is above the maximum 30 (allowed: 0 to 30)"
    assert flag_err == f"nerfkit fit-image: error: argument --L: {problem} (see nerfkit fit-image --help)"
    assert sweep_err == f"nerfkit fit-image: error: --sweep L=100: {problem}"
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    "argv,expect",
    [
        (["missing.jpg"], "no such file"),
        (["--width", "0"], "--width"),
        (["--lr", "-1"], "--lr"),
        (["--progress-steps", "a,b"], "--progress-steps"),
        (["--background", "sky"], "--background"),
        (["--sweep", "seed=1,2"], "cannot sweep"),
    ],
)
def test_cli_bad_input_exits_2(tmp_path, capsys, argv, expect):
    argv = [a.replace("missing.jpg", str(tmp_path / "missing.jpg")) for a in argv]
    assert main(["fit-image", *argv, "--out", str(tmp_path / "r"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert expect in err and len(err.splitlines()) == 1


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the no-GPU message")
def test_cli_cuda_without_gpu_exits_2(tmp_path, capsys):
    img = save_png(tmp_path / "p.png", smooth_image(8, 8))
    assert main(["fit-image", str(img), "--device", "cuda", "--out", str(tmp_path / "r"), "--quiet"]) == 2
    assert "CUDA" in capsys.readouterr().err
