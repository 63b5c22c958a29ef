"""The viewer in small steps: the picture's name, a run folder's live viewer, the tag size a
capture records, and the training view whose rays are drawn."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any


def check_png(png: Path | None) -> None:
    """Refuse a picture ``png`` named as a folder or not as a PNG."""
    from ...errors import fail

    if png is None:
        return
    if png.is_dir():
        raise fail("--png", f"{png} is a folder", f"Name a PNG file, e.g. {png / 'scene.png'}")
    if png.suffix.lower() != ".png":
        raise fail("--png", f"'{png}' should end in .png (the picture is a PNG)")


@dataclass(frozen=True)
class RunOptions:
    """The options of ``view`` that draw datasets, none of which a run's live viewer takes."""

    rays: int | None
    rays_from: int | None
    samples: int | None
    downscale: float | None
    png: Path | None
    force: bool


def refuse_run_file(path: Path) -> None:
    """Refuse a run's ``config.json`` (or another of its files) named instead of its folder."""
    from ...data.load import is_run_folder, is_run_in_training
    from ...errors import fail

    folder = path.parent
    if path.is_file() and (is_run_folder(folder) or is_run_in_training(folder)):
        raise fail(path, "is a file of a trained run", f"Pass the run's folder to view it live: nerfkit view {folder}")


def serve_run(
    run: Path,
    host: str,
    port: int,
    options: RunOptions,
    block: bool,
    allow_outside_paths: bool = False,
    quiet: bool = False,
) -> None:
    """Serve the live viewer of the trained ``run`` until Ctrl-C; the options that draw datasets
    are refused, and so is a viewer that would not block (it renders on the calling thread)."""
    from ...errors import fail

    if options.downscale:
        raise fail("--downscale", "a trained run loads its dataset as it was trained", "Leave out --downscale")
    given = [
        flag
        for flag, value in (
            ("--rays", options.rays),
            ("--rays-from", options.rays_from),
            ("--samples", options.samples),
        )
        if value is not None
    ]
    if given:
        raise fail(
            given[0],
            "the live viewer of a trained run draws its cameras and renders, not rays",
            "View the run's dataset for its rays: nerfkit view DATASET --rays N",
        )
    if options.png or options.force:
        raise fail(
            run,
            f"{'--png' if options.png else '--force'} is for a dataset's picture; this is a trained run",
            f"Pass the run's dataset instead: nerfkit view {_run_dataset(run) or 'DATASET'}"
            f"{' --png ' + str(options.png) if options.png else ''}",
        )
    if not block:
        raise fail(
            run,
            "is a trained run: its live viewer renders on the calling thread until Ctrl-C",
            "Pass block=True (or run nerfkit view RUN)",
        )
    try:
        from ..live import serve_run as serve_live
    except ImportError:
        raise fail(
            run,
            "is a trained run, but the live viewer (nerfkit.commands.live) is not available in this build",
            "View its dataset instead: nerfkit view DATASET",
        ) from None
    serve_live(run, host=host, port=port, allow_outside_paths=allow_outside_paths, quiet=quiet)


def dataset_tag_size(path: Path) -> float | None:
    """The tag size a capture dataset records (transforms.json beside it), if any."""
    from ...data.nerfstudio import nerfkit_block

    v = (nerfkit_block(path if path.is_dir() else path.parent) or {}).get("tag_size")
    return float(v) if isinstance(v, (int, float)) and v > 0 else None


def check_rays_from(scene: Any, rays_from: int | None) -> None:
    """Refuse ``rays_from`` when ``scene`` has no such training view."""
    from ...errors import fail

    if rays_from is not None and rays_from >= len(scene.train):
        raise fail(
            "--rays-from",
            f"the dataset has {len(scene.train)} training views (0 to {len(scene.train) - 1}), not a view {rays_from}",
            "Give a training view's number",
        )


def _run_dataset(run: Any) -> str | None:
    """The dataset ``run`` was trained on, as its config.json records it; None when unknown."""
    from ...errors import NerfkitError
    from ...train.checkpoint import read_run

    try:
        return read_run(run).train.data or None
    except (NerfkitError, OSError, ValueError):
        return None
