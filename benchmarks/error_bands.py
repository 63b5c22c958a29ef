"""Where a run's held-out error lies: in the broad shading or in the fine detail.

Each held-out photo's error (render as the eval renders it, minus the photo) is split by a
Gaussian blur of ``--sigma`` pixels into its low frequencies (the blurred error: exposure,
shading, a shadow) and the rest, its high frequencies (edges, texture, grain), and each part
is printed as a PSNR beside the whole. Two runs side by side show which part one model gets
right and the other wrong: a model that paints light where the photos disagree scores lower
in the low band; one that blurs, misplaces or loses texture scores lower in the high band.
The two parts' mean squared errors add up to about the whole's (they are nearly orthogonal).
With ``--tags``, the high band is also scored apart over the printed tags of a capture (each
tag's square grown by ``TAG_GROWTH`` about its centre, to take in its paper) and elsewhere.

    python benchmarks/error_bands.py RUN [RUN ...] [--split val] [--sigma 4] [--tags]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from nerfkit.train.metrics import psnr_from_mse

# --tags: a tag's square grown this much about its centre covers its printed paper's margin
TAG_GROWTH = 1.5


def split_error(render: np.ndarray, photo: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(err, low, high)`` (H, W, 3) each: the error ``render - photo``, that error blurred by a
    Gaussian of ``sigma`` pixels (its low frequencies) and what the blur removed (its high)."""
    err = render.astype(np.float32) - photo.astype(np.float32)
    low = cv2.GaussianBlur(err, (0, 0), sigma)
    return err, low, err - low


def error_bands(render: np.ndarray, photo: np.ndarray, sigma: float = 4.0) -> tuple[float, float, float]:
    """``(whole, low, high)`` PSNRs (dB) of ``render`` against ``photo``, both (H, W, 3) in
    [0, 1]: of the error and of its two bands (:func:`split_error`)."""
    err, low, high = split_error(render, photo, sigma)
    whole, low_psnr, high_psnr = (psnr_from_mse(float(np.mean(x**2))) for x in (err, low, high))
    return whole, low_psnr, high_psnr


def tag_mask(K: np.ndarray, c2w: np.ndarray, tags: np.ndarray, width: int, height: int) -> np.ndarray:
    """(height, width) bool: the pixels of a view (``K``, ``c2w``) over the printed tags
    ``tags`` (n, 4, 3), each square grown by :data:`TAG_GROWTH` about its centre; tags
    behind the camera cover nothing."""
    from nerfkit.cameras import project_points

    mask = np.zeros((height, width), np.uint8)
    for quad in np.asarray(tags, np.float64):
        centre = quad.mean(0)
        uv, z = project_points(K, c2w, centre + TAG_GROWTH * (quad - centre))
        if (z > 0).all():  # (pixel (col, row) covers [col, col + 1): its centre is at + 0.5)
            cv2.fillConvexPoly(mask, np.round(uv - 0.5).astype(np.int32), 1)
    return mask.astype(bool)


def masked_high(render: np.ndarray, photo: np.ndarray, mask: np.ndarray, sigma: float = 4.0) -> tuple[float, float]:
    """``(inside, outside)`` PSNRs (dB) of the high band of ``render - photo`` (as
    :func:`error_bands`) over the pixels of ``mask`` (H, W) and over the rest (nan: none)."""
    high = split_error(render, photo, sigma)[2]

    def part(values: np.ndarray) -> float:
        return psnr_from_mse(float(np.mean(values**2))) if values.size else float("nan")

    return part(high[mask]), part(high[~mask])


def open_split(run: str, split: str, own_colour: bool = False):
    """Open ``run`` for scoring its dataset's ``split``: ``(scene, views, render)``, where
    ``render(i)`` is view ``i`` as ``eval`` renders it, (H, W, 3) float in [0, 1]; with
    ``own_colour``, in the scene's own colour (not the training photos' near the view)."""
    from nerfkit.commands._common import RunToOpen, open_run, scene_for_run
    from nerfkit.output.images import render_image

    opened = open_run(RunToOpen(run, "cpu", 16384))
    if own_colour:
        opened.model.appearance = None
    scene = scene_for_run(opened.info, None, need=split)
    views = getattr(scene, split)

    def render(i: int) -> np.ndarray:
        view = render_image(
            opened.model, views.K[i], views.c2w[i], views.width, views.height, opened.background(), opened.chunk
        )
        assert view is not None  # (None only when aborted)
        return np.clip(view.rgb, 0.0, 1.0)

    return scene, views, render


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", metavar="RUN", help="run folders (nerfkit train --out)")
    ap.add_argument("--split", default="val", choices=("val", "test", "train"), help="the views to score")
    ap.add_argument("--sigma", type=float, default=4.0, help="blur between the bands, in pixels")
    ap.add_argument("--tags", action="store_true", help="also the high band over the printed tags and elsewhere")
    args = ap.parse_args()

    tag_columns = " high over the tags | high elsewhere |" if args.tags else ""
    print(f"| run | view | whole | low (sigma {args.sigma:g} px) | high |" + tag_columns)
    print("|---|---|---:|---:|---:|" + ("---:|---:|" if args.tags else ""))
    for run in args.runs:
        scene, views, render = open_split(run, args.split)
        if args.tags and scene.tags is None:
            raise SystemExit(f"{run}: its dataset records no printed tags: leave out --tags")
        bands = []
        for i in range(len(views)):
            photo = views.images[i].astype(np.float32) / 255.0
            rgb = render(i)
            bands.append(error_bands(rgb, photo, args.sigma))
            if args.tags:
                mask = tag_mask(views.K[i], views.c2w[i], scene.tags, views.width, views.height)
                bands[-1] += masked_high(rgb, photo, mask, args.sigma)
            print(f"| {run} | {views.names[i]} | " + " | ".join(f"{b:.2f}" for b in bands[-1]) + " |")
        mean = np.nanmean(np.array(bands), axis=0)
        print(f"| {run} | mean of {len(bands)} | " + " | ".join(f"**{b:.2f}**" for b in mean) + " |")


if __name__ == "__main__":
    main()
