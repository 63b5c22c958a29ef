"""Plots as PNG files (matplotlib, headless): training curves, contact sheets, where the photos look from."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_path


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_curves(
    path: str | Path,
    series: dict[str, tuple[Sequence[float], Sequence[float]]],
    xlabel: str,
    ylabel: str,
    title: str = "",
    logy: bool = False,
) -> None:
    """Line plot of several named (x, y) series, written atomically to ``path`` (PNG); a
    series of one point is drawn as a dot."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
    for label, (x, y) in series.items():
        if len(x):
            ax.plot(np.asarray(x), np.asarray(y), label=label, linewidth=1.4, marker="o" if len(x) == 1 else None)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if logy:
        ax.set_yscale("log")
    if title:
        ax.set_title(title)
    ax.grid(alpha=0.3)
    if len(series) > 1:
        ax.legend()
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


# dots per inch of image_grid's figures
GRID_DPI = 110


def native_tile_inches(image: np.ndarray, most: int = 640, least: int = 240) -> float:
    """The tile width (inches, at ``GRID_DPI``) that shows ``image`` at its own pixel width,
    between ``least`` pixels (room for a tile's title) and ``most``: a contact sheet meant
    to judge sharpness should not shrink it."""
    return min(max(image.shape[1], least), most) / GRID_DPI


def image_grid(
    path: str | Path,
    images: Sequence[np.ndarray],
    titles: Sequence[str],
    ncols: int | None = None,
    suptitle: str = "",
    tile_inches: float = 2.6,
) -> None:
    """A labelled grid of images (float [0, 1] or uint8), written atomically as PNG.

    Each tile is ``tile_inches`` wide (at ``GRID_DPI`` dots per inch) and as tall as the
    first image's aspect ratio makes it, so photos are not letterboxed in square tiles.
    Tiles are placed by hand, each under a band of its own for its title (a layout
    engine packed the rows so tightly that a title overprinted the image above it).
    """
    plt = _pyplot()
    n = len(images)
    ncols = ncols or n
    nrows = (n + ncols - 1) // ncols
    h, w = images[0].shape[:2]
    tile_h = tile_inches * h / max(w, 1)
    head = 0.45 if suptitle else 0.05  # inches kept for the title above the grid
    band, gap = 0.25, 0.08  # inches: a tile's title band; the margin around and between tiles
    fig_w = ncols * tile_inches + (ncols + 1) * gap
    fig_h = head + nrows * (band + tile_h) + gap
    fig = plt.figure(figsize=(fig_w, fig_h), dpi=GRID_DPI)
    for k, (img, title) in enumerate(zip(images, titles)):
        row, col = divmod(k, ncols)
        left = gap + col * (tile_inches + gap)
        bottom = fig_h - head - (row + 1) * (band + tile_h)
        ax = fig.add_axes((left / fig_w, bottom / fig_h, tile_inches / fig_w, tile_h / fig_h))
        ax.axis("off")
        ax.imshow(img, cmap="gray" if img.ndim == 2 else None)
        ax.set_title(title, fontsize=9, pad=3)
    if suptitle:
        fig.suptitle(suptitle, y=1.0 - 0.1 / fig_h, va="top")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


# marker colour of each split in plot_coverage
SPLIT_COLOURS = {"train": "tab:blue", "val": "tab:orange", "test": "tab:green"}


def plot_coverage(path: str | Path, where: dict[str, np.ndarray], gaps: dict[str, np.ndarray], title: str = "") -> None:
    """Where the photos look from, seen from above: a polar chart with azimuth as the angle and
    90 - elevation as the radius (the centre looks straight down). ``where``: split -> (n, 2)
    azimuth and elevation of its photos, degrees; ``gaps``: label -> (m, 2) the outline of a gap,
    drawn as a dashed line. Written atomically as PNG."""
    plt = _pyplot()
    fig = plt.figure(figsize=(5.2, 5.4), dpi=110)
    ax = fig.add_subplot(projection="polar")
    for split, ae in where.items():
        if len(ae):
            ax.scatter(
                np.radians(ae[:, 0]),
                90.0 - ae[:, 1],
                s=18,
                label=f"{split} ({len(ae)})",
                color=SPLIT_COLOURS.get(split),
                zorder=3,
            )
    for (label, outline), colour in zip(gaps.items(), itertools.cycle(["tab:red", "tab:purple"])):
        ax.plot(np.radians(outline[:, 0]), 90.0 - outline[:, 1], "--", color=colour, linewidth=1.2, label=label)
    ax.set_rlim(0, 90)
    ax.set_rticks([30, 60, 90])
    ax.set_yticklabels(["60\u00b0 up", "30\u00b0", "0\u00b0"], fontsize=7)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.06), ncol=3, fontsize=7, frameon=False)
    if title:
        ax.set_title(title, fontsize=9, pad=14)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
