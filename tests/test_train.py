"""Training, checkpoints, resume, rendering and evaluation on a tiny generated scene."""

from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from conftest import tiny_vanilla
from nerfkit import presets
from nerfkit.cli import main
from nerfkit.models.base import SceneBounds
from nerfkit.models.vanilla import VanillaConfig, VanillaNeRF
from nerfkit.train.config import TrainConfig
from nerfkit.train.reports import validation_series
from nerfkit.train.trainer import Trainer, resume, train

SMALL = dict(n_samples=16, width=32, depth=4)


def small_cfg(tmp_path, name="run", **kw):
    base = dict(
        data="sphere",
        model="vanilla",
        out=str(tmp_path / name),
        steps=300,
        batch_rays=256,
        lr=3e-3,
        seed=0,
        eval_views=1,
        checkpoint_seconds=1e9,
    )
    base.update(kw)
    return presets.without_scene(TrainConfig(**base))  # the model's training settings, as train() resolves them


def background_psnr(scene) -> float:
    """PSNR of rendering nothing but the black background on the validation views."""
    img = scene.val.images.astype(np.float64) / 255
    return -10 * np.log10(np.mean(img**2))


@pytest.mark.slow
def test_training_rises_well_above_the_empty_render(tmp_path, sphere):
    result = train(sphere, small_cfg(tmp_path), VanillaConfig(**SMALL), quiet=True)
    val = [r for r in result.rows if r["split"] == "val"]
    assert val[0]["step"] == 0 and val[-1]["step"] == 300
    baseline = background_psnr(sphere)
    assert val[-1]["psnr"] > baseline + 4.0, (baseline, val)
    assert val[-1]["psnr"] > val[0]["psnr"] + 4.0
    run = tmp_path / "run"
    for f in ["config.json", "metrics.csv", "metrics.json", "plots/psnr.png", "plots/loss.png", "plots/progress.png"]:
        assert (run / f).exists(), f
    assert iio.imread(run / "plots" / "psnr.png").ndim == 3
    rows = json.loads((run / "metrics.json").read_text())["rows"]
    assert [r["step"] for r in rows if r["split"] == "train"] == list(range(10, 301, 10))


def test_default_init_leaves_the_dead_zone(sphere):
    """The robust default gives every sample positive density at init; the course's zero
    bias can give none (ReLU then passes no gradient)."""
    torch.manual_seed(0)
    bounds = SceneBounds.from_scene(sphere)
    model = VanillaNeRF(VanillaConfig(), bounds)
    pts = torch.rand(4096, 3) * 4 - 2
    dirs = torch.nn.functional.normalize(torch.randn(4096, 3), dim=-1)
    sigma, rgb = model.query(pts, dirs)
    assert (sigma > 0).float().mean() > 0.99
    # with the dead init forced (bias very negative) no sample has density and no gradient flows
    dead = VanillaNeRF(VanillaConfig(density_bias_init=-10.0), bounds)
    sigma_dead, _ = dead.query(pts, dirs)
    sigma_dead.sum().backward()
    assert torch.all(sigma_dead == 0)
    assert all(
        p.grad is None or torch.all(p.grad == 0)
        for n, p in dead.coarse.named_parameters()
        if "color" not in n and "feature" not in n
    )


@pytest.mark.slow
def test_hierarchical_sampling_trains(tmp_path, sphere):
    result = train(
        sphere,
        small_cfg(tmp_path, steps=250),
        VanillaConfig(n_samples=8, n_importance=8, width=32, depth=4),
        quiet=True,
    )
    val = [r for r in result.rows if r["split"] == "val"]
    assert val[-1]["psnr"] > background_psnr(sphere) + 2.0


