"""Does a splat file render what nerfkit's own eval renders? Scores a 3DGS PLY on a run's
held-out views with a renderer that reads only the PLY (no learned background: over black,
as a standard viewer draws it), beside the run's own ``eval_<split>.json``::

    nerfkit export RUN --splat RUN/splat.ply
    python benchmarks/splat_file_check.py RUN RUN/splat.ply [--split val] [--out check.json]

The views (cameras, images, resolution) are the run's dataset loaded as it was trained, so the
per-view PSNRs compare one for one with the eval's; ``psnr_ply_vs_model`` scores the PLY's render
against the run's own (its learned background included) at each view, as nerfkit draws it (a
capture's in the colour of the training photos near the view), and ``psnr_ply_vs_scene_colour``
against the run's render in the scene's own colour (what a file can carry). Prints a JSON report.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def render_ply(g, K: np.ndarray, c2w: np.ndarray, width: int, height: int, near_plane: float) -> np.ndarray:
    """The Gaussians ``g`` (:class:`~nerfkit.splat_files.Gaussians`) seen from ``(K, c2w)`` over
    black: (H, W, 3) in [0, 1], with nerfkit's rasterizer (compiled when available)."""
    import torch

    from nerfkit.kernels.splat_ops import render_gaussians

    sh = np.zeros((len(g), 16, 3), np.float32)
    sh[:, :1] = g.sh_dc
    sh[:, 1 : 1 + g.sh_rest.shape[1]] = g.sh_rest
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32)  # noqa: E731
    w2c = torch.linalg.inv(torch.as_tensor(c2w, dtype=torch.float64)).float()
    with torch.no_grad():
        out = render_gaussians(
            t(g.means),
            t(g.log_scales),
            t(g.quats),
            t(g.opacity_logits),
            t(sh),
            g.sh_degree,
            w2c,
            t(K),
            width,
            height,
            torch.zeros(height, width, 3),
            near_plane,
            "auto",
        )
    return out.rgb.clamp(0, 1).numpy()


def check(run: str, ply: str, split: str) -> dict:
    from nerfkit.commands._common import RunToOpen, open_run, scene_for_run
    from nerfkit.output.images import render_image
    from nerfkit.splat_files import read_splat_ply
    from nerfkit.train.metrics import psnr

    opened = open_run(RunToOpen(run, "cpu"))
    info, step = opened.info, opened.step
    scene = scene_for_run(info, None, need=split)
    views = scene.splits[split]
    g = read_splat_ply(ply)
    near_plane = 0.05 * float(info.bounds.near)  # as the splat model's
    t0 = time.perf_counter()
    rows, same, plain = [], [], []
    appearance = getattr(opened.model, "appearance", None)  # a capture's colour of each new view
    for i in range(len(views)):
        K, c2w, w, h = views.K[i], views.c2w[i], views.width, views.height
        rgb = render_ply(g, K, c2w, w, h, near_plane)
        rows.append(round(psnr(rgb, views.images[i].astype(np.float32) / 255.0), 4))
        own = render_image(opened.model, K, c2w, w, h, opened.background(), opened.chunk).rgb
        same.append(round(psnr(rgb, own), 4))
        if appearance is not None:
            opened.model.appearance = None
            try:
                scene_colour = render_image(opened.model, K, c2w, w, h, opened.background(), opened.chunk).rgb
            finally:
                opened.model.appearance = appearance
            plain.append(round(psnr(rgb, scene_colour), 4))
    report = {
        "run": run,
        "ply": ply,
        "step": step,
        "split": split,
        "n_gaussians": len(g),
        "n_views": len(rows),
        "psnr_ply_over_black": round(float(np.mean(rows)), 4),
        "psnr_ply_vs_model": round(float(np.mean(same)), 4),
        "seconds": round(time.perf_counter() - t0, 1),
        "per_view_ply": rows,
        "per_view_ply_vs_model": same,
        **(
            {"psnr_ply_vs_scene_colour": round(float(np.mean(plain)), 4), "per_view_ply_vs_scene_colour": plain}
            if plain
            else {}
        ),
    }
    ev = Path(run) / f"eval_{split}.json"
    if ev.is_file():
        e = json.loads(ev.read_text())
        report["psnr_eval"] = e["psnr"]
        report["per_view_eval"] = [p["psnr"] for p in e["per_image"]]
        report["difference_db"] = round(report["psnr_ply_over_black"] - e["psnr"], 4)
    return report


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="splat run folder (its dataset gives the views)")
    p.add_argument("ply", help="the 3DGS PLY to score")
    p.add_argument("--split", default="val")
    p.add_argument("--out", help="also write the JSON report here")
    a = p.parse_args(argv)
    report = check(a.run, a.ply, a.split)
    text = json.dumps(report, indent=1)
    print(text)
    if a.out:
        Path(a.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
