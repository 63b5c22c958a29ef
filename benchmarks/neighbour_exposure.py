"""How much of a held-out photo's colour its pose alone predicts.

A real capture's training photos each get a colour correction (exposure, white balance,
colour mixing: ``nerfkit.train.view_corrections.ExposureCorrection``); a held-out photo is
rendered at the average one. A phone sets its exposure from what it sees, so photos taken
from nearby look alike. This scores each held-out photo rendered three ways: at the average
colour (as ``eval`` does), and with the mean correction of the ``k`` training photos whose
directions from the scene's centre are nearest its own (for each ``--k``): a guess from the
pose alone, no pixel of the held-out photo used.

    python benchmarks/neighbour_exposure.py RUN [RUN ...] [--split val] [--k 1,3]

A run keeps its training photos' corrections in its last checkpoint (``train`` keeps one).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from nerfkit.train.metrics import psnr_from_mse


def view_directions(c2w: np.ndarray, center: np.ndarray) -> np.ndarray:
    """(n, 4, 4) camera-to-world poses -> (n, 3) unit directions from ``center`` (3,) to each
    camera's centre."""
    d = np.asarray(c2w, np.float64)[:, :3, 3] - np.asarray(center, np.float64)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def nearest_views(train_dirs: np.ndarray, direction: np.ndarray, k: int) -> np.ndarray:
    """(k,) indices of the rows of ``train_dirs`` (n, 3) at the smallest angles to
    ``direction`` (3,), nearest first (all unit vectors)."""
    return np.argsort(-(train_dirs @ direction), kind="stable")[:k]


def mean_correction(M: np.ndarray, b: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean of views ``idx``'s affine colour corrections ``rgb -> M_i rgb + b_i``
    (``M`` (n, 3, 3), ``b`` (n, 3)): ``(M (3, 3), b (3,))``. Being affine, applying it equals
    averaging the views' corrected colours."""
    return M[idx].mean(0), b[idx].mean(0)


def corrections_of(run: Path) -> tuple[np.ndarray, np.ndarray]:
    """The training photos' colour corrections ``(M (n, 3, 3), b (n, 3))`` (mean removed, as
    training applies them) from ``run``'s last checkpoint."""
    from nerfkit.train.checkpoint import checkpoint_paths
    from nerfkit.train.view_corrections import ExposureCorrection

    paths = checkpoint_paths(run)
    if not paths:
        raise SystemExit(f"{run}: no checkpoint, so no training photo's colour correction to use")
    state = torch.load(paths[0], map_location="cpu", weights_only=False).get("views") or {}
    exposure = {k.split(".", 1)[1]: v for k, v in state.items() if k.startswith("exposure.")}
    if not exposure:
        raise SystemExit(f"{paths[0]}: this run learned no colour corrections (not a real capture's run)")
    ex = ExposureCorrection(exposure["log_gain"].shape[0], mix="mix" in exposure)
    ex.load_state_dict(exposure)
    with torch.no_grad():
        return ex.matrices().numpy().astype(np.float64), ex.centred()[1].numpy().astype(np.float64)


def main() -> None:
    from error_bands import open_split  # (this folder's, beside this script)

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", metavar="RUN", help="run folders (nerfkit train --out) of real captures")
    ap.add_argument("--split", default="val", choices=("val", "test"), help="the held-out views to score")
    ap.add_argument("--k", default="1,3", help="numbers of nearest training photos, comma-separated")
    args = ap.parse_args()
    ks = [int(k) for k in args.k.split(",")]

    print("| run | view | average colour | " + " | ".join(f"{k} nearest" for k in ks) + " |")
    print("|---|---|---:|" + "---:|" * len(ks))
    for run in args.runs:
        scene, views, render = open_split(run, args.split)
        M, b = corrections_of(Path(run))
        train_dirs = view_directions(scene.train.c2w, scene.center)
        rows = []
        for i in range(len(views)):
            photo = views.images[i].astype(np.float64) / 255.0
            rgb = render(i).astype(np.float64)
            near = view_directions(views.c2w[i : i + 1], scene.center)[0]
            scores = [psnr_from_mse(float(np.mean((rgb - photo) ** 2)))]
            for k in ks:
                Mk, bk = mean_correction(M, b, nearest_views(train_dirs, near, k))
                guess = np.clip(rgb @ Mk.T + bk, 0.0, 1.0)
                scores.append(psnr_from_mse(float(np.mean((guess - photo) ** 2))))
            rows.append(scores)
            print(f"| {run} | {views.names[i]} | " + " | ".join(f"{s:.2f}" for s in scores) + " |")
        mean = np.mean(np.array(rows), axis=0)
        print(f"| {run} | mean of {len(rows)} | " + " | ".join(f"**{s:.2f}**" for s in mean) + " |")


if __name__ == "__main__":
    main()