@pytest.mark.slow
def test_resume_continues_exactly(tmp_path, sphere):
    """Stopping at step 60 and resuming to 120 gives the same model as 120 steps straight."""
    straight = train(sphere, small_cfg(tmp_path, "a", steps=120, eval_every=60), VanillaConfig(**SMALL), quiet=True)
    cfg_b = small_cfg(tmp_path, "b", steps=120, eval_every=60)
    first = Trainer(sphere, cfg_b, VanillaConfig(**SMALL), quiet=True).run(stop_after=60)
    assert first.step == 60
    resumed = resume(tmp_path / "b", sphere, quiet=True)
    assert resumed.step == 120
    a = torch.load(tmp_path / "a" / "checkpoints" / "step_00000120.pt", weights_only=True)
    b = torch.load(tmp_path / "b" / "checkpoints" / "step_00000120.pt", weights_only=True)
    for k in a["model"]:
        torch.testing.assert_close(a["model"][k], b["model"][k], rtol=1e-4, atol=1e-5)
    steps_a = [(r["step"], r["split"]) for r in straight.rows]
    steps_b = [(r["step"], r["split"]) for r in resumed.rows]
    assert steps_a == steps_b  # no duplicated or missing rows


def test_resume_goes_on_in_the_precision_auto_chose_where_the_run_started(tmp_path, sphere, monkeypatch, capsys):
    import nerfkit.precision

    tiny = VanillaConfig(n_samples=4, width=8, depth=2)
    native = {"bf16": False}
    monkeypatch.setattr(nerfkit.precision, "cpu_has_native_bf16", lambda: native["bf16"])
    for started, moved in ((False, True), (True, False)):
        name = f"started_{started}"
        native["bf16"] = started
        cfg = small_cfg(tmp_path, name, steps=6, batch_rays=32, eval_views=0, device="cpu", precision="auto")
        first = Trainer(sphere, cfg, tiny, quiet=True)
        assert first.autocast == (torch.bfloat16 if started else None)
        first.run(stop_after=3)
        native["bf16"] = moved  # resumed on another machine
        capsys.readouterr()
        again = Trainer(sphere, cfg, tiny, resume=True, quiet=True)
        err = capsys.readouterr().err
        assert again.step == 3 and again.autocast is None  # fp32: as trained, or as this CPU can
        assert ("trained in bf16, which this cpu does not do natively" in err) == started, err
        assert len(err.strip().splitlines()) == int(started)


def test_resume_refuses_steps_below_the_step_reached_and_ends_at_it_with_the_final_evaluation(tmp_path, sphere):
    from nerfkit.errors import NerfkitError

    tiny = VanillaConfig(n_samples=4, width=8, depth=2)
    cfg = small_cfg(tmp_path, "r", steps=10, batch_rays=32, eval_every=1)
    Trainer(sphere, cfg, tiny, quiet=True).run(stop_after=5)
    with pytest.raises(NerfkitError, match=r"--steps: 3 is below step 5, which run .* has reached.*Pass --steps 5"):
        resume(tmp_path / "r", sphere, steps=3, quiet=True)
    ended = resume(tmp_path / "r", sphere, steps=5, quiet=True)
    metrics = json.loads((tmp_path / "r" / "metrics.json").read_text())
    last = metrics["rows"][-1]
    assert metrics["finished"] and ended.step == 5
    assert (last["split"], last["step"], last["views"]) == ("val", 5, len(sphere.val))  # every view, not one
    assert ended.final_val_psnr == last["psnr"]


def test_a_resumed_run_writes_the_metrics_rows_of_a_straight_one(tmp_path, sphere):
    """Stopped at step 15, between two train rows: the row at step 20 still averages the PSNR of
    steps 11 to 20 (the window is in the checkpoint)."""
    tiny = VanillaConfig(n_samples=4, width=8, depth=2)

    def trainer(name):
        return Trainer(sphere, small_cfg(tmp_path, name, steps=30, batch_rays=32, eval_views=0), tiny, quiet=True)

    straight = trainer("a").run()
    trainer("b").run(stop_after=15)
    resumed = resume(tmp_path / "b", sphere, quiet=True)
    rows = [[(r["step"], r["split"], r["psnr"]) for r in run.rows] for run in (straight, resumed)]
    assert [r[:2] for r in rows[0]] == [r[:2] for r in rows[1]]
    assert [r[2] for r in rows[1]] == pytest.approx([r[2] for r in rows[0]], abs=1e-4)


