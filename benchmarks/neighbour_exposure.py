"""How much of a held-out photo's colour its pose alone predicts.

A real capture's training photos each get a colour correction (exposure, white balance,
colour mixing: ``nerfkit.train.view_corrections.ExposureCorrection``). A phone sets its
exposure from what it sees, so photos taken from nearby look alike, and a new view is
rendered with the corrections of the training photos near it in direction
(``nerfkit.models.appearance.DirectionalColour``: a Gaussian of the angle, as wide as the
median angle from a photo to its third nearest). This scores each held-out photo rendered
in the scene's own colour (the photos' average), with the mean correction of the ``k``
training photos nearest in direction (for each ``--k``) and with the Gaussian at each of
``--widths`` (multiples of that spacing; 0.5 is what ``eval`` and the videos use): a guess
from the pose alone, no pixel of the held-out photo used.

    python benchmarks/neighbour_exposure.py RUN [RUN ...] [--split val] [--k 1,3] [--widths 0.5,1,1.5]

A run keeps its training photos' corrections in its last checkpoint (``train`` keeps one).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from nerfkit.models.appearance import DirectionalColour, camera_directions, neighbour_spacing
from nerfkit.train.metrics import psnr_from_mse


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
    ap.add_argument("--widths", default="0.5,1,1.5", help="the Gaussian's widths, in multiples of the spacing")
    args = ap.parse_args()
    ks = [int(k) for k in args.k.split(",")]
    widths = [float(w) for w in args.widths.split(",")]

    heads = ["own colour", *(f"{k} nearest" for k in ks), *(f"Gaussian x{w:g}" for w in widths)]
    print("| run | view | " + " | ".join(heads) + " |")
    print("|---|---|" + "---:|" * len(heads))
    for run in args.runs:
        scene, views, render = open_split(run, args.split, own_colour=True)
        M, b = corrections_of(Path(run))
        train_dirs = camera_directions(scene.train.c2w, scene.center)
        spacing = neighbour_spacing(train_dirs)
        kernels = [DirectionalColour(train_dirs, M, b, scene.center, w * spacing) for w in widths]
        rows = []
        for i in range(len(views)):
            photo = views.images[i].astype(np.float64) / 255.0
            rgb = render(i).astype(np.float64)
            here = camera_directions(views.c2w[i : i + 1], scene.center)
            guesses = [(np.eye(3), np.zeros(3))]
            guesses += [mean_correction(M, b, nearest_views(train_dirs, here[0], k)) for k in ks]
            guesses += [k.correction(views.c2w[i]) for k in kernels]
            scores = [
                psnr_from_mse(float(np.mean((np.clip(rgb @ Mk.T + bk, 0.0, 1.0) - photo) ** 2))) for Mk, bk in guesses
            ]
            rows.append(scores)
            print(f"| {run} | {views.names[i]} | " + " | ".join(f"{s:.2f}" for s in scores) + " |")
        mean = np.mean(np.array(rows), axis=0)
        print(
            f"| {run} | mean of {len(rows)} (spacing {np.degrees(spacing):.1f} deg) | "
            + " | ".join(f"**{s:.2f}**" for s in mean)
            + " |"
        )


if __name__ == "__main__":
    main()
