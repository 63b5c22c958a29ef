"""Benchmark of ``nerfkit fit-image``: speed (fp32 vs bf16 autocast) and final PSNR.

Trains the course model at the defaults (L=10, width 256, depth 3, 10,000 pixels/step,
Adam 1e-2) on the shipped image and, when given and present, on another image such as
the course's fox::

    python benchmarks/fit_image.py                                # shipped image only
    python benchmarks/fit_image.py --image /path/to/fox.jpg --steps 2000
    python benchmarks/fit_image.py --precisions bf16 --steps 300   # a quick speed check

steps/s counts training steps only (the first, slow warm-up steps included); "eval s" is
the time spent on the PSNR curve (every --eval-every steps), the progression renders and
the final full-resolution render. Timings depend on machine load: run it on an idle
machine for figures you want to quote.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--image",
        action="append",
        default=[],
        help="extra image(s) to fit (skipped with a note when the file does not exist)",
    )
    parser.add_argument("--steps", type=int, default=2000, help="training steps per fit (default: 2000)")
    parser.add_argument("--precisions", default="fp32,bf16", help="comma-separated (default: fp32,bf16)")
    parser.add_argument("--eval-every", type=int, default=50, help="as fit-image's --eval-every (default: 50)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="also write each run folder here (figures, metrics)")
    args = parser.parse_args(argv)

    import torch

    from nerfkit.fit_image import FitImageConfig, fit_image, load_target, write_run

    images: list[Path | None] = [None]
    for p in args.image:
        if Path(p).is_file():
            images.append(Path(p))
        else:
            print(f"note: {p} does not exist; skipped", file=sys.stderr)

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, load average {load:.2f} at start")
    header = (
        f"{'image':16s} {'size':>10s} {'prec':>5s} {'steps':>6s} {'steps/s':>8s} {'1000 steps':>10s} "
        f"{'train s':>8s} {'eval s':>7s} {'PSNR dB':>8s} {'curve dB':>8s}"
    )
    print(header)
    print("-" * len(header))
    for image in images:
        for precision in args.precisions.split(","):
            cfg = FitImageConfig(
                steps=args.steps, precision=precision, device="cpu", seed=args.seed, eval_every=args.eval_every
            )
            target, path = load_target(image, cfg.background)
            t0 = time.perf_counter()
            r = fit_image(target, cfg, progress=False)
            wall = time.perf_counter() - t0
            if args.out:
                write_run(Path(args.out) / f"{path.stem}-{precision}", r, target, path)
            # The curve's last point: the full image, or a fixed random subset for big images.
            curve_final = r.curve_psnr[-1]
            print(
                f"{path.name[:16]:16s} {f'{r.width}x{r.height}':>10s} {r.precision:>5s} {cfg.steps:6d} "
                f"{r.steps_per_s:8.1f} {1000 / r.steps_per_s:9.1f}s {r.train_seconds:8.1f} "
                f"{r.eval_seconds:7.1f} {r.final_psnr:8.2f} {curve_final:8.2f}   (wall {wall:.0f} s)",
                flush=True,
            )
            del target, r
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"load average {load:.2f} at end (2 cores; other processes slow every figure above)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
