"""The evaluation stage in small steps: how held-out views are scored, the contact sheet and
the printed summary."""

from __future__ import annotations

import math
from typing import Any, cast

# views listed one by one up to this many; beyond, the lowest and highest few
LISTED_VIEWS = 20


def fit_steps(capture: bool, fit_views: int | None) -> int:
    """Steps each held-out view's pose is fitted for: ``fit_views``, else 100 for a capture's
    run and 0 otherwise (a model that renders whole views, splat, fits its pose from whole
    renders: :func:`~nerfkit.train.view_corrections.fit_whole_view`)."""
    if fit_views is not None:
        return fit_views
    return 100 if capture else 0


def held_out_views(scene: Any, split: str) -> Any:
    """The ``split`` views of ``scene``; refused when they have no images to compare with."""
    from ...errors import fail

    views = scene.splits[split]
    if not views.has_images:
        other = scene.split_with_images(split)
        raise fail(
            scene.source,
            f"the {split} split has no images to compare with",
            f"Choose a split with images (--split {other})" if other else None,
        )
    return views


def scores(opened: Any, scene: Any, split: str, steps: int, sheet: list) -> dict[str, Any]:
    """What eval_<split>.json holds for the run ``opened`` (:class:`~nerfkit.commands._common.OpenRun`)
    on ``scene``'s ``split``: the means and each view's scores, each view's pose fitted for
    ``steps`` (0: not), and for a capture the object's own pixels. ``sheet`` gets the contact
    sheet's rows."""
    from ...models.base import NerfModel
    from ...surroundings import object_alone
    from ...train.evaluate import evaluate_views
    from ...train.view_corrections import ViewFitConfig

    capture = getattr(opened.info.train, "capture", "off") == "on"
    whole = bool(getattr(opened.model, "whole_images", False))
    fit = ViewFitConfig(steps=steps) if steps else None  # (a gain and offset per channel: see evaluate)
    alone = object_alone(opened.model) if capture and not whole else None  # (a copy: memory for a second model)
    colour = opened.model.appearance
    return {
        "split": split,
        "step": opened.step,
        "data": scene.source,
        "colour": "the scene's own"
        if colour is None
        else "the training photos' colour corrections near each view's direction, weighted by a Gaussian "
        f"of the angle of {math.degrees(colour.width):.1f} degrees",
        **evaluate_views(
            opened.model,
            scene.splits[split],
            opened.background(),
            opened.chunk,
            opened.autocast,
            fit=fit,
            scale=opened.info.bounds.radius,
            sheet=sheet,
            alone=cast("NerfModel", alone.model) if alone is not None and alone.left_out else None,
        ),
    }


def write_contact_sheet(path, sheet: list, split: str) -> None:
    """Photo beside render (and beside the render with its pose fitted and each half's colour
    solved on the other half), a row per view,
    at the photos' own size (up to 640 pixels wide) so that sharpness can be judged."""
    from ...viz.plots import image_grid, native_tile_inches

    images, titles = [], []
    for photo, render, fitted, row in sheet:
        name = row["name"] or f"view {row['index']}"
        images += [photo, render]
        titles += [f"{name[:28]}", f"render {row['psnr']:.1f} dB"]
        if fitted is not None:
            images.append(fitted)
            titles.append(f"pose fitted, colour from the other half {row['psnr_fitted']:.1f} dB")
    if images:
        image_grid(
            path,
            images,
            titles,
            ncols=3 if sheet[0][2] is not None else 2,
            suptitle=f"{split} photos and renders",
            tile_inches=native_tile_inches(images[0]),
        )


def summary(result: dict) -> str:
    """``nerfkit eval``'s printed report of its ``result`` (what eval_<split>.json holds)."""
    lines = [
        f"{result['split']}: {result['n_images']} views at step {result['step']}: "
        f"PSNR {result['psnr']:.2f} dB, SSIM {result['ssim']:.3f}"
    ]
    fitted, colour, obj = result.get("fitted"), result.get("colour_only"), result.get("object")
    if fitted:
        lines.append(
            f"  with each view's pose fitted, and each half's colour solved on the other half: "
            f"{fitted['psnr']:.2f} dB / "
            f"{fitted['ssim']:.3f}" + (f" (its colour alone: {colour['psnr']:.2f} dB)" if colour else "")
        )
    if obj and obj.get("psnr") is not None:
        lines.append(
            f"  the object's own pixels: {obj['psnr']:.2f} dB"
            + (f", {obj['psnr_fitted']:.2f} fitted" if obj.get("psnr_fitted") is not None else "")
        )
    views = result.get("per_image", [])
    columns = "(PSNR dB, SSIM" + (", fitted PSNR):" if fitted else "):")
    if len(views) > LISTED_VIEWS:
        half = LISTED_VIEWS // 2
        ranked = sorted(views, key=lambda v: v["psnr"])
        shown = ranked[:half] + ranked[-half:]
        lines.append(f"  the {half} lowest and highest of {len(views)} views {columns}")
    else:
        shown = views
        lines.append(f"  per view {columns}")
    for v in shown:
        name = v.get("name") or f"view {v['index']}"
        lines.append(
            f"    {name[:32]:32s} {v['psnr']:6.2f}  {v['ssim']:.3f}"
            + (f"  {v['psnr_fitted']:6.2f}" if v.get("psnr_fitted") is not None else "")
        )
    return "\n".join(lines)
