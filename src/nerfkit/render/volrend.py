"""Volume rendering (emission-absorption), as in NeRF, over packed samples.

For samples i along a ray with density sigma_i, colour c_i and interval length delta_i::

    alpha_i = 1 - exp(-sigma_i * delta_i)
    T_i     = exp(-sum_{j < i} sigma_j * delta_j)        (transmittance)
    w_i     = T_i * alpha_i
    C       = sum_i w_i * c_i  +  T_final * background

**The packed layout** (nerfacc's): the samples of a batch of ``n_rays`` rays are flat
tensors of length ``n_samples``; ``ray_indices`` (n_samples,) long names each sample's
ray, is non-decreasing (a ray's samples are consecutive, in increasing ``t``), and a ray
may have no samples. Per-sample scalars are (n_samples,), colours (n_samples, 3). Every
ray holding the same number of samples (the course's stratified sampling) is the special
case :func:`regular_ray_indices`; :func:`volrend` keeps the course's (n_rays, n_samples)
signature on top of it.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from nerfkit.arrays import accepts_numpy


def tau_cap(dtype: torch.dtype) -> float:
    """The most optical depth one sample adds to the transmittance sums: ``exp(-cap)`` is
    ``tiny ** 2``, zero in ``dtype``, so the cap changes no result; it keeps the batch-wide
    float64 sums of :func:`exclusive_cumsum` well scaled (float32: 175)."""
    return -2.0 * math.log(torch.finfo(dtype).tiny)


def regular_ray_indices(n_rays: int, n_samples: int, device: torch.device | str | None = None) -> Tensor:
    """(n_rays * n_samples,) ray of each sample when every ray has ``n_samples`` (the
    row-major flattening of (n_rays, n_samples)). Example: (2, 3) -> [0, 0, 0, 1, 1, 1]."""
    return torch.arange(n_rays, device=device).repeat_interleave(n_samples)


def exclusive_cumsum(x: Tensor, ray_indices: Tensor) -> Tensor:
    """Sum of the earlier samples of the same ray: ``out[k] = sum of x[j]`` over ``j < k``
    with ``ray_indices[j] == ray_indices[k]``.

    Shifts before summing, so an entry never enters the sum in front of it (``cumsum(x) -
    x`` cancels in float32: x = [0.25, 0.25, 1e9] gives 0 instead of 0.5 at the last entry).
    The sums run over the whole batch in float64 and each ray subtracts its own start: a
    ray's result is exact to about 1e-16 times the sum over all rays before it.

    Args:
        x: (n_samples,) values; ray_indices: (n_samples,) non-decreasing.

    Returns:
        (n_samples,) in ``x``'s dtype. Example: x = [1, 2, 3, 4], rays [0, 0, 1, 1] ->
        [0, 1, 0, 3].
    """
    m = x.shape[0]
    if m == 0:
        return x.clone()
    total = torch.cumsum(x.to(torch.float64), dim=0)
    before = torch.cat([total.new_zeros(1), total[:-1]])  # sum over all earlier samples of the batch
    first = torch.ones(m, dtype=torch.bool, device=x.device)
    first[1:] = ray_indices[1:] != ray_indices[:-1]
    start = torch.where(first, torch.arange(m, device=x.device), torch.zeros_like(ray_indices))
    start = torch.cummax(start, dim=0).values  # index of the first sample of each sample's ray
    return (before - before[start]).to(x.dtype)


def render_weights(sigmas: Tensor, deltas: Tensor | float, ray_indices: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Compositing weights from densities.

    Args:
        sigmas: (n_samples,) non-negative densities.
        deltas: (n_samples,) interval lengths, or a scalar.
        ray_indices: (n_samples,) non-decreasing ray of each sample.

    Returns:
        ``(weights, transmittance, alphas)``, each (n_samples,); the transmittance is the
        light reaching each sample *before* it.

    Example: one sample with sigma=1e10 takes all the weight (w = 1) and every later
    sample of its ray gets w = 0.
    """
    tau = sigmas * deltas  # optical thickness of each interval
    alphas = -torch.expm1(-tau)
    transmittance = torch.exp(-exclusive_cumsum(tau.clamp(max=tau_cap(tau.dtype)), ray_indices))
    weights = transmittance * alphas
    return weights, transmittance, alphas


def accumulate(values: Tensor, ray_indices: Tensor, n_rays: int) -> Tensor:
    """Sum per ray: (n_samples,) or (n_samples, k) -> (n_rays,) or (n_rays, k); rays
    without samples get 0."""
    out = values.new_zeros((n_rays,) + tuple(values.shape[1:]))
    return out.index_add(0, ray_indices, values)


def composite(
    weights: Tensor,
    rgbs: Tensor,
    ray_indices: Tensor,
    n_rays: int,
    t: Tensor | None = None,
    background: Tensor | float | None = None,
) -> tuple[Tensor, Tensor | None, Tensor]:
    """Accumulate colour (and expected depth) along rays.

    Args:
        weights: (n_samples,) from :func:`render_weights`.
        rgbs: (n_samples, 3) sample colours.
        ray_indices: (n_samples,) ray of each sample; n_rays: the batch's rays.
        t: optional (n_samples,) sample distances, for the expected depth.
        background: optional colour (3,) or scalar filling the transmittance left over.

    Returns:
        ``(rgb, depth, acc)``: (n_rays, 3) colour, (n_rays,) expected depth
        ``sum w_i t_i`` (None without ``t``), and (n_rays,) opacity ``sum w_i``.
    """
    acc = accumulate(weights, ray_indices, n_rays)
    rgb = accumulate(weights.unsqueeze(-1) * rgbs, ray_indices, n_rays)
    if background is not None:
        bg = torch.as_tensor(background, dtype=rgb.dtype, device=rgb.device)
        rgb = rgb + (1.0 - acc).unsqueeze(-1) * bg
    depth = accumulate(weights * t, ray_indices, n_rays) if t is not None else None
    return rgb, depth, acc


