"""Transients on a capture: the photographer's shadow painted onto some training photos.

    python benchmarks/shadow_transients.py --capture NAME=DATASET [...] --out OUT
                                           [--share 0.5] [--darkness 0.55] [--steps 1500]
                                           [--models fast] [--variant NAME:FIELD=VALUE,...]

A photographer standing with the light behind them throws a shadow that enters each photo at
its bottom edge and falls somewhere else on the table in every photo. No static scene explains
it; fitted, it leaves a faint dark smear on the table of the new views. This benchmark makes
that case from a posed capture dataset whose photos have no such shadow: it writes a copy
(``OUT/data/NAME-shadow.npz``) in which ``--share`` of the training photos (chosen at random,
``--seed``) carry a soft-edged shadow (:func:`photographer_shadow`: an ellipse rising from the
bottom edge at a random place, the light inside it multiplied by ``--darkness``). The val and
test photos are left as they were.

Then it runs ``benchmarks/heldout.py`` on the clean and the shadowed dataset side by side (each
model and ``--variant`` on both, scored on the same clean val photos as rendered), so that the
table shows what the shadows cost each way of training, and how much of it a transient rule
(``--variant fast+tr:transient_quantile=0.9``) wins back without costing the clean capture.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import heldout  # noqa: E402

from nerfkit.errors import NerfkitError, fail  # noqa: E402
from nerfkit.io.atomic import write_npz  # noqa: E402

# the shadow's half-width and height as shares of the photo's width and height (ranges drawn from)
HALF_WIDTH = (0.12, 0.22)
HEIGHT = (0.35, 0.6)
# the soft edge (penumbra): a Gaussian blur of this share of the photo's width
SOFTNESS = 0.03


def photographer_shadow(height: int, width: int, rng: np.random.Generator, darkness: float) -> np.ndarray:
    """(height, width) float32 factor in [darkness, 1] to multiply a photo's pixels by: 1 outside
    the shadow, ``darkness`` inside it. The shadow is an ellipse centred on the bottom edge at a
    random column in the middle 60% of the photo, its half-width and height drawn from
    :data:`HALF_WIDTH` and :data:`HEIGHT`, its edge blurred by :data:`SOFTNESS` of the width."""
    cx = rng.uniform(0.2, 0.8) * width
    a = rng.uniform(*HALF_WIDTH) * width
    b = rng.uniform(*HEIGHT) * height
    y, x = np.mgrid[0:height, 0:width].astype(np.float32) + 0.5
    inside = (((x - cx) / a) ** 2 + ((y - height) / b) ** 2 <= 1.0).astype(np.float32)
    sigma = max(SOFTNESS * width, 0.5)
    soft = cv2.GaussianBlur(inside, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
    return (1.0 - (1.0 - darkness) * soft).astype(np.float32)


def add_shadows(
    images: np.ndarray, share: float, darkness: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``(shadowed, which)``: a copy of ``images`` (n, H, W, 3) uint8 in which ``round(share n)``
    photos, chosen at random (``which`` (k,) their sorted indices), are multiplied by a
    :func:`photographer_shadow` each."""
    n, h, w = images.shape[:3]
    which = np.sort(rng.choice(n, size=int(round(share * n)), replace=False))
    out = images.copy()
    for i in which:
        factor = photographer_shadow(h, w, rng, darkness)
        out[i] = np.clip(np.rint(images[i].astype(np.float32) * factor[..., None]), 0, 255).astype(np.uint8)
    return out, which


def shadowed_copy(src: Path, dst: Path, share: float, darkness: float, seed: int) -> np.ndarray:
    """Write ``dst``: the dataset ``src`` (.npz) with :func:`add_shadows` on its training photos
    (every other array as it was); returns the indices of the shadowed photos."""
    with np.load(src, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    if "images_train" not in arrays:
        raise fail(src, "has no images_train", "Give a posed capture dataset (nerfkit poses' output)")
    arrays["images_train"], which = add_shadows(arrays["images_train"], share, darkness, np.random.default_rng(seed))
    write_npz(dst, **arrays)
    return which


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--capture", action="append", default=[], metavar="NAME=DATASET", help="a posed capture dataset (repeatable)"
    )
    p.add_argument("--out", type=Path, required=True, help="folder for the shadowed datasets and the runs")
    p.add_argument("--share", type=float, default=0.5, help="share of the training photos that get a shadow")
    p.add_argument("--darkness", type=float, default=0.55, help="the light left inside a shadow (0-1)")
    p.add_argument("--steps", default="1500", help="training budgets in steps, comma-separated")
    p.add_argument("--models", default="fast", help="comma-separated model names (as heldout.py)")
    p.add_argument(
        "--variant", action="append", default=[], metavar="NAME:FIELD=VALUE,...", help="as heldout.py (repeatable)"
    )
    p.add_argument("--seed", type=int, default=0)
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        if not 0.0 < args.share <= 1.0 or not 0.0 <= args.darkness < 1.0:
            raise fail("--share/--darkness", "--share must be in (0, 1] and --darkness in [0, 1)")
        captures = heldout.parse_captures(args.capture)
        if not captures:
            raise fail("--capture", "no capture given", "Give at least one --capture NAME=DATASET")
        pairs = []
        for name, path in captures.items():
            shadowed = args.out / "data" / f"{name}-shadow.npz"
            which = shadowed_copy(path, shadowed, args.share, args.darkness, args.seed)
            print(f"{name}: shadows on {len(which)} training photos {which.tolist()} -> {shadowed}", flush=True)
            pairs += [f"{name}={path}", f"{name}-shadow={shadowed}"]
        argv_heldout = [
            "--scenes",
            "captures",
            "--models",
            args.models,
            "--steps",
            args.steps,
            "--seed",
            str(args.seed),
        ]
        argv_heldout += [a for pair in pairs for a in ("--capture", pair)]
        argv_heldout += [a for v in args.variant for a in ("--variant", v)]
        return heldout.run(heldout.parse_args([*argv_heldout, "--out", str(args.out)]))
    except NerfkitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
