"""Size and accuracy of a run's compact ``model.pt`` against the dense one.

Loads a finished ``fast`` run (its newest checkpoint, full precision), writes its model
file three ways into a temporary folder — dense float32 (``save_model(compact=False)``),
compact (occupied vertices, float16), and compact with the density in float32 — reloads each
as ``eval``/``render`` would, and
scores both on the run's validation views (and test views with images).

Usage::

    python benchmarks/model_file.py RUN [--data DATASET] [--split val]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import torch

from nerfkit.data.load import load_scene
from nerfkit.models import build_model
from nerfkit.models.packing import vertices_touching
from nerfkit.precision import resolve_precision
from nerfkit.train.checkpoint import MODEL_FILE, load_latest_checkpoint, read_run, save_model
from nerfkit.train.config import parse_background
from nerfkit.train.evaluate import evaluate_views


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run")
    ap.add_argument("--data", default=None, help="dataset (default: the run's)")
    ap.add_argument("--split", default="val")
    args = ap.parse_args()
    info = read_run(args.run)
    scene = load_scene(args.data or info.train.data)
    views = scene.splits[args.split]
    model = build_model(info.train.model, info.model_config, info.bounds)
    _, path = load_latest_checkpoint(Path(args.run), model)  # the resume checkpoint: full precision
    bg = torch.tensor(parse_background(info.train.background))
    dtype = resolve_precision(info.train.precision, torch.device("cpu"))
    out = {
        "run": args.run,
        "checkpoint": path.name,
        "grid_res": list(model.field.geom.res),
        "occupied_cells": model.occupied_fraction,
        "kept_vertices": float(vertices_touching(model.estimator.occ).float().mean()),
    }
    tmp = Path(tempfile.mkdtemp())
    try:
        import nerfkit.models.fast as fast

        for name, compact, density in (
            ("dense", False, None),
            ("compact", True, torch.float16),
            ("compact_fp32_density", True, torch.float32),
        ):
            fast.PACKED_DENSITY_DTYPE = density or fast.PACKED_DENSITY_DTYPE
            folder = tmp / name
            folder.mkdir()
            shutil.copy(Path(args.run) / "config.json", folder / "config.json")
            save_model(folder, int(path.stem.split("_")[1]), model, compact=compact)
            fresh = build_model(info.train.model, info.model_config, info.bounds)
            load_latest_checkpoint(folder, fresh, final_model=True)
            fresh.eval()
            scores = evaluate_views(fresh, views, bg, info.train.render_chunk, dtype, progress=False)
            out[name] = {"bytes": (folder / MODEL_FILE).stat().st_size, "psnr": scores["psnr"], "ssim": scores["ssim"]}
            print(name, out[name], flush=True)
    finally:
        shutil.rmtree(tmp)
    out["psnr_loss_db"] = out["dense"]["psnr"] - out["compact"]["psnr"]
    out["psnr_loss_db_fp32_density"] = out["dense"]["psnr"] - out["compact_fp32_density"]["psnr"]
    out["size_ratio"] = out["compact"]["bytes"] / out["dense"]["bytes"]
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
