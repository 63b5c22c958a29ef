"""Which captures show a plain object, before training and after.

Before training, ``nerfkit.object_detail.object_detail`` finds the object's pixels by the
photos' disagreement about the table behind them and takes the median brightness gradient
there and on the table: a plain object widens the box ``fast``'s grid starts from.
Given a run trained on the capture, this checks that figure against the object the run
learned: the run draws its object alone (``nerfkit.surroundings.object_alone``) from the
cameras of up to 6 training photos, and where that drawing is over half opaque (shrunk by 2
pixels) are the object's own pixels; the same median gradient over them, and over the
photos' white paper (bright, unsaturated pixels: the sheet under the tags), which is what
the camera's noise and the paper's grain alone give.

    python benchmarks/plain_objects.py --capture NAME=DATASET[:RUN] [...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from nerfkit.errors import NerfkitError
from nerfkit.object_detail import gradient_magnitude

# bright and unsaturated: a pixel of white paper (grey level, max - min of the channels)
PAPER_GREY, PAPER_SATURATION = 0.6, 0.12


def paper_mask(rgb: np.ndarray, shrink: int = 4) -> np.ndarray:
    """(H, W) bool: white paper in ``rgb`` (H, W, 3) in [0, 1] (grey at least
    :data:`PAPER_GREY`, channels within :data:`PAPER_SATURATION`), shrunk by ``shrink``
    pixels away from anything else."""
    grey = rgb.mean(-1)
    spread = rgb.max(-1) - rgb.min(-1)
    return shrunk((grey >= PAPER_GREY) & (spread <= PAPER_SATURATION), shrink)


def shrunk(mask: np.ndarray, by: int) -> np.ndarray:
    """``mask`` (H, W) bool without its pixels within ``by`` pixels of its outside."""
    if by <= 0:
        return mask.astype(bool)
    kernel = np.ones((2 * by + 1, 2 * by + 1), np.uint8)
    return cv2.erode(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_REPLICATE).astype(bool)


def median_over(values: np.ndarray, mask: np.ndarray, least: int = 200) -> float | None:
    """The median of ``values`` where ``mask`` holds, or None over fewer than ``least`` pixels."""
    return float(np.median(values[mask])) if int(mask.sum()) >= least else None


def object_masks(model, views, picks: np.ndarray, stride: int = 2) -> list[np.ndarray]:
    """(H, W) bool per picked view: where ``model`` (an object alone) is over half opaque,
    drawn every ``stride`` pixels and shrunk by 2 pixels at the full size."""
    import torch

    from nerfkit.cameras import strided_camera
    from nerfkit.output.images import render_image

    background = torch.zeros(3)
    masks = []
    for i in picks:
        K, w, h = strided_camera(views.K[i], views.width, views.height, stride)
        out = render_image(model, K, views.c2w[i], w, h, background)
        assert out is not None
        opaque = (np.asarray(out.acc).reshape(h, w) > 0.5).astype(np.uint8)
        full = np.repeat(np.repeat(opaque, stride, 0), stride, 1)[: views.height, : views.width]
        masks.append(shrunk(full, 2))
    return masks


def learned_row(views, masks: list[np.ndarray], picks: np.ndarray) -> dict:
    """The medians over the picked photos of the learned object's share of the photo and the
    median gradient on it and on the paper beside it (None where too few pixels)."""
    share, on_object, on_paper = [], [], []
    for i, mask in zip(picks, masks, strict=True):
        rgb = views.images[i][..., :3].astype(np.float32) / 255.0
        grad = gradient_magnitude(rgb)
        share.append(float(mask.mean()))
        on_object.append(median_over(grad, mask))
        on_paper.append(median_over(grad, paper_mask(rgb) & ~mask))

    def mid(xs):
        xs = [x for x in xs if x is not None]
        return float(np.median(xs)) if xs else None

    return {"learned_share": mid(share), "learned": mid(on_object), "paper": mid(on_paper)}


COLUMNS = [
    ("capture", "capture", None),
    ("before training: on the object", "object", ".4f"),
    ("on the table", "table", ".4f"),
    ("plain", "plain", None),
    ("on the learned object", "learned", ".4f"),
    ("its share of a photo", "learned_share", ".3f"),
    ("on the paper", "paper", ".4f"),
]


def table_markdown(rows: list[dict]) -> str:
    lines = ["| " + " | ".join(c[0] for c in COLUMNS) + " |", "|---|" + "---:|" * (len(COLUMNS) - 1)]
    for r in rows:
        cells = []
        for _, key, fmt in COLUMNS:
            v = r.get(key)
            cells.append(
                "-"
                if v is None
                else (format(v, fmt) if fmt else ("yes" if v is True else "no" if v is False else str(v)))
            )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def parse_capture(text: str) -> tuple[str, Path, Path | None]:
    """``NAME=DATASET`` or ``NAME=DATASET:RUN`` -> (name, dataset, run folder or None)."""
    name, sep, rest = text.partition("=")
    dataset, _, run = rest.partition(":")
    if not (sep and name and dataset):
        raise NerfkitError(f"--capture {text!r}: expected NAME=DATASET or NAME=DATASET:RUN")
    return name, Path(dataset), Path(run) if run else None


def capture_row(name: str, scene, run: Path | None, photos: int) -> dict:
    from nerfkit.object_detail import scene_object_detail

    row: dict = {"capture": name}
    detail = scene_object_detail(scene)
    if detail is not None:
        row.update(object=detail.on_object, table=detail.on_table, plain=detail.plain)
    if run is not None:
        from nerfkit.commands._common import RunToOpen, open_run
        from nerfkit.surroundings import object_alone

        views = scene.train
        model = object_alone(open_run(RunToOpen(str(run), "cpu", 16384)).model).model
        picks = np.unique(np.linspace(0, len(views) - 1, min(photos, len(views))).astype(int))
        row.update(learned_row(views, object_masks(model, views, picks), picks))
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--capture",
        action="append",
        default=[],
        metavar="NAME=DATASET[:RUN]",
        help="a capture, and a run trained on it",
    )
    ap.add_argument("--photos", type=int, default=6, help="training photos a run's object is drawn from")
    args = ap.parse_args()
    if not args.capture:
        ap.error("give at least one --capture NAME=DATASET[:RUN]")
    from nerfkit.data.load import load_scene

    rows = []
    try:
        for text in args.capture:
            name, dataset, run = parse_capture(text)
            rows.append(capture_row(name, load_scene(dataset), run, args.photos))
    except NerfkitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(table_markdown(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
