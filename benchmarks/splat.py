"""Gaussian splatting (``splat``) next to ``fast``: time to PSNR, render speed, size.

    python benchmarks/splat.py OUT [--data src/nerfkit/assets/lego_200x200.npz] [--budgets 120,600]
                                   [--models splat,fast]

For every model and budget B (seconds of training, evaluation excluded) one fresh run
trains with ``--minutes B/60`` exactly as ``nerfkit train`` would and is scored on all
validation views. Each run is its own process, so its peak memory (max RSS) is its own.
Also recorded: validation PSNR on the way (the run's own periodic evaluations, 2 views),
frames per second rendering validation views (median of 10 frames after one warm-up),
the number of Gaussians and the size of the exported 3DGS PLY (splat), the load average
before and after (the machine may be shared: compare CPU and wall seconds).

Writes ``OUT/results.json`` and ``OUT/table.md``; run folders go to ``OUT/runs/``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", help="output folder")
    p.add_argument(
        "--data", default=str(Path(__file__).resolve().parents[1] / "src" / "nerfkit" / "assets" / "lego_200x200.npz")
    )
    p.add_argument("--models", default="splat,fast", help="comma-separated model names")
    p.add_argument("--budgets", default="120,600", help="training seconds, comma-separated")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--model", help=argparse.SUPPRESS)
    p.add_argument("--seconds", type=float, help=argparse.SUPPRESS)
    p.add_argument("--run", help=argparse.SUPPRESS)
    return p.parse_args(argv)


def worker(args) -> dict:
    """Train one model for one budget in this process and return its figures."""
    import torch

    from nerfkit import presets
    from nerfkit.data.load import load_scene
    from nerfkit.models import model_config_class
    from nerfkit.output.images import render_image
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    scene = load_scene(args.data)
    model_cfg = model_config_class(args.model)()
    cfg = TrainConfig(
        data=args.data,
        model=args.model,
        out=args.run,
        minutes=args.seconds / 60.0,
        seed=args.seed,
        checkpoint_seconds=1e9,
    )
    cfg, model_cfg = presets.resolve(cfg.validate(), model_cfg, scene).configs()

    class TimedTrainer(Trainer):
        cpu_seconds = 0.0

        def train_step(self) -> dict:
            c = time.process_time()
            stats = super().train_step()
            self.cpu_seconds += time.process_time() - c
            return stats

    load_before = os.getloadavg()
    trainer = TimedTrainer(scene, cfg, model_cfg, quiet=True)
    result = trainer.run()
    bg = trainer.background
    val = scene.val

    def frame(i):
        return render_image(
            trainer.model, val.K[i], val.c2w[i], val.width, val.height, bg, cfg.render_chunk, trainer.autocast
        )

    frame(0)
    times = []
    for k in range(10):
        t = time.perf_counter()
        frame(k % len(val))
        times.append(time.perf_counter() - t)
    fig = {
        "model": args.model,
        "budget_s": args.seconds,
        "steps": result.step,
        "train_s": result.train_seconds,
        "train_cpu_s": trainer.cpu_seconds,
        "final_val_psnr": result.final_val_psnr,
        "fps": 1.0 / statistics.median(times),
        "frame": [val.width, val.height],
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "curve": [
            {"seconds": r["seconds"], "psnr": r["psnr"], "views": r.get("views")}
            for r in result.rows
            if r["split"] == "val"
        ],
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(),
        "torch_threads": torch.get_num_threads(),
    }
    if hasattr(trainer.model, "n_gaussians"):
        from nerfkit.splat_files import Gaussians, write_splat_ply

        ply = Path(args.run) / "splat.ply"
        write_splat_ply(ply, Gaussians.from_model(trainer.model))
        fig.update(n_gaussians=trainer.model.n_gaussians, ply_mb=ply.stat().st_size / 1e6)
    return fig


def table(results: list[dict]) -> str:
    rows = [
        "| model | budget (s) | steps | val PSNR (dB) | fps (render) | Gaussians | .ply MB | peak RSS MB | "
        "CPU s / wall s | load avg |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        rows.append(
            f"| {r['model']} | {r['budget_s']:.0f} | {r['steps']} | {r['final_val_psnr']:.2f} | "
            f"{r['fps']:.1f} | "
            f"{r.get('n_gaussians', '-')} | {r.get('ply_mb', float('nan')):.1f} | {r['peak_rss_mb']:.0f} | "
            f"{r['train_cpu_s']:.0f} / {r['train_s']:.0f} | "
            f"{r['loadavg_before'][0]:.1f}-{r['loadavg_after'][0]:.1f} |"
        )
    return "\n".join(rows) + "\n"


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args)))
        return 0
    out = Path(args.out)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    results = []
    for budget in [float(b) for b in args.budgets.split(",") if b]:
        for model in [m for m in args.models.split(",") if m]:
            run = out / "runs" / f"{model}_{budget:.0f}s"
            cmd = [
                sys.executable,
                __file__,
                str(out),
                "--worker",
                "--model",
                model,
                "--seconds",
                str(budget),
                "--run",
                str(run),
                "--data",
                args.data,
                "--seed",
                str(args.seed),
            ]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                print(proc.stderr[-2000:], file=sys.stderr)
                return 1
            r = json.loads(proc.stdout.strip().splitlines()[-1])
            results.append(r)
            print(
                f"{model} {budget:.0f}s: {r['final_val_psnr']:.2f} dB in {r['steps']} steps, {r['fps']:.1f} fps",
                flush=True,
            )
            (out / "results.json").write_text(json.dumps(results, indent=1))
    text = table(results)
    (out / "table.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
