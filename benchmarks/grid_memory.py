"""Memory, speed and PSNR of the ``fast`` model's grid storage: dense against sparse.

    python benchmarks/grid_memory.py OUT [--data src/nerfkit/assets/lego_200x200.npz] [--steps 5000]
    python benchmarks/grid_memory.py OUT --data lego400.npz --minutes 5 \
        --configs "default=;final 256=--resolutions 32,64,128,256 --upsample-steps 60,300,1500"

Each configuration is one ``nerfkit train`` run (a child process, one after the other, so
its peak RSS is its own), then ``nerfkit eval --split val``. Configurations are
``name=extra train flags``, separated by ``;`` (default: ``dense`` with ``--sparse-from
100000``, which stores every vertex, and ``sparse``, the default). Prints a table of
steps, training seconds, val PSNR/SSIM, peak RSS, stored vertices of the final grid and
file sizes, and writes it to ``OUT/table.md``. Compare seconds only between runs that
had the machine to themselves (``load`` is the 1-minute load average at the end).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CONFIGS = "dense=--sparse-from 100000;sparse="


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", help="output folder (run folders go inside)")
    p.add_argument("--data", default=str(ROOT / "src" / "nerfkit" / "assets" / "lego_200x200.npz"))
    budget = p.add_mutually_exclusive_group()
    budget.add_argument("--steps", type=int, default=None, help="training steps per run (default 5000)")
    budget.add_argument("--minutes", type=float, default=None, help="training minutes per run instead of steps")
    p.add_argument("--configs", default=DEFAULT_CONFIGS, help="'name=flags;name=flags'")
    return p.parse_args(argv)


def stored_vertices(run: Path) -> tuple[int, int]:
    """(stored, all) vertices of the newest resume checkpoint's grid."""
    ckpt = torch.load(sorted((run / "checkpoints").glob("*.pt"))[-1], weights_only=True, map_location="cpu")
    extra = json.loads(ckpt["model_extra"])
    rx, ry, rz = extra["res"]
    state = ckpt["model"]
    grid = state["field.grid"] if "field.grid" in state else state["grid"]  # (the name of older runs)
    return int(grid.shape[0]) - 1, rx * ry * rz


def run_one(name: str, flags: str, args, out: Path) -> dict:
    run = out / name.replace(" ", "_")
    budget = ["--minutes", str(args.minutes)] if args.minutes else ["--steps", str(args.steps or 5000)]
    if run.exists():
        raise SystemExit(f"{run} exists: give a new OUT folder")
    cmd = [
        sys.executable,
        "-m",
        "nerfkit",
        "train",
        "--model",
        "fast",
        "--data",
        args.data,
        "--out",
        str(run),
        *budget,
        *shlex.split(flags),
    ]
    with open(out / f"{run.name}.log", "w") as log:
        child = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(child.pid, 0)  # this child's own peak RSS
        child.returncode = os.waitstatus_to_exitcode(status)
        if child.returncode:
            raise SystemExit(f"{name}: training failed, see {out / f'{run.name}.log'}")
        subprocess.run(
            [sys.executable, "-m", "nerfkit", "eval", str(run), "--split", "val"],
            check=True,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    ev = json.loads((run / "eval_val.json").read_text())
    metrics = json.loads((run / "metrics.json").read_text())
    stored, total = stored_vertices(run)
    ckpts = sorted((run / "checkpoints").glob("*.pt"))
    return {
        "name": name,
        "flags": flags,
        "steps": metrics["step"],
        "seconds": round(metrics["train_seconds"], 1),
        "psnr": ev["psnr"],
        "ssim": ev["ssim"],
        "views": ev["n_images"],
        "peak_rss_mb": round(usage.ru_maxrss / 1024),
        "stored": stored,
        "vertices": total,
        "checkpoint_mb": round(ckpts[-1].stat().st_size / 1e6),
        "model_mb": round((run / "model.pt").stat().st_size / 1e6, 1),
        "load": round(os.getloadavg()[0], 1),
    }


def main(argv=None) -> None:
    args = parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for item in filter(None, (c.strip() for c in args.configs.split(";"))):
        name, _, flags = item.partition("=")
        t = time.time()
        rows.append(run_one(name.strip(), flags.strip(), args, out))
        print(f"{name}: done in {time.time() - t:.0f} s", file=sys.stderr)
    head = (
        "| config | steps | train s | val PSNR / SSIM | peak RSS | stored vertices (final grid) | checkpoint | "
        "model.pt | load |\n|---|---:|---:|---|---:|---|---:|---:|---:|"
    )
    lines = [head] + [
        f"| {r['name']} | {r['steps']} | {r['seconds']} | {r['psnr']:.3f} / {r['ssim']:.4f} | "
        f"{r['peak_rss_mb']} MB | "
        f"{r['stored'] / 1e6:.2f} M of {r['vertices'] / 1e6:.2f} M ({100 * r['stored'] / r['vertices']:.0f}%) | "
        f"{r['checkpoint_mb']} MB | {r['model_mb']} MB | {r['load']} |"
        for r in rows
    ]
    table = "\n".join(lines)
    print(f"data {args.data}, {rows[0]['views'] if rows else 0} val views\n{table}")
    (out / "table.md").write_text(table + "\n")
    (out / "results.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
