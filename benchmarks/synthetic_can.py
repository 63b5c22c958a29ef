"""A glossy drink can on a white table, rendered, through `nerfkit capture`: the object's own pixels.

    python benchmarks/synthetic_can.py OUT [--photos 40] [--minutes 3] [--seed 0] [--gloss 1] [--label busy]

A stand-in for a shiny, thin object (``nerfkit.capture.synthetic``): a red can 6.6 cm wide and
12.2 cm tall whose label mirrors 30% of a room around it and whose metal top mirrors 70%,
beside one 6 cm tag on a white, faintly mottled table (``--label busy``: a label with white
script and a band of small letters, as a real drink can's, whose photos show more detail than
the table's: :func:`busy_label`); the photos of a 6-tag sheet calibrate a
lens with radial distortion first. Known poses and no exposure changes, so what is left is what
the view-dependent colour and the grid make of a glossy cylinder. Runs

    nerfkit capture OUT/object --calib OUT/calib --tag-size 0.06 --sheet-tag-size 0.05 --model fast

and prints the val photos' PSNR / SSIM, the can's own pixels (``eval``'s object score) and how
far the dataset's cameras (the tags' or structure-from-motion's, as ``poses`` chose) are from
the true ones (median, mm and degrees).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from nerfkit.capture import synthetic as S
from nerfkit.capture.camera import FILM_DIAGONAL_MM

TAG = 0.06
SHEET_TAG = 0.05
CAN_CENTER = (0.12, 0.02, 0.061)
CAN_RADIUS = 0.033
SIZE = (640, 480)


def white_table(seed: int) -> np.ndarray:
    """The default table texture's mottling about a white of 228, 4 m before it repeats (a
    texture that repeats within the photos gives structure-from-motion false matches)."""
    t = S.table_texture(seed, n=2048).astype(np.float64)
    return np.clip(t - t.reshape(-1, 3).mean(0) + 228.0, 0, 255).astype(np.uint8)


def busy_label(seed: int = 0, size: tuple[int, int] = (256, 1024)) -> np.ndarray:
    """A drink can's label (h, w, 3) uint8 with more detail than :func:`~nerfkit.capture.synthetic.can_label`:
    red, six strokes of thick white script in its upper half, a white wave, and a band of 60
    small white and dark letters near its foot."""
    rng = np.random.default_rng(seed)
    h, w = size
    img = S.red_label(size, 0.62, 0.10, 0.04)
    t = np.linspace(0.0, 1.0, 400)
    for k in range(6):  # script: a thick stroke along a sine wave, 10 px wide
        xs = k * w / 6 + t * w / 7
        ys = 0.3 * h + 0.12 * h * np.sin(2 * np.pi * (3 * t + 0.3 * k))
        for x, y in zip(xs.astype(int), ys.astype(int), strict=True):
            img[max(y - 5, 0) : y + 5, max(x - 5, 0) : x + 5] = (245, 245, 240)
    for _ in range(60):  # small letters, white and dark
        x, bw = int(rng.integers(0, w - 12)), int(rng.integers(4, 10))
        y, bh = int(rng.integers(int(0.75 * h), int(0.9 * h))), int(rng.integers(8, 14))
        img[y : y + bh, x : x + bw] = (245, 245, 240) if rng.random() < 0.5 else (30, 20, 20)
    return img


def write_capture(out: Path, photos: int, seed: int, gloss: float = 1.0, label: str = "plain") -> S.SyntheticCapture:
    """The calibration photos (OUT/calib) and the can's (OUT/object); returns the can's capture."""
    f35 = round(S.DEFAULT_K[0, 0] * FILM_DIAGONAL_MM / np.hypot(*SIZE))
    S.make_calibration_capture(n=20, size=SIZE, tag_size=SHEET_TAG, seed=seed).write(out / "calib", f35=f35)
    cap = S.make_object_capture(
        n=photos,
        size=SIZE,
        tag_size=TAG,
        object_center=CAN_CENTER,
        object_radius=CAN_RADIUS,
        seed=seed + 1,
        can=True,
        table=white_table(seed),
        distance=(0.34, 0.46),
        gloss=gloss,
        label=busy_label(seed + 1) if label == "busy" else None,
    )
    cap.write(out / "object", f35=f35)
    return cap


def pose_errors(cap: S.SyntheticCapture, dataset: Path) -> tuple[float, float, int]:
    """Median position (mm) and rotation (degrees) error of the cameras in ``dataset`` (its
    dataset.npz, every split: the poses the model trains and is scored on, the tags' or
    structure-from-motion's; the tag's frame, metres, as the truth's), and how many."""
    from nerfkit.data.load import load_scene
    from nerfkit.sfm.tagged import pose_agreement

    views = [v for v in load_scene(dataset / "dataset.npz").splits.values() if v is not None and len(v)]
    est = {n: m for v in views for n, m in zip(v.names or [], v.c2w)}
    apart = pose_agreement(dict(zip(cap.names, cap.c2w)), est)
    if apart is None:
        raise SystemExit(f"{dataset}: no photo named as the rendered ones")
    return 1000 * apart["shift_median"], apart["rot_deg_median"], apart["photos"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--photos", type=int, default=40)
    ap.add_argument("--minutes", type=float, default=3.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--gloss", type=float, default=1.0, help="the can's gloss, times the default (0: matte)")
    ap.add_argument("--label", choices=("plain", "busy"), default="plain", help="busy: script and letters on the label")
    args = ap.parse_args()
    cap = write_capture(args.out, args.photos, args.seed, args.gloss, args.label)
    run = args.out / "capture"
    subprocess.run(
        [sys.executable, "-m", "nerfkit", "capture", str(args.out / "object"), "--calib", str(args.out / "calib")]
        + ["--tag-size", str(TAG), "--sheet-tag-size", str(SHEET_TAG), "--model", "fast", "--no-mesh"]
        + ["--minutes", str(args.minutes), "--out", str(run), "--force"],
        check=True,
    )
    e = json.loads((run / "run" / "eval_val.json").read_text())
    steps = json.loads((run / "run" / "metrics.json").read_text())["step"]
    mm, deg, placed = pose_errors(cap, run / "dataset")
    obj = (e.get("object") or {}).get("psnr")
    obj = float("nan") if obj is None else obj  # (none when the run drew no opaque object pixel)
    print("\n| photos | posed | camera error: mm / degrees | steps | val PSNR / SSIM | the can's pixels |")
    print("|---:|---:|---|---:|---|---:|")
    scores = f"{e['psnr']:.2f} / {e['ssim']:.3f}"
    print(f"| {args.photos} | {placed} | {mm:.2f} / {deg:.3f} | {steps} | {scores} | {obj:.2f} |")


if __name__ == "__main__":
    main()
