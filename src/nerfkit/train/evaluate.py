"""Evaluate a trained model on a split's images: PSNR and SSIM per image and mean.

For real captures the held-out photos' poses and exposures carry the same small errors
the training views had corrected; scoring them as given measures those errors as much as
the scene. With ``fit`` each held-out view's pose is first fitted to its photo with the
scene frozen (as BARF does); then each half of the photo (left, right) is scored with
the colour correction solved on the other half, as NeRF-W scores its test photos (both
ways here). A colour correction solved on the pixels it is scored on would also take up
the render's own errors there: solved on the whole of a val photo, an affine transform
gains several times what it gains on the half it was not solved on, and a gain and offset
per channel lies between (``eval``'s fitted score in BENCHMARKS.md). A third score lies
between: the colour alone, at the given pose
(how much of the difference is the photo's exposure, how much its pose). With a model of
the object alone (a capture's, :func:`~nerfkit.surroundings.object_alone`), the object's own
pixels are scored too: a capture's score is mostly its table's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..cameras import image_rays, rotation_angles_deg, strided_camera
from ..data.scene import Views
from ..images import write_image
from ..models.base import NerfModel
from ..output.images import render_image
from .config import eval_stride
from .metrics import masked_psnr, psnr, ssim
from .view_corrections import ViewFitConfig, fit_view, fit_whole_view, least_squares_colour, rounded


def fit_held_out_view(
    model: NerfModel,
    K: np.ndarray,
    c2w: np.ndarray,
    image: np.ndarray,
    background: torch.Tensor,
    scale: float,
    cfg: ViewFitConfig,
    seed: int = 0,
) -> np.ndarray:
    """Fit one held-out view's pose to its photo, the model frozen (its exposure is fitted
    alongside, so that a colour change does not pull the pose; :func:`least_squares_colour`
    then solves the colour at the fitted pose exactly).

    Args:
        K (3, 3), c2w (4, 4): the view's camera; image: (H, W, 3) uint8 photo.
        scale: the scene's length unit (the model's bounding radius).

    Returns:
        (4, 4) the corrected camera-to-world pose.
    """
    device = background.device
    h, w = image.shape[:2]
    K_t, c2w_t = torch.as_tensor(K, dtype=torch.float32), torch.as_tensor(c2w, dtype=torch.float32).to(device)
    target = torch.from_numpy(image.reshape(-1, 3).astype(np.float32) / 255.0).to(device)
    frozen = [p for p in model.parameters() if p.requires_grad]
    was_training = model.training
    model.eval()
    for p in frozen:
        p.requires_grad_(False)
    try:
        if model.whole_images:  # (splat: the whole view from the corrected camera, every step)
            whole: Any = model  # (render_view is the whole-view models' own)
            pose, _ = fit_whole_view(
                lambda pose: whole.render_view(K_t, pose, w, h, background).rgb.reshape(-1, 3),
                c2w_t,
                target,
                scale,
                cfg,
            )
        else:
            pose, _ = fit_view(
                lambda r: model.render_rays(r, background, perturb=False).rgb,
                image_rays(K_t, c2w_t, w, h),
                target,
                scale,
                cfg,
                torch.Generator().manual_seed(seed),
            )
    finally:
        for p in frozen:
            p.requires_grad_(True)
        model.train(was_training)
    return pose.corrected_c2w(np.asarray(c2w)[None])[0]


def photo_halves(width: int) -> tuple[slice, slice]:
    """The left and right halves of an image's columns (the right one takes an odd column)."""
    return slice(0, width // 2), slice(width // 2, width)


def score_val_views(
    model: NerfModel,
    val: Views,
    n_views: int | None,
    background: torch.Tensor,
    chunk: int,
    autocast_dtype: torch.dtype | None,
    eval_pixels: int,
    first_render: Path,
) -> tuple[list[float], int] | None:
    """PSNR of each of the first ``n_views`` ``val`` images and the pixels scored per view
    (None: ``val`` has no images, or no view is asked for), as training evaluates its model.

    With ``n_views`` (a periodic evaluation) every k-th pixel of each view is scored on an
    even grid, k from ``eval_pixels`` (:func:`~nerfkit.train.config.eval_stride`); with None
    every val image is scored whole. View 0's render (H/k, W/k, 3) goes to ``first_render``.
    """
    n = len(val) if n_views is None else min(n_views, len(val))
    if not val.has_images or n == 0:
        return None
    images = val.images
    assert images is not None  # (has_images)
    stride = 1 if n_views is None else eval_stride(val.width, val.height, n, eval_pixels)
    scores = []
    for i in range(n):
        K, w, h = strided_camera(val.K[i], val.width, val.height, stride)
        view = render_image(model, K, val.c2w[i], w, h, background, chunk, autocast_dtype)
        assert view is not None  # (None only when aborted; no abort here)
        target = images[i][::stride, ::stride].astype(np.float32) / 255.0
        scores.append(psnr(view.rgb, target))
        if i == 0:
            write_image(first_render, view.rgb)
    return scores, w * h


def evaluate_views(
    model: NerfModel,
    views: Views,
    background: torch.Tensor,
    chunk: int = 16384,
    autocast_dtype: torch.dtype | None = None,
    progress: bool = True,
    fit: ViewFitConfig | None = None,
    scale: float = 1.0,
    sheet: list | None = None,
    sheet_views: int = 6,
    alone: NerfModel | None = None,
) -> dict:
    """Render every view and compare with its image.

    Returns ``{"psnr": mean, "ssim": mean, "n_images": N, "per_image": [{index, name,
    psnr, ssim}, ...]}``; with ``fit``, also ``"fitted": {"psnr", "ssim", ...}`` and per
    image ``psnr_fitted``, ``ssim_fitted``: each view's pose fitted to its photo
    (``scale``: the scene's length unit), then each half of the render
    (:func:`photo_halves`) recoloured by the colour correction solved on the other half at
    that pose, with the mean of the two corrections: ``fitted_grey_gain`` (per channel, the
    gain a grey input sees: the row sums of the colour matrix), ``fitted_offset`` and, with
    ``fit.colour_mix``, ``fitted_colour_matrix`` (rows: output channels); and
    ``"colour_only"`` (per image ``psnr_colour``, ``ssim_colour``): the same at the given
    pose, no pose fit. Memory holds one image at a time, plus the images appended to
    ``sheet`` (``(photo, render, fitted render or None, row)`` of ``sheet_views`` views
    spread over the split), when a list is given. With ``alone`` (the model's object
    alone, a second model in memory), also ``"object"``: the PSNR over the pixels where
    ``alone`` renders opaque (opacity > 0.5) at the view's pose, as rendered and (with
    ``fit``, at the fitted pose) fitted, averaged over the views that see the object (per
    image ``object_share``, the share of its pixels, ``psnr_object`` and
    ``psnr_object_fitted``); it costs a render of the object alone per pose.
    """
    from tqdm import tqdm

    per_image = []
    shown = set(np.linspace(0, len(views) - 1, min(sheet_views, len(views))).round().astype(int).tolist())
    for i in tqdm(range(len(views)), desc="eval", unit="view", disable=None if progress else True):
        images = views.images
        assert images is not None  # (held-out views have photos)
        target = images[i].astype(np.float32) / 255.0
        view = render_image(
            model, views.K[i], views.c2w[i], views.width, views.height, background, chunk, autocast_dtype
        )
        assert view is not None  # (None only when aborted; no abort here)
        row = {"index": i, "name": views.names[i] if views.names else None, **_scores(view.rgb, target)}
        rgb = None
        if fit is not None:
            row.update(_scores(_cross_recoloured(view.rgb, target, fit.colour_mix)[0], target, "_colour"))
            c2w = fit_held_out_view(model, views.K[i], views.c2w[i], images[i], background, scale, fit, seed=i)
            fitted = render_image(model, views.K[i], c2w, views.width, views.height, background, chunk, autocast_dtype)
            assert fitted is not None
            rgb, matrix, offset = _cross_recoloured(fitted.rgb, target, fit.colour_mix)
            row.update(
                _scores(rgb, target, "_fitted"),
                fitted_rotation_deg=round(float(rotation_angles_deg(c2w[None], views.c2w[i][None])[0]), 4),
                fitted_translation=round(float(np.linalg.norm(c2w[:3, 3] - views.c2w[i][:3, 3])), 6),
                fitted_grey_gain=rounded(matrix.sum(axis=1)),
                fitted_offset=rounded(offset),
            )
            if fit.colour_mix:
                row["fitted_colour_matrix"] = [rounded(r) for r in matrix]
        if alone is not None:
            row.update(_object_scores(alone, views, i, view.rgb, target, background, chunk, autocast_dtype))
            if fit is not None:
                assert rgb is not None  # (set by the fit above)
                row.update(
                    _object_scores(alone, views, i, rgb, target, background, chunk, autocast_dtype, c2w, "_fitted")
                )
        if sheet is not None and i in shown:
            sheet.append((images[i], view.rgb, rgb, row))
        per_image.append(row)
    out = {**_means(per_image), "n_images": len(per_image)}
    if fit is not None:
        model_name = "an affine colour transform" if fit.colour_mix else "a gain and offset per channel"
        out["fitted"] = {
            "what": f"each view's pose fitted to its photo first ({fit.steps} steps, scene frozen), then each half "
            f"of the photo (left, right) scored with the colour correction ({model_name}, least squares) "
            "solved on the other half at that pose (NeRF-W's protocol, both ways)",
            **_means(per_image, "_fitted"),
        }
        out["colour_only"] = {
            "what": f"each half of the photo scored with the colour correction ({model_name}) "
            "solved on the other half at the view's given pose (no pose fit)",
            **_means(per_image, "_colour"),
        }
    if alone is not None:
        out["object"] = _object_means(per_image, fit is not None)
    out["per_image"] = per_image
    return out


def _object_scores(
    alone: NerfModel,
    views: Views,
    i: int,
    rgb: np.ndarray,
    target: np.ndarray,
    background: torch.Tensor,
    chunk: int,
    autocast_dtype,
    c2w: np.ndarray | None = None,
    suffix: str = "",
) -> dict:
    """``{"object_share" (as rendered only), "psnr_object" + suffix}``: the share of view
    ``i``'s pixels where the object alone is opaque at pose ``c2w`` (default: the view's),
    and ``rgb``'s PSNR against ``target`` there (None where it has none)."""
    pose = views.c2w[i] if c2w is None else c2w
    view = render_image(alone, views.K[i], pose, views.width, views.height, background, chunk, autocast_dtype)
    assert view is not None  # (None only when aborted; no abort here)
    solid = view.acc > 0.5
    score = masked_psnr(rgb, target, solid)
    row = {f"psnr_object{suffix}": None if score is None else round(score, 4)}
    if not suffix:
        row["object_share"] = round(float(solid.mean()), 5)
    return row


def _object_means(per_image: list[dict], fitted: bool) -> dict:
    """The object's scores, each averaged over the images that see the object at its pose
    (``n_images``; fitted: ``n_images_fitted``)."""

    def mean_of(key: str) -> tuple[float | None, int]:
        scores = [p[key] for p in per_image if p.get(key) is not None]
        return (round(float(np.mean(scores)), 4) if scores else None), len(scores)

    psnr_, n = mean_of("psnr_object")
    out = {
        "what": "PSNR over the pixels where the object alone (no table, floor or room) renders opaque",
        "n_images": n,
        "psnr": psnr_,
    }
    if fitted:
        out["psnr_fitted"], out["n_images_fitted"] = mean_of("psnr_object_fitted")
    return out


def _cross_recoloured(rgb: np.ndarray, target: np.ndarray, mix: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A render (H, W, 3) with each half (:func:`photo_halves`) recoloured by the correction
    that maps the other half best onto ``target`` (:func:`least_squares_colour`), clipped
    to [0, 1]; and the mean of the two corrections' matrices and offsets."""
    out, solved = np.empty_like(rgb), []
    halves = photo_halves(rgb.shape[1])
    for half, other in zip(halves, halves[::-1]):
        matrix, offset = least_squares_colour(rgb[:, other], target[:, other], mix)
        out[:, half] = np.clip(rgb[:, half] @ matrix.T + offset, 0.0, 1.0)
        solved.append((matrix, offset))
    matrix, offset = (np.mean(c, axis=0) for c in zip(*solved))
    return out, matrix, offset


def _scores(rgb: np.ndarray, target: np.ndarray, suffix: str = "") -> dict:
    """``{"psnr" + suffix, "ssim" + suffix}`` of one image, rounded as the report keeps them."""
    return {f"psnr{suffix}": round(psnr(rgb, target), 4), f"ssim{suffix}": round(ssim(rgb, target), 5)}


def _means(per_image: list[dict], suffix: str = "") -> dict:
    """``{"psnr", "ssim"}``: the means over the images of their ``psnr`` + suffix and ``ssim`` + suffix."""
    return {
        "psnr": round(float(np.mean([p[f"psnr{suffix}"] for p in per_image])), 4),
        "ssim": round(float(np.mean([p[f"ssim{suffix}"] for p in per_image])), 5),
    }