def distortion(
    weights: Tensor, t: Tensor, interval: Tensor | float, ray_indices: Tensor, n_rays: int, t_end: Tensor | None = None
) -> Tensor:
    """mip-NeRF 360's distortion loss of each ray: small when its weight is compact.

    ``L = sum_ij w_i w_j |t_i - t_j| + (1/3) sum_i w_i^2 delta_i`` over the samples, in
    O(n_samples) with prefix sums. With ``t_end`` the weight left over, ``1 - sum_i w_i``,
    counts as one more sample at ``t_end`` (an opaque surface behind the samples, such as
    a capture's table): weight spread between the table and the space in front of it
    (haze) then costs as much as weight spread along the samples. ``inf`` entries of
    ``t_end`` add no such sample.

    Args:
        weights: (n_samples,) compositing weights.
        t: (n_samples,) sample distances, increasing along each ray.
        interval: interval lengths, (n_samples,) or a scalar.
        ray_indices: (n_samples,) ray of each sample; n_rays: the batch's rays.
        t_end: optional (n_rays,) distance of the surface behind the samples.

    Returns:
        (n_rays,) the loss, in the units of ``t``. Example: all weight in one sample of
        interval 1 gives 1/3; half the weight there and half at ``t_end`` 2 further
        gives ``2 * 0.5 * 0.5 * 2 + 0.25 / 3``.
    """
    wt = weights * t
    w_before = exclusive_cumsum(weights, ray_indices)
    wt_before = exclusive_cumsum(wt, ray_indices)
    per_sample = 2.0 * weights * (t * w_before - wt_before) + weights**2 * interval / 3.0
    loss = accumulate(per_sample, ray_indices, n_rays)
    if t_end is not None:
        w_sum = accumulate(weights, ray_indices, n_rays)
        rest = (1.0 - w_sum).clamp(min=0.0)
        end = torch.isfinite(t_end)
        te = torch.where(end, t_end, torch.zeros_like(t_end))
        tail = 2.0 * rest * (te * w_sum - accumulate(wt, ray_indices, n_rays))
        loss = loss + torch.where(end, tail, torch.zeros_like(tail))
    return loss


def sight_line_loss(empty: Tensor, stopped: Tensor) -> Tensor:
    """The loss of sight lines from cameras to sparse points they saw (DS-NeRF's idea, as
    opacities): what lies before a point must be empty, and a point on a surface must
    stop the ray.

    Args:
        empty: (n,) each line's opacity up to just before its point.
        stopped: (m,) for the lines whose point must stop them (m <= n), the opacity up to
            just past the point.

    Returns:
        scalar ``(sum(empty) + sum(1 - stopped)) / n``: 0 when every line is clear up to
        its point and stopped there, 1 per line for a line wholly blocked in front or
        wholly clear through its point.
    """
    n = max(len(empty), 1)
    return (empty.float().sum() + (1.0 - stopped.float()).sum()) / n


@accepts_numpy
def volrend(
    sigmas: Tensor, rgbs: Tensor, step_size: Tensor | float, background: Tensor | float | None = None
) -> Tensor:
    """The course's volume renderer, every ray with the same samples.

    Args:
        sigmas: (n_rays, n_samples, 1) or (n_rays, n_samples) densities.
        rgbs: (n_rays, n_samples, 3) colours.
        step_size: scalar or (n_rays, n_samples[, 1]) interval lengths.
        background: optional colour for light that passes through.

    Returns:
        (n_rays, 3) rendered colours.
    """
    if sigmas.dim() == 3 and sigmas.shape[-1] == 1:
        sigmas = sigmas.squeeze(-1)
    if sigmas.dim() != 2 or tuple(rgbs.shape) != (*sigmas.shape, 3):
        raise ValueError(
            f"volrend takes sigmas (n_rays, n_samples[, 1]) and rgbs (n_rays, n_samples, 3), got "
            f"{tuple(sigmas.shape)} and {tuple(rgbs.shape)}"
        )
    n_rays, n_samples = sigmas.shape
    if isinstance(step_size, Tensor) and step_size.dim() == 3 and step_size.shape[-1] == 1:
        step_size = step_size.squeeze(-1)
    if isinstance(step_size, Tensor) and step_size.dim() and tuple(step_size.shape) != (n_rays, n_samples):
        raise ValueError(
            f"volrend's step_size is a number or (n_rays, n_samples) = {(n_rays, n_samples)} interval "
            f"lengths, got {tuple(step_size.shape)}"
        )
    rays = regular_ray_indices(n_rays, n_samples, sigmas.device)
    step = torch.as_tensor(step_size, dtype=sigmas.dtype, device=sigmas.device)
    deltas = step.expand(n_rays, n_samples).reshape(-1) if step.dim() else step
    weights, _, _ = render_weights(sigmas.reshape(-1), deltas, rays)
    rgb, _, _ = composite(weights, rgbs.reshape(-1, 3), rays, n_rays, background=background)
    return rgb
