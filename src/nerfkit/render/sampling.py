"""Where along each ray to evaluate the field.

Shapes: ``n_rays`` rays, ``n_samples`` samples per ray; ``t`` is distance along the
(unit) ray direction, so the world point is ``o + t * d``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from nerfkit.arrays import accepts_numpy


def stratified_t(
    near: Tensor | float,
    far: Tensor | float,
    n_rays: int,
    n_samples: int,
    perturb: bool,
    device: torch.device | str | None = None,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Sample distances in ``n_samples`` equal bins between near and far.

    With ``perturb`` each sample is uniform inside its bin (stratified sampling, as in
    NeRF); without, it is the bin's midpoint.

    Args:
        near, far: scalars or (n_rays,) tensors.

    Returns:
        t: (n_rays, n_samples), increasing along each ray.

    Example: near=2, far=6, n_samples=4, perturb=False -> [2.5, 3.5, 4.5, 5.5].
    """
    if n_samples < 1:
        raise ValueError(f"n_samples must be at least 1, got {n_samples}")
    near = torch.as_tensor(near, dtype=dtype, device=device).reshape(-1, 1)
    far = torch.as_tensor(far, dtype=dtype, device=device).reshape(-1, 1)
    edges = torch.linspace(0.0, 1.0, n_samples + 1, device=near.device, dtype=dtype)
    lower, width = edges[:-1], edges[1] - edges[0]
    if perturb:
        u = torch.rand((n_rays, n_samples), device=near.device, generator=generator, dtype=dtype)
    else:
        u = torch.full((n_rays, n_samples), 0.5, device=near.device, dtype=dtype)
    frac = lower + u * width
    return near + (far - near) * frac


@accepts_numpy
def sample_along_rays(
    rays_o: Tensor,
    rays_d: Tensor,
    near: Tensor | float = 2.0,
    far: Tensor | float = 6.0,
    n_samples: int = 64,
    perturb: bool = True,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, Tensor]:
    """The course's ray sampler: stratified points between near and far.

    Args:
        rays_o, rays_d: (n_rays, 3) origins and unit directions (flatten a batch of
            images' rays first: ``rays_o.reshape(-1, 3)``).
        near, far: scalars, or (n_rays,) per ray.
        n_samples: points per ray; bin i of ``[near, far]`` cut in ``n_samples`` equal bins
            holds sample i.
        perturb: a uniformly random point in each bin (training); False: each bin's
            centre (evaluation, renders).
        generator: the random source for ``perturb``.

    Returns:
        ``(points, t)``: (n_rays, n_samples, 3) world points and their (n_rays, n_samples)
        distances along the rays, sorted.
    """
    if rays_o.ndim != 2 or rays_o.shape[-1] != 3 or rays_d.shape != rays_o.shape:
        raise ValueError(
            f"sample_along_rays takes (n_rays, 3) origins and directions, got {tuple(rays_o.shape)} "
            f"and {tuple(rays_d.shape)}: reshape them with .reshape(-1, 3)"
        )
    if not bool((torch.as_tensor(near, dtype=torch.float64) < torch.as_tensor(far, dtype=torch.float64)).all()):
        raise ValueError(f"sample_along_rays needs near < far on every ray, got near {near} and far {far}")
    t = stratified_t(near, far, rays_o.shape[0], n_samples, perturb, rays_o.device, generator, rays_o.dtype)
    points = rays_o[:, None, :] + t[..., None] * rays_d[:, None, :]
    return points, t


def intervals_from_t(t: Tensor, far: Tensor | float | None = None) -> Tensor:
    """Interval lengths (n_rays, n_samples) for samples at ``t``: gaps to the next sample.

    The last sample's interval reaches ``far`` when given, else repeats the previous gap.
    """
    deltas = t[..., 1:] - t[..., :-1]
    if far is None:
        last = deltas[..., -1:] if deltas.shape[-1] else torch.ones_like(t[..., :1])
    else:
        far = torch.as_tensor(far, dtype=t.dtype, device=t.device).reshape(-1, 1)
        last = torch.clamp(far - t[..., -1:], min=0.0).expand_as(t[..., -1:])
    return torch.cat([deltas, last], dim=-1)


def sample_pdf(
    bins: Tensor,
    weights: Tensor,
    n_samples: int,
    perturb: bool,
    generator: torch.Generator | None = None,
) -> Tensor:
    """Inverse-transform sampling of the piecewise-constant pdf given by ``weights``.

    Used for NeRF's hierarchical (coarse-to-fine) sampling.

    Args:
        bins: (n_rays, n_bins + 1) bin edges along each ray (increasing).
        weights: (n_rays, n_bins) non-negative weights of the bins.
        n_samples: samples to draw per ray.

    Returns:
        (n_rays, n_samples) sorted distances inside the bins.
    """
    weights = weights.detach() + 1e-5  # avoid nan on all-zero rays
    pdf = weights / weights.sum(dim=-1, keepdim=True)
    cdf = torch.cumsum(pdf, dim=-1)
    cdf = torch.cat([torch.zeros_like(cdf[..., :1]), cdf], dim=-1)  # (n_rays, n_bins + 1)
    n_rays = bins.shape[0]
    if perturb:
        u = torch.rand((n_rays, n_samples), device=bins.device, generator=generator)
    else:
        u = torch.linspace(0.0, 1.0, n_samples, device=bins.device).expand(n_rays, n_samples)
    u = u.contiguous()
    idx = torch.searchsorted(cdf, u, right=True)
    below = torch.clamp(idx - 1, min=0)
    above = torch.clamp(idx, max=cdf.shape[-1] - 1)
    cdf_lo, cdf_hi = torch.gather(cdf, -1, below), torch.gather(cdf, -1, above)
    bin_lo, bin_hi = torch.gather(bins, -1, below), torch.gather(bins, -1, above)
    denom = torch.where(cdf_hi - cdf_lo < 1e-5, torch.ones_like(cdf_hi), cdf_hi - cdf_lo)
    frac = (u - cdf_lo) / denom
    return (bin_lo + frac * (bin_hi - bin_lo)).detach()
