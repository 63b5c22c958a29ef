"""Seconds per training step and samples per second of the course NeRF, fp32 vs bf16.

Usage: python benchmarks/vanilla_speed.py [--batch-rays 1024] [--samples 64] [--repeats 5]
Prints a table of medians over repeated steps (after one warm-up step) and the ratio.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from datetime import date

import torch

from nerfkit.data.npz import load_npz
from nerfkit.data.rays import RaysData
from nerfkit.models.base import SceneBounds
from nerfkit.models.vanilla import VanillaConfig, VanillaNeRF
from nerfkit.render.renderer import render_image


def step_times(model, rays, batch, autocast, repeats):
    opt = model.make_optimizer(5e-4)
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


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data", default="src/nerfkit/assets/lego_200x200.npz")
    ap.add_argument("--batch-rays", type=int, default=1024)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--render", action="store_true", help="also time one full 200x200 render per precision")
    args = ap.parse_args()
    scene = load_npz(args.data)
    rays = RaysData(scene.train, seed=0)
    print(f"# vanilla NeRF speed, {date.today()}, {platform.processor() or platform.machine()}, "
          f"{torch.get_num_threads()} threads, torch {torch.__version__}")
    print(f"# batch {args.batch_rays} rays x {args.samples} samples, median of {args.repeats} steps")
    print("| precision | s/step | samples/s | render s/frame |")
    print("|---|---|---|---|")
    results = {}
    for name, autocast in [("fp32", False), ("bf16", True)]:
        torch.manual_seed(0)
        model = VanillaNeRF(VanillaConfig(n_samples=args.samples), SceneBounds.from_scene(scene))
        sec, n = step_times(model, rays, args.batch_rays, autocast, args.repeats)
        render = "-"
        if args.render:
            t0 = time.perf_counter()
            render_image(model, scene.val.K[0], scene.val.c2w[0], scene.val.width, scene.val.height, torch.zeros(3),
                         4096, torch.bfloat16 if autocast else None)
            render = f"{time.perf_counter() - t0:.1f}"
        results[name] = sec
        print(f"| {name} | {sec:.3f} | {n / sec / 1e6:.3f} M | {render} |")
    print(f"\nbf16 speed-up: {results['fp32'] / results['bf16']:.2f}x")


if __name__ == "__main__":
    main()
