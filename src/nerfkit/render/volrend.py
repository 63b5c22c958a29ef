"""Volume rendering (emission-absorption), as in NeRF.

For samples i along a ray with density sigma_i, colour c_i and interval length delta_i::

    alpha_i = 1 - exp(-sigma_i * delta_i)
    T_i     = exp(-sum_{j < i} sigma_j * delta_j)        (transmittance)
    w_i     = T_i * alpha_i
    C       = sum_i w_i * c_i  +  T_final * background

All functions take flat tensors: (n_rays, n_samples) for per-sample scalars and
(n_rays, n_samples, 3) for colours.
"""

from __future__ import annotations

import torch
from torch import Tensor


def exclusive_cumsum(x: Tensor) -> Tensor:
    """Sum of the earlier entries along the last axis: ``out[..., i] = sum_{j < i} x[..., j]``.

    Shifts before summing, so a large entry never enters the sums in front of it:
    ``cumsum(x) - x`` would cancel in float32 (x = [0.25, 0.25, 1e9] gives 0 instead of
    0.5 at the last entry). Shape in = shape out, (..., n).
    """
    total = torch.cumsum(x, dim=-1)
    return torch.cat([torch.zeros_like(total[..., :1]), total[..., :-1]], dim=-1)


def render_weights(sigmas: Tensor, deltas: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Compositing weights from densities.

    Args:
        sigmas: (n_rays, n_samples) non-negative densities.
        deltas: (n_rays, n_samples) interval lengths (or broadcastable, e.g. a scalar).

    Returns:
        ``(weights, transmittance, alphas)``, each (n_rays, n_samples); the
        transmittance is the light reaching each sample *before* it.

    Example: one sample with sigma=1e10 takes all the weight (w = 1) and every later
    sample gets w = 0.
    """
    tau = sigmas * deltas  # optical thickness of each interval
    alphas = -torch.expm1(-tau)
    accum = exclusive_cumsum(tau)  # thickness in front of each sample
    transmittance = torch.exp(-accum)
    weights = transmittance * alphas
    return weights, transmittance, alphas


def composite(
    weights: Tensor,
    rgbs: Tensor,
    t: Tensor | None = None,
    background: Tensor | float | None = None,
) -> tuple[Tensor, Tensor | None, Tensor]:
    """Accumulate colour (and expected depth) along rays.

    Args:
        weights: (n_rays, n_samples) from :func:`render_weights`.
        rgbs: (n_rays, n_samples, 3) sample colours.
        t: optional (n_rays, n_samples) sample distances, for the expected depth.
        background: optional colour (3,) or scalar filling the transmittance left over.

    Returns:
        ``(rgb, depth, acc)``: (n_rays, 3) colour, (n_rays,) expected depth
        ``sum w_i t_i`` (None without ``t``), and (n_rays,) opacity ``sum w_i``.
    """
    acc = weights.sum(dim=-1)
    rgb = (weights.unsqueeze(-1) * rgbs).sum(dim=-2)
    if background is not None:
        bg = torch.as_tensor(background, dtype=rgb.dtype, device=rgb.device)
        rgb = rgb + (1.0 - acc).unsqueeze(-1) * bg
    depth = (weights * t).sum(dim=-1) if t is not None else None
    return rgb, depth, acc


def distortion(weights: Tensor, t: Tensor, interval: Tensor | float, t_end: Tensor | None = None) -> Tensor:
    """mip-NeRF 360's distortion loss of each ray: small when its weight is compact.

    ``L = sum_ij w_i w_j |t_i - t_j| + (1/3) sum_i w_i^2 delta_i`` over the samples, in
    O(n_samples) with prefix sums. With ``t_end`` the weight left over, ``1 - sum_i w_i``,
    counts as one more sample at ``t_end`` (an opaque surface behind the samples, such as
    a capture's table): weight spread between the table and the space in front of it
    (haze) then costs as much as weight spread along the samples. ``inf`` entries of
    ``t_end`` add no such sample.

    Args:
        weights: (n_rays, n_samples) compositing weights (0 for padding).
        t: (n_rays, n_samples) sample distances, increasing along each ray.
        interval: interval lengths, (n_rays, n_samples) or a scalar.
        t_end: optional (n_rays,) distance of the surface behind the samples.

    Returns:
        (n_rays,) the loss, in the units of ``t``. Example: all weight in one sample of
        interval 1 gives 1/3; half the weight there and half at ``t_end`` 2 further
        gives ``2 * 0.5 * 0.5 * 2 + 0.25 / 3``.
    """
    wt = weights * t
    w_before = exclusive_cumsum(weights)
    wt_before = exclusive_cumsum(wt)
    loss = 2.0 * (weights * (t * w_before - wt_before)).sum(-1) + (weights ** 2 * interval).sum(-1) / 3.0
    if t_end is not None:
        rest = (1.0 - weights.sum(-1)).clamp(min=0.0)
        end = torch.isfinite(t_end)
        te = torch.where(end, t_end, torch.zeros_like(t_end))
        tail = 2.0 * rest * (te * weights.sum(-1) - wt.sum(-1))
        loss = loss + torch.where(end, tail, torch.zeros_like(tail))
    return loss


def volrend(sigmas: Tensor, rgbs: Tensor, step_size: Tensor | float, background: Tensor | float | None = None) -> Tensor:
    """The course's volume renderer.

    Args:
        sigmas: (n_rays, n_samples, 1) or (n_rays, n_samples) densities.
        rgbs: (n_rays, n_samples, 3) colours.
        step_size: scalar or (n_rays, n_samples) interval lengths.
        background: optional colour for light that passes through.

    Returns:
        (n_rays, 3) rendered colours.
    """
    if sigmas.dim() == rgbs.dim():
        sigmas = sigmas.squeeze(-1)
    weights, _, _ = render_weights(sigmas, torch.as_tensor(step_size, dtype=sigmas.dtype, device=sigmas.device))
    rgb, _, _ = composite(weights, rgbs, background=background)
    return rgb