@pytest.mark.slow
def test_resume_keeps_the_default_validation_marks(tmp_path, sphere):
    """Resumed at step 60 of 120, a run validates at the steps a straight run does, no more."""
    straight = train(sphere, small_cfg(tmp_path, "a", steps=120), VanillaConfig(**SMALL), quiet=True)
    assert (
        Trainer(sphere, small_cfg(tmp_path, "b", steps=120), VanillaConfig(**SMALL), quiet=True).run(stop_after=60).step
        == 60
    )
    resumed = resume(tmp_path / "b", sphere, quiet=True)
    val_steps = [(r["step"], r["views"]) for r in straight.rows if r["split"] == "val"]
    n_val = len(sphere.val)  # the last step twice: its periodic view again, then every view
    assert val_steps == [(s, 1) for s in [0, 2, 4] + list(range(12, 121, 12))] + [(120, n_val)]
    assert [(r["step"], r["views"]) for r in resumed.rows if r["split"] == "val"] == val_steps


def test_validation_marks_without_eval_every(tmp_path, sphere):
    """Val renders at 1% and 3% of the run and at each tenth, by steps or by the time budget."""
    by_steps = Trainer(sphere, small_cfg(tmp_path, "a", steps=200), VanillaConfig(**SMALL), quiet=True)
    due = []
    for step in range(1, 201):
        by_steps.step = step
        if by_steps._eval_due():
            due.append(step)
    assert due == [2, 6] + list(range(20, 201, 20))
    by_time = Trainer(sphere, small_cfg(tmp_path, "b", steps=0, minutes=1.0), VanillaConfig(**SMALL), quiet=True)
    due = []
    for tick in range(1, 601):  # a tenth of a second a step
        by_time.train_seconds = tick / 10
        if by_time._eval_due():
            due.append(tick)
    assert due == [6, 18] + list(range(60, 601, 60))


@pytest.mark.slow
def test_refuses_to_overwrite_a_run(tmp_path, sphere):
    cfg = small_cfg(tmp_path, steps=2)
    train(sphere, cfg, VanillaConfig(**SMALL), quiet=True)
    from nerfkit.errors import NerfkitError

    with pytest.raises(NerfkitError, match="already holds a run"):
        train(sphere, cfg, VanillaConfig(**SMALL), quiet=True)


