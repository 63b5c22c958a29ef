"""A forward-facing scene (LLFF layout) trained in NDC and in a box, under one time budget.

    python benchmarks/forward_facing.py OUT [--size 160] [--views 33] [--minutes 1]
    python benchmarks/forward_facing.py OUT --capture DATASET [--minutes 5]

By default the scene is generated (``heldout.py --scenes forward`` trains the real LLFF flower): the
synthetic forward-facing scene of ``nerfkit.data.synthetic`` (two textured spheres 3 and
6 units from the cameras, a textured backdrop 15 units away; cameras within +-0.4 units
across the view), written as an LLFF folder (``poses_bounds.npy`` + ``images/``, bounds
from the true depths). With ``--capture``, real photos make it instead: from a posed
capture dataset (``nerfkit poses``' output), the largest set of photos that look within
20 degrees of one photo's direction from within a quarter of the cameras' distance, less
the outermost until nerfkit calls them forward-facing (an LLFF-style sweep across one
side of the scene), their undistorted images cropped so the
principal point is centred (LLFF stores one focal length and no principal point), bounds
from the sparse points each photo sees (1st and 99th depth percentiles, as LLFF's
``imgs2poses``). ``nerfkit train`` reads it as any LLFF scene: every 8th photo is held
out. Each configuration is a fresh ``fast`` run of ``--minutes`` (``--model fast``: a
forward-facing scene trains ``splat`` by default), then ``nerfkit eval`` on the held-out photos:

* ``ndc``              the default for a forward-facing scene (``--space auto`` picks NDC);
* ``box``              the grid in the box around the scene's sphere, background black;
* ``box + background`` the box, and a learned colour per direction beyond it;
* ``ndc + capture training`` (with ``--capture``) NDC with ``--capture on``: per-photo
  exposure and pose corrections, the room shells behind the grid.

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
from nerfkit.data.synthetic import BACKDROP_Y, FORWARD_SPHERES, forward_facing_scene

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


def write_capture_scene(folder: Path, dataset: Path, max_angle: float = 20.0, max_shift: float = 0.25) -> str:
    """An LLFF folder from the forward-facing sweep in a posed capture; returns a description."""
    from nerfkit.cameras import forward_facing
    from nerfkit.data.llff import forward_facing_center
    from nerfkit.data.load import load_scene

    scene = load_scene(dataset)
    views = [v for v in scene.splits.values() if v is not None and len(v)]
    names = [n for v in views for n in v.names]
    c2w = np.concatenate([v.c2w for v in views]).astype(np.float64)
    K = np.concatenate([v.K for v in views]).astype(np.float64)
    images = np.concatenate([v.images for v in views])
    order = np.argsort(names)
    names, c2w, K, images = [names[i] for i in order], c2w[order], K[order], images[order]
    forward = c2w[:, :3, 2]
    reach = float(np.linalg.norm(c2w[:, :3, 3] - scene.center, axis=1).mean())
    sweeps = [
        np.flatnonzero(
            (forward @ forward[i] > np.cos(np.radians(max_angle)))
            & (np.linalg.norm(c2w[:, :3, 3] - c2w[i, :3, 3], axis=1) < max_shift * reach)
        )
        for i in range(len(names))
    ]
    sel = max(sweeps, key=len)
    h, w = images.shape[1:3]
    cx, cy = float(K[0, 0, 2]), float(K[0, 1, 2])  # nerfkit convention: the image centre is (w/2, h/2)
    x0 = max(0, int(round(2 * cx - w)))
    x1 = min(w, int(round(2 * cx)))
    y0 = max(0, int(round(2 * cy - h)))
    y1 = min(h, int(round(2 * cy)))
    points = scene.points.astype(np.float64) if scene.points is not None else None
    bounds = {}
    for i in sel:
        if points is None:
            bounds[i] = (scene.near, scene.far)
            continue
        w2c = np.linalg.inv(c2w[i])
        cam = points @ w2c[:3, :3].T + w2c[:3, 3]
        uv = cam[:, :2] / np.maximum(cam[:, 2:], 1e-9) @ K[i, :2, :2].T + K[i, :2, 2]
        seen = (cam[:, 2] > 0) & (uv[:, 0] >= x0) & (uv[:, 0] < x1) & (uv[:, 1] >= y0) & (uv[:, 1] < y1)
        bounds[i] = np.percentile(cam[seen, 2], [1, 99])
    sel = list(sel)
    while True:  # trim the sweep until nerfkit sees it as forward-facing (the photo farthest out first)
        near, far = 0.9 * min(bounds[i][0] for i in sel), max(bounds[i][1] for i in sel)
        if forward_facing(c2w[sel], forward_facing_center(c2w[sel], near, far)):
            break
        eyes = c2w[sel, :3, 3]
        sel.pop(int(np.argmax(np.linalg.norm(eyes - eyes.mean(0), axis=1))))
    bounds = np.array([bounds[i] for i in sel])
    hwf = np.tile([y1 - y0, x1 - x0, K[0, 0, 0]], (len(sel), 1))
    rows = np.concatenate([opencv_to_llff(c2w[sel], hwf).reshape(len(sel), 15), bounds], axis=1)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    np.save(folder / "poses_bounds.npy", rows)
    for i in sel:
        iio.imwrite(folder / "images" / (Path(names[i]).stem + ".png"), images[i, y0:y1, x0:x1])
    spread = np.degrees(
        np.arccos(np.clip(forward[sel] @ forward[sel].mean(0) / np.linalg.norm(forward[sel].mean(0)), -1, 1))
    ).max()
    return (
        f"{len(sel)} photos of {dataset} ({x1 - x0}x{y1 - y0}, cropped to centre the principal point) looking "
        f"within {spread:.0f} degrees of their mean direction, every 8th held out"
    )


def run(cmd: list[str]) -> None:
    subprocess.run([sys.executable, "-m", "nerfkit", *cmd], check=True, stdout=subprocess.DEVNULL)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--size", type=int, default=160)
    ap.add_argument("--views", type=int, default=33)
    ap.add_argument("--minutes", type=float, default=1.0)
    ap.add_argument("--capture", type=Path, help="a posed capture dataset to take a real forward-facing sweep from")
    args = ap.parse_args()
    out = Path(args.out)
    scene_dir = out / "scene"
    if args.capture is not None:
        about = write_capture_scene(scene_dir, args.capture)
    else:
        if not (scene_dir / "poses_bounds.npy").exists():
            write_scene(scene_dir, args.size, args.views)
        about = f"synthetic forward-facing scene, {args.views} photos of {args.size}x{args.size} (every 8th held out)"
    lines = [
        f"{about}, fast, {args.minutes:g} min each",
        "",
        "| configuration | steps | held-out PSNR | SSIM |",
        "|---|---:|---:|---:|",
    ]
    configs = dict(CONFIGS)
    if args.capture is not None:  # real photos: also with the capture training (exposure, pose corrections)
        configs["ndc + capture training"] = ["--capture", "on"]
    for name, flags in configs.items():
        run_dir = out / name.replace(" + ", "_").replace(" ", "_")
        if not (run_dir / "metrics.json").exists():
            run(
                ["train", "--model", "fast", "--data", str(scene_dir), "--out", str(run_dir)]
                + ["--minutes", str(args.minutes), *flags]
            )
        run(["eval", str(run_dir), "--split", "val"])
        e = json.loads((run_dir / "eval_val.json").read_text())
        steps = json.loads((run_dir / "metrics.json").read_text())["step"]
        lines.append(f"| {name} | {steps} | {e['psnr']:.2f} | {e['ssim']:.3f} |")
        print(lines[-1], flush=True)
    (out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
