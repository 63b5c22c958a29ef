"""The viewer in small steps: the picture's name, a run folder's live viewer, the tag size a
capture records, and the training view whose rays are drawn."""

from __future__ import annotations

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


def serve_run(
    run: Path,
    host: str,
    port: int,
    rays: int | None,
    rays_from: int | None,
    downscale: float | None,
    png: Path | None,
    block: bool,
) -> None:
    """Serve the live viewer of the trained ``run`` until Ctrl-C; the options that draw datasets
    are refused, and so is a viewer that would not block (it renders on the calling thread)."""
    from ...errors import fail

    if downscale:
        raise fail("--downscale", "a trained run loads its dataset as it was trained", "Leave out --downscale")
    if rays or rays_from is not None:
        raise fail(
            "--rays" if rays else "--rays-from",
            "the live viewer of a trained run draws its cameras and renders, not rays",
            "View the run's dataset for its rays: nerfkit view DATASET --rays N",
        )
    if png:
        raise fail(run, "--png draws datasets; this is a trained run", "Pass the run's dataset instead")
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
    serve_live(run, host=host, port=port)


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