@pytest.mark.slow
def test_cli_train_render_eval(tmp_path, sphere_npz, capsys):
    run = tmp_path / "cli_run"
    code = main(
        [
            "train",
            "--data",
            str(sphere_npz),
            "--model",
            "vanilla",
            "--out",
            str(run),
            "--steps",
            "20",
            "--batch-rays",
            "128",
            "--n-samples",
            "8",
            "--width",
            "16",
            "--depth",
            "2",
            "--lr",
            "2e-3",
        ]
    )
    assert code == 0
    assert main(["render", str(run), "--path", "spiral", "--out", str(tmp_path / "spiral")]) == 2
    assert "--path spiral: the training cameras do not all look the same way" in capsys.readouterr().err
    assert not (tmp_path / "spiral").exists()
    assert main(["render", str(run), "--path", "orbit", "--frames", "4"]) == 0
    for name in ["orbit.mp4", "orbit.gif", "depth.mp4"]:
        assert (run / "videos" / name).stat().st_size > 0
    gif = iio.imread(run / "videos" / "orbit.gif")
    assert gif.shape == (4, 32, 32, 3)
    # each depth frame carries its scale below it: the bar starts warm (red) at its near end
    depth = iio.imread(run / "videos" / "depth.mp4")
    assert depth.shape[:3] == (4, 32 + 24, 32) and depth[0, 34, 0, 0] > 2 * depth[0, 34, 0, 2]
    capsys.readouterr()
    # the object alone: a model that draws nothing around its object is only framed
    assert main(["render", str(run), "--object", "--frames", "4"]) == 0
    assert "of the object (the model draws nothing around it to leave out; zoomed" in capsys.readouterr().out
    assert iio.imread(run / "videos" / "object.gif").shape == (4, 32, 32, 3)
    assert (run / "videos" / "object_depth.mp4").stat().st_size > 0
    assert main(["eval", str(run), "--split", "val", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_images"] == 2 and len(out["per_image"]) == 2
    assert np.isclose(out["psnr"], np.mean([p["psnr"] for p in out["per_image"]]), atol=1e-3)
    assert 0 < out["ssim"] <= 1
    assert json.loads((run / "eval_val.json").read_text())["psnr"] == out["psnr"]
    assert main(["eval", str(run), "--split", "val"]) == 0  # the summary
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == f"val: 2 views at step 20: PSNR {out['psnr']:.2f} dB, SSIM {out['ssim']:.3f}"
    assert printed[-1] == f"wrote {run / 'eval_val.json'} and {run / 'eval_val.png'} (photo beside render)"


def test_eval_summary_lists_the_fitted_scores_and_the_extreme_views():
    from nerfkit.commands.eval import LISTED_VIEWS, summary

    views = [
        {"index": i, "name": f"IMG_{i}.jpg", "psnr": 20.0 + (i * 7) % 31, "ssim": 0.5, "psnr_fitted": 30.0}
        for i in range(31)
    ]
    result = {
        "split": "val",
        "n_images": 31,
        "step": 9,
        "psnr": 25.0,
        "ssim": 0.7,
        "per_image": views,
        "fitted": {"psnr": 27.5, "ssim": 0.75},
        "colour_only": {"psnr": 26.0},
        "object": {"psnr": 24.0, "psnr_fitted": 28.0},
    }
    lines = summary(result).splitlines()
    assert "and each half's colour solved on the other half: 27.50 dB / 0.750 (its colour alone: 26.00 dB)" in lines[1]
    assert lines[2] == "  the object's own pixels: 24.00 dB, 28.00 fitted"
    listed = [float(line.split()[1]) for line in lines[4:]]
    assert len(listed) == LISTED_VIEWS and listed == sorted(listed)
    all_psnr = sorted(v["psnr"] for v in views)
    assert listed == all_psnr[: LISTED_VIEWS // 2] + all_psnr[-(LISTED_VIEWS // 2) :]
    result["per_image"] = views[:3]  # few views: each, in the split's order
    assert [line.split()[0] for line in summary(result).splitlines()[4:]] == ["IMG_0.jpg", "IMG_1.jpg", "IMG_2.jpg"]


def test_cli_errors_are_one_line_with_exit_code_2(tmp_path, capsys):
    assert main(["train", "--data", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "r"), "--steps", "1"]) == 2
    err = capsys.readouterr().err
    assert "missing.npz" in err and "Traceback" not in err and err.count("\n") == 1
    assert main(["eval", str(tmp_path / "nope")]) == 2
    assert main(["eval", str(tmp_path)]) == 2
    assert "config.json" in capsys.readouterr().err
    assert main(["train", "--data", "x.npz", "--background", "purple", "--steps", "1"]) == 2


@pytest.mark.slow
def test_vanilla_occupancy_skipping_keeps_the_image_and_saves_samples(tmp_path, sphere):
    cfg = VanillaConfig(n_samples=32, width=32, depth=4, occupancy=True, occupancy_warmup=100, occupancy_every=50)
    train(sphere, small_cfg(tmp_path, steps=300), cfg, quiet=True)
    from nerfkit.output.images import render_image
    from nerfkit.train.checkpoint import load_run

    model, _, _ = load_run(tmp_path / "run")
    assert 0.02 < model.estimator.occupied_fraction < 0.5  # the sphere fills ~7% of its box
    v = sphere.val
    bg = torch.zeros(3)
    skipped = render_image(model, v.K[0], v.c2w[0], v.width, v.height, bg)
    estimator, model.estimator = model.estimator, None  # the same network, every sample evaluated
    full = render_image(model, v.K[0], v.c2w[0], v.width, v.height, bg)
    model.estimator = estimator
    # skipping drops only faint haze (alpha < 1% per sample): close images, no loss in accuracy
    from nerfkit.train.metrics import psnr

    target = v.images[0] / 255.0
    assert np.abs(skipped.rgb - full.rgb).mean() < 0.01
    assert psnr(skipped.rgb, target) > psnr(full.rgb, target) - 0.3
    from nerfkit.cameras import image_rays

    rays = image_rays(torch.from_numpy(v.K[0]), torch.from_numpy(v.c2w[0]), v.width, v.height)
    with torch.no_grad():
        assert model.render_rays(rays, bg, perturb=False).n_samples < 0.5 * len(rays) * 32


@pytest.mark.slow
def test_progress_bar_in_a_log_file_redraws_rarely(tmp_path, sphere_npz):
    # Not a terminal: the bar redraws every 30 s, not every step (a 5-minute run once wrote
    # thousands of redraws into its log). A 3-second run draws the start and the end only.
    import subprocess
    import sys

    log = tmp_path / "train.log"
    with open(log, "w") as f:
        code = subprocess.run(
            [
                sys.executable,
                "-m",
                "nerfkit.cli",
                "train",
                "--data",
                str(sphere_npz),
                "--out",
                str(tmp_path / "run"),
                "--minutes",
                "0.05",
                *tiny_vanilla(batch_rays=64, eval_every=1000000),
            ],
            stderr=f,
            stdout=f,
        ).returncode
    assert code == 0, log.read_text()[-2000:]
    text = log.read_text()
    steps = json.loads((tmp_path / "run" / "metrics.json").read_text())["step"]
    assert steps > 8  # (redrawn every step, the log would hold more than 4 bars)
    assert text.count("step/s") <= 4, text[-2000:]


def test_strided_camera_sees_every_kth_pixel():
    from nerfkit.cameras import image_rays, strided_camera

    K = torch.tensor([[40.0, 0.3, 18.2], [0.0, 42.0, 11.7], [0.0, 0.0, 1.0]])
    c2w = torch.eye(4)
    c2w[:3, 3] = torch.tensor([0.1, -0.2, 3.0])
    W, H = 37, 23
    full = image_rays(K, c2w, W, H)
    for s in (1, 2, 4, 7):
        Ks, w, h = strided_camera(K, W, H, s)
        sub = image_rays(Ks, c2w, w, h)
        expect = full.directions.reshape(H, W, 3)[::s, ::s].reshape(-1, 3)
        assert (w, h) == (len(range(0, W, s)), len(range(0, H, s)))
        assert torch.allclose(sub.directions, expect, atol=1e-6)
    Kn, _, _ = strided_camera(K.numpy(), W, H, 3)  # numpy in, numpy out, input untouched
    assert isinstance(Kn, np.ndarray) and float(K[0, 0]) == 40.0


@pytest.mark.parametrize("w,h,n,pixels", [(200, 200, 2, 4096), (37, 23, 3, 100), (32, 32, 1, 1 << 20), (5, 9, 4, 1)])
def test_eval_stride_is_the_smallest_within_budget(w, h, n, pixels):
    from nerfkit.train.config import eval_stride

    s = eval_stride(w, h, n, pixels)
    count = lambda k: n * -(-w // k) * -(-h // k)  # noqa: E731
    assert count(s) <= pixels or s == max(w, h)  # one pixel per view at the least
    assert s == 1 or count(s - 1) > pixels


def test_periodic_validation_cost_is_bounded_and_the_final_one_is_whole(tmp_path, sphere):
    cfg = small_cfg(tmp_path, steps=50, eval_views=2, eval_pixels=100)
    trainer = Trainer(sphere, cfg, VanillaConfig(n_samples=16, width=16, depth=2, occupancy=False), quiet=True)
    spent = []
    render = trainer.model.render_rays

    def counting(rays, background, perturb):
        out = render(rays, background, perturb)
        spent.append((len(rays), out.n_samples))
        return out

    trainer.model.render_rays = counting
    trainer._record_eval()  # step 0: periodic
    rays, samples = sum(r for r, _ in spent), sum(s for _, s in spent)
    assert 0 < rays <= 100 and samples <= 100 * 16  # field evaluations bounded by eval_pixels x n_samples
    periodic = trainer.rows[-1]
    assert periodic["views"] == 2 and periodic["pixels"] * 2 == rays
    # the score is the whole image's PSNR on that pixel subset: same pixels, same colours
    from nerfkit.output.images import render_image
    from nerfkit.train.config import eval_stride
    from nerfkit.train.metrics import psnr

    v = sphere.val
    whole = [
        render_image(
            trainer.model, v.K[i], v.c2w[i], v.width, v.height, trainer.background, autocast_dtype=trainer.autocast
        ).rgb
        for i in range(2)
    ]  # bf16 where the CPU has it
    s = eval_stride(v.width, v.height, 2, 100)
    assert len(range(0, v.width, s)) * len(range(0, v.height, s)) == periodic["pixels"]
    expect = np.mean([psnr(whole[i][::s, ::s], v.images[i][::s, ::s] / 255.0) for i in range(2)])
    assert abs(periodic["psnr"] - expect) < 1e-3
    spent.clear()
    trainer.step = cfg.steps  # done: the final evaluation scores every validation view whole
    trainer._record_eval()
    assert sum(r for r, _ in spent) == len(v) * v.width * v.height
    assert trainer.rows[-1]["pixels"] == v.width * v.height


@pytest.mark.slow
def test_the_periodic_validation_curve_ends_with_the_final_score_of_its_views(tmp_path, sphere):
    # Periodic evaluations of the first view, whole: at the end that view is scored again beside
    # every view, so its curve reaches the last step (steve's ended 20 s early at 21.6 dB, above
    # a lone final dot of 20.2 for all six views, and read as the score falling).
    from nerfkit.output.images import render_image
    from nerfkit.train.metrics import psnr

    v = sphere.val
    assert len(v) > 1
    trainer = Trainer(
        sphere,
        small_cfg(tmp_path, steps=20, eval_views=1, eval_pixels=10**7),
        VanillaConfig(n_samples=16, width=16, depth=2, occupancy=False),
        quiet=True,
    )
    result = trainer.run()
    val = [r for r in result.rows if r["split"] == "val"]
    first, every = val[-2], val[-1]
    assert first["step"] == every["step"] == 20 and first["views"] == 1 and every["views"] == len(v)
    assert first["pixels"] == every["pixels"] == v.width * v.height
    assert result.final_val_psnr == every["psnr"]
    scores = [
        psnr(
            render_image(
                trainer.model, v.K[i], v.c2w[i], v.width, v.height, trainer.background, autocast_dtype=trainer.autocast
            ).rgb,
            v.images[i] / 255.0,
        )
        for i in range(len(v))
    ]
    assert first["psnr"] == pytest.approx(scores[0], abs=1e-4)
    assert every["psnr"] == pytest.approx(np.mean(scores), abs=1e-4)
    curves = validation_series(val, len(v), v.width * v.height)
    assert list(curves) == [
        f"validation, first 1 of {len(v)} views, whole images",
        f"validation, all {len(v)} views, whole images",
    ]
    assert curves[f"validation, first 1 of {len(v)} views, whole images"][0][-1] == first["seconds"]


def test_the_psnr_plot_keeps_periodic_and_final_validation_apart():
    """Periodic scores (the first views, a pixel subset) and final ones (every view, whole)
    are different numbers; joined in one line, a run's last point looked like a collapse."""
    rows = [
        {"seconds": 0.0, "psnr": 11.0, "views": 2, "pixels": 300},
        {"seconds": 9.0, "psnr": 21.0, "views": 2, "pixels": 300},
        {"seconds": 10.0, "psnr": 19.5, "views": 6, "pixels": 4096},
        {"seconds": 20.0, "psnr": 21.5, "views": 2, "pixels": 300},  # resumed
        {"seconds": 30.0, "psnr": 20.0, "views": 6, "pixels": 4096},
    ]
    curves = validation_series(rows, 6, 4096)
    assert curves == {
        "validation, first 2 of 6 views, 300 px per view": ([0.0, 9.0, 20.0], [11.0, 21.0, 21.5]),
        "validation, all 6 views, whole images": ([10.0, 30.0], [19.5, 20.0]),
    }
    # --eval-views above the split's size: both are every view, and a whole-image score is one curve
    one = [
        {"seconds": 1.0, "psnr": 20.0, "views": 2, "pixels": 4096},
        {"seconds": 2.0, "psnr": 21.0, "views": 1, "pixels": 4096},
    ]
    assert validation_series(one, 1, 4096) == {"validation, all 1 view, whole images": ([1.0, 2.0], [20.0, 21.0])}
    # every view scored whole at every evaluation: one curve
    assert list(validation_series([{**r, "views": 6, "pixels": 4096} for r in rows], 6, 4096)) == [
        "validation, all 6 views, whole images"
    ]


@pytest.mark.slow
def test_a_run_ending_before_the_occupancy_warmup_measures_it_for_the_final_evaluation(tmp_path, sphere):
    cfg = small_cfg(tmp_path, steps=50, eval_views=1)
    trainer = Trainer(sphere, cfg, VanillaConfig(n_samples=16, width=16, depth=2, occupancy_res=16), quiet=True)
    model = trainer.model
    assert torch.isinf(model.estimator.cell_sigma).all()  # warm-up (200 steps) not reached
    for _ in range(20):
        trainer.train_step()
    rng = torch.get_rng_state()
    trainer.step = cfg.steps
    trainer._record_eval()  # the final evaluation
    assert torch.equal(torch.get_rng_state(), rng)  # training's random streams untouched
    assert torch.isfinite(model.estimator.cell_sigma).all() and model.estimator.occupied_fraction < 1.0
    measured = model.estimator.cell_sigma.clone()
    model.finish_training()  # once only
    assert torch.equal(model.estimator.cell_sigma, measured)


def test_schedules_run_in_their_phase_in_order_and_report_their_notes():
    from nerfkit.models.base import Schedule, StepState, run_schedules

    ran = []
    jobs = [
        Schedule("a", lambda s: s.step % 2 == 0, lambda s: ran.append(("a", s.step)) or "grew"),
        Schedule("b", lambda s: True, lambda s: ran.append(("b", s.step)), phase="after_step"),
        Schedule("c", lambda s: s.progress > 0.5, lambda s: ran.append(("c", s.step))),
    ]
    assert run_schedules(jobs, StepState(0, 0.0), phase="before_step") == ["grew"]
    assert run_schedules(jobs, StepState(0, 0.0), phase="after_step") == []
    assert run_schedules(jobs, StepState(1, 0.9), phase="before_step") == []
    assert ran == [("a", 0), ("b", 0), ("c", 1)]


@pytest.mark.parametrize("shape", [(1, 1), (2, 5), (4, 9), (6, 8), (24, 32)])
def test_ssim_scores_images_of_any_size(shape):
    # scikit-image's 11-pixel window refused images under 7 pixels a side: `eval` died on them
    from skimage.metrics import structural_similarity

    from nerfkit.train.metrics import ssim

    rng = np.random.default_rng(0)
    a = rng.uniform(0.2, 0.8, (*shape, 3))
    noisy = np.clip(a + rng.normal(0, 0.2, a.shape), 0, 1)
    assert ssim(a, a) == pytest.approx(1.0)
    assert ssim(a, noisy) < 0.99
    assert ssim(a, 1.0 - a) < ssim(a, noisy)  # inverted contrast scores worst
    if min(shape) >= 11:  # the usual case is scikit-image's Gaussian-window SSIM itself
        assert ssim(a, noisy) == pytest.approx(
            structural_similarity(
                a, noisy, channel_axis=-1, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False
            )
        )
