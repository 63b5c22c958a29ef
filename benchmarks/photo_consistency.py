"""How well the photos of a capture agree on its table: a ceiling for any diffuse table.

A NeRF with a diffuse (view-independent) table shows each table point in one colour. If
the photos themselves show a point in different colours (a varnished table's sheen, the
photographer's shadow, exposure), no such model can match them all. This script projects
a grid of points on the dataset's table plane (within ``--extent`` of the centre, away
from the object's box, which may hide them) into every photo, and prints:

* the number of table points and of photos seeing each;
* across the training photos: the RMS difference of each photo's colour at a point from
  the point's mean colour over the photos that see it, as a PSNR (also after blurring the
  photos by 3 pixels, so that pose and resampling errors at edges count less);
* per held-out photo: the PSNR of its colours at the table points against the training
  photos' mean there (and with its per-channel gain fitted): what a diffuse table with
  each point's mean colour would score on those pixels; with ``--run``, also what the run's
  render scores on the same pixels (a learned table that scores below the plain mean has
  fitted the training photos' differences instead of the table).

Split the across-view figure by brightness to see what disagrees (paper, dark wood)::

    python benchmarks/photo_consistency.py CAPTURES/steve/dataset/dataset.npz   # a capture_real.py dataset
    python benchmarks/photo_consistency.py DATA.npz --extent 0.3 --split val
    python benchmarks/photo_consistency.py DATA.npz --run RUN   # and the run's renders
"""

from __future__ import annotations

import argparse

import numpy as np

from nerfkit.capture.agreement import EXTENT_RADII, MIN_PHOTOS, consistency, sample_photo, table_points
from nerfkit.capture.agreement import psnr_of as psnr


def main() -> None:
    from nerfkit.data.load import load_scene
    from nerfkit.models import SceneBounds

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", help="a capture dataset (.npz with a table plane)")
    ap.add_argument(
        "--extent",
        type=float,
        default=None,
        help="half-width of the table square, in scene units (default: the object radius times "
        f"{EXTENT_RADII}, as `poses` measures it)",
    )
    ap.add_argument("--grid", type=int, default=241, help="points per side of the square (default 241)")
    ap.add_argument("--split", default="val", help="held-out split to score (default val)")
    ap.add_argument("--run", help="a run trained on DATA: also score its renders of the held-out photos")
    args = ap.parse_args()

    scene = load_scene(args.data)
    if scene.table is None:
        raise SystemExit(f"{args.data}: the dataset has no table plane (a tag capture's, or SfM's found table)")
    bounds = SceneBounds.from_scene(scene)
    extent = args.extent or EXTENT_RADII * bounds.radius
    pts = table_points(np.asarray(scene.center, np.float64), scene.table, extent, args.grid, bounds.object_box)
    train = scene.splits["train"]
    mean, count, dev, seen = consistency(train, pts, bounds.object_box)
    good = count >= MIN_PHOTOS
    print(
        f"{args.data}: {good.sum()} table points seen by >= {MIN_PHOTOS} of {len(train)} training photos "
        f"(median {np.median(count[good]):.0f}), square of half-width {extent:.3f}"
    )
    _, _, dev_b, seen_b = consistency(train, pts, bounds.object_box, blur=3.0)
    print(
        f"across the training photos: {psnr(dev[:, good].sum() / seen[:, good].sum()):.2f} dB "
        f"(blurred by 3 px: {psnr(dev_b[:, good].sum() / seen_b[:, good].sum()):.2f} dB)"
    )
    bright = mean.mean(-1)
    print("\n| table points | share of points | across-view PSNR | share of the disagreement |")
    print("|---|---:|---:|---:|")
    for name, sel in (
        ("bright (> 0.55)", bright > 0.55),
        ("mid", (bright >= 0.3) & (bright <= 0.55)),
        ("dark (< 0.3)", bright < 0.3),
    ):
        sel = sel & good
        if sel.any():
            print(
                f"| {name} | {sel.sum() / good.sum():.2f} | {psnr(dev[:, sel].sum() / seen[:, sel].sum()):.2f} | "
                f"{dev[:, sel].sum() / dev[:, good].sum():.2f} |"
            )
    held = scene.splits.get(args.split)
    if held is None or not held.has_images:
        return
    render = run_renderer(args.run) if args.run else None
    extra = (" the run's render |", "---:|") if render else ("", "")
    print(f"\n| {args.split} photo | table points | PSNR against the mean colour | with its gain fitted |{extra[0]}")
    print(f"|---|---:|---:|---:|{extra[1]}")
    for i in range(len(held)):
        col, ok = sample_photo(held.images[i], held.K[i], held.c2w[i], pts, bounds.object_box)
        ok &= good
        if ok.sum() < 10:
            continue
        gain = (col[ok] * mean[ok]).sum(0) / np.maximum((mean[ok] ** 2).sum(0), 1e-12)
        name = held.names[i] if held.names else str(i)
        row = (
            f"| {name} | {ok.sum()} | {psnr(((col[ok] - mean[ok]) ** 2).mean()):.2f} | "
            f"{psnr(((col[ok] - gain * mean[ok]) ** 2).mean()):.2f} |"
        )
        if render:
            rendered, _ = sample_photo(render(held, i), held.K[i], held.c2w[i], pts, bounds.object_box)
            row += f" {psnr(((col[ok] - rendered[ok]) ** 2).mean()):.2f} |"
        print(row)


def run_renderer(run: str):
    """``render(views, i) -> (H, W, 3) uint8``: the run's render of a view at its given pose."""
    from types import SimpleNamespace

    from nerfkit.commands._common import open_run
    from nerfkit.images import to_uint8
    from nerfkit.output.images import render_image

    opened = open_run(SimpleNamespace(run=run, device="auto", chunk=0))

    def render(views, i: int) -> np.ndarray:
        view = render_image(
            opened.model,
            views.K[i],
            views.c2w[i],
            views.width,
            views.height,
            opened.background(),
            opened.chunk,
            opened.autocast,
        )
        return to_uint8(view.rgb)

    return render


if __name__ == "__main__":
    main()
