"""A forward-facing scene (LLFF layout) trained in NDC and in a box, under one time budget.

    python benchmarks/forward_facing.py OUT [--size 160] [--views 33] [--minutes 1]

There is no real LLFF capture on these machines, so the scene is generated: the
synthetic forward-facing scene of ``nerfkit.data.synthetic`` (two textured spheres 3 and
6 units from the cameras, a textured backdrop 15 units away; cameras within +-0.4 units
across the view), written as an LLFF folder (``poses_bounds.npy`` + ``images/``, bounds
from the true depths). ``nerfkit train`` reads it as any LLFF scene: every 8th photo is
held out. Each configuration is a fresh ``fast`` run of ``--minutes``, then ``nerfkit
eval`` on the held-out photos:

* ``ndc``              the default for a forward-facing scene (``--space auto`` picks NDC);
* ``box``              the grid in the box around the scene's sphere, background black;
* ``box + background`` the box, and a learned colour per direction beyond it.

Prints a table (steps, held-out PSNR/SSIM) and writes ``OUT/table.md``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from nerfkit.data.llff import opencv_to_llff
from nerfkit.data.synthetic import FORWARD_SPHERES, BACKDROP_Y, forward_facing_scene

CONFIGS = {"ndc": [], "box": ["--space", "box"], "box + background": ["--space", "box", "--learn-background"]}


def write_scene(folder: Path, size: int, views: int) -> None:
    scene = forward_facing_scene(n_train=views, n_val=0, size=size)
    c2w, K = scene.train.c2w, scene.train.K
    near = min(np.linalg.norm(c - c2w[:, :3, 3], axis=1).min() - r for c, r in FORWARD_SPHERES)
    bounds = np.tile([0.9 * near, 1.2 * BACKDROP_Y / 0.9], (views, 1))
    hwf = np.stack([np.full(views, size), np.full(views, size), K[:, 0, 0]], 1)
    rows = np.concatenate([opencv_to_llff(c2w, hwf).reshape(views, 15), bounds], axis=1)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    np.save(folder / "poses_bounds.npy", rows)
    for i, img in enumerate(scene.train.images):
        iio.imwrite(folder / "images" / f"IMG_{i:04d}.png", img)


def run(cmd: list[str]) -> None:
    subprocess.run([sys.executable, "-m", "nerfkit", *cmd], check=True, stdout=subprocess.DEVNULL)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--size", type=int, default=160)
    ap.add_argument("--views", type=int, default=33)
    ap.add_argument("--minutes", type=float, default=1.0)
    args = ap.parse_args()
    out = Path(args.out)
    scene_dir = out / "scene"
    if not (scene_dir / "poses_bounds.npy").exists():
        write_scene(scene_dir, args.size, args.views)
    lines = [f"synthetic forward-facing scene, {args.views} photos of {args.size}x{args.size} "
             f"(every 8th held out), fast, {args.minutes:g} min each", "",
             "| configuration | steps | held-out PSNR | SSIM |", "|---|---:|---:|---:|"]
    for name, flags in CONFIGS.items():
        run_dir = out / name.replace(" + ", "_")
        if not (run_dir / "metrics.json").exists():
            run(["train", "--data", str(scene_dir), "--out", str(run_dir), "--minutes", str(args.minutes), *flags])
        run(["eval", str(run_dir), "--split", "val"])
        e = json.loads((run_dir / "eval_val.json").read_text())
        steps = json.loads((run_dir / "metrics.json").read_text())["step"]
        lines.append(f"| {name} | {steps} | {e['psnr']:.2f} | {e['ssim']:.3f} |")
        print(lines[-1], flush=True)
    (out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
