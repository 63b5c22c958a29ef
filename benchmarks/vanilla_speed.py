"""Seconds per training step and samples per second of the course NeRF, fp32 vs bf16.

Usage: python benchmarks/vanilla_speed.py [--batches 512,1024,4096] [--samples 64] [--repeats 5] [--render]
                                          [--run RUN]
Prints a table of medians over repeated steps (after one warm-up step) per batch size and
precision, and the bf16 speed-up. With ``--run`` (a trained vanilla run folder), also times
empty-space skipping (``--occupancy``) on the trained weights: the share of samples the MLP
still evaluates, s/step and s/frame, with and without.
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import statistics
import time
from datetime import date
from pathlib import Path

import numpy as np
import torch

from nerfkit.data.npz import load_npz
from nerfkit.data.rays import RaysData
from nerfkit.models.base import SceneBounds
from nerfkit.models.vanilla import VanillaConfig, VanillaNeRF
from nerfkit.output.images import render_image
from nerfkit.train.checkpoint import load_run
from nerfkit.train.metrics import psnr
from nerfkit.train.optim import build_optimizer


def step_times(model, rays, batch, autocast, repeats):
    opt = build_optimizer(model, 5e-4)
    bg = torch.zeros(3)
    times = []
    for i in range(repeats + 1):
        b = rays.sample(batch)
        t0 = time.perf_counter()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
            out = model.render_rays(b.rays, bg, perturb=True)
            loss = model.loss(out, b.rgb)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if i:  # the first step warms up the kernels
            times.append(time.perf_counter() - t0)
    return statistics.median(times), out.n_samples


def render_seconds(model, scene, autocast):
    t0 = time.perf_counter()
    view = render_image(
        model,
        scene.val.K[0],
        scene.val.c2w[0],
        scene.val.width,
        scene.val.height,
        torch.zeros(3),
        4096,
        torch.bfloat16 if autocast else None,
    )
    return time.perf_counter() - t0, view


def speed_table(scene, rays, batches, samples, repeats, render):
    print(f"# batch rays x {samples} samples, median of {repeats} steps")
    print("| batch rays | precision | s/step | samples/s | render s/frame |")
    print("|---:|---|---:|---:|---:|")
    for batch in batches:
        results = {}
        for name, autocast in [("fp32", False), ("bf16", True)]:
            torch.manual_seed(0)
            model = VanillaNeRF(VanillaConfig(n_samples=samples), SceneBounds.from_scene(scene))
            sec, n = step_times(model, rays, batch, autocast, repeats)
            frame = f"{render_seconds(model, scene, autocast)[0]:.1f}" if render else "-"
            results[name] = sec
            print(f"| {batch} | {name} | {sec:.3f} | {n / sec / 1e6:.3f} M | {frame} |")
        print(f"| {batch} | bf16 speed-up | {results['fp32'] / results['bf16']:.2f}x | | |")


def occupancy_table(run, scene, rays, batch, repeats):
    """Trained weights, with and without empty-space skipping (same MLP, same samples)."""
    loaded, info, step = load_run(run)
    if info.train.model != "vanilla":
        raise SystemExit(f"{run} is a {info.train.model} run; --run needs a vanilla run")
    plain = VanillaNeRF(dataclasses.replace(info.model_config, occupancy=False), info.bounds)
    plain.load_state_dict(loaded.state_dict(), strict=False)  # the same MLP, every sample evaluated
    cfg = dataclasses.replace(info.model_config, occupancy=True)
    if info.model_config.occupancy:
        skip = loaded  # the grid the run trained with
    else:
        skip = VanillaNeRF(cfg, info.bounds)
        skip.load_state_dict(loaded.state_dict(), strict=False)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            for _ in range(3):  # a few refreshes: the running max settles
                skip.update_occupancy()
    occupied = skip.estimator.occupied_fraction
    print(
        f"\n# trained run {run} (step {step}), bf16, batch {batch}; occupancy grid {cfg.occupancy_res}^3, "
        f"{occupied:.1%} of cells occupied"
    )
    print("| occupancy | samples evaluated per ray | s/step | render s/frame | val[0] PSNR |")
    print("|---|---:|---:|---:|---:|")
    rows = {}
    for name, model in [("off", plain), ("on", skip)]:
        model.train()
        sec, n = step_times(model, rays, batch, True, repeats)
        model.eval()
        frame, view = render_seconds(model, scene, True)
        score = psnr(view.rgb, scene.val.images[0].astype(np.float32) / 255.0)
        rows[name] = (sec, frame)
        print(f"| {name} | {n / batch:.1f} | {sec:.3f} | {frame:.2f} | {score:.2f} |")
    print(f"| speed-up | | {rows['off'][0] / rows['on'][0]:.2f}x | {rows['off'][1] / rows['on'][1]:.2f}x | |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1] / "src/nerfkit/assets/lego_200x200.npz"))
    ap.add_argument("--batches", default="1024", help="comma-separated rays per step (default: 1024)")
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--render", action="store_true", help="also time one full 200x200 render per row")
    ap.add_argument("--skip-speed", action="store_true", help="only the --run table")
    ap.add_argument("--run", help="a trained vanilla run folder: also time --occupancy on its weights")
    args = ap.parse_args()
    scene = load_npz(args.data)
    rays = RaysData(scene.train, seed=0)
    print(
        f"# vanilla NeRF speed, {date.today()}, {platform.processor() or platform.machine()}, "
        f"{torch.get_num_threads()} threads, torch {torch.__version__}"
    )
    batches = [int(b) for b in args.batches.split(",")]
    if not args.skip_speed:
        speed_table(scene, rays, batches, args.samples, args.repeats, args.render)
    if args.run:
        occupancy_table(args.run, scene, rays, batches[0], args.repeats)


if __name__ == "__main__":
    main()
