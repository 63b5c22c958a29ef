"""Front-to-back compositing of a few surfaces per ray, over an (n, k) layout (the packed
samples of a volume are :mod:`~nerfkit.render.volrend`'s).

* :func:`composite_layers`: front-to-back compositing of these surfaces along each ray
  (:func:`layer_weights`: their weights); :func:`layers_depth`: the distance of the
  surface a ray meets among them.
"""

from __future__ import annotations

import torch
from torch import Tensor


def layer_weights(t: Tensor, alpha: Tensor) -> tuple[Tensor, Tensor]:
    """Front-to-back compositing weights of a few surfaces per ray.

    Args:
        t: (n, k) distance of each layer along the ray (any order; ``inf``: not on this
            ray, give it alpha 0); alpha: (n, k) opacity in [0, 1].

    Returns:
        (n, k) ``T_j alpha_j`` in the layers' given order, with ``T_j`` the product of
        ``1 - alpha_i`` over the layers nearer than ``j``; and (n, 1) the transmittance
        through all of them.
    """
    order = torch.argsort(t, dim=1)
    a = torch.gather(alpha, 1, order)
    keep = torch.cumprod(1.0 - a, dim=1)  # (n, k) transmittance after each layer
    trans = torch.cat([torch.ones_like(keep[:, :1]), keep[:, :-1]], dim=1)
    weights = torch.empty_like(a).scatter_(1, order, trans * a)
    return weights, keep[:, -1:]


def composite_layers(t: Tensor, rgb: Tensor, alpha: Tensor, behind: Tensor) -> Tensor:
    """Front-to-back alpha compositing of a few surfaces per ray, in order of distance.

    Args:
        t: (n, k) distance of each layer along the ray (``inf``: not on this ray, give it
            alpha 0); rgb: (n, k, 3); alpha: (n, k) opacity in [0, 1]; behind: (n, 3) what
            is seen through all of them.

    Returns:
        (n, 3) ``sum_j T_j alpha_j rgb_j + T_k behind`` over the layers sorted by ``t``,
        with ``T_j = prod_{i<j} (1 - alpha_i)``.
    """
    weights, through = layer_weights(t, alpha)
    return (weights.unsqueeze(-1) * rgb).sum(1) + through * behind


def layers_depth(t: Tensor, alpha: Tensor) -> tuple[Tensor, Tensor]:
    """The distance of the surface a ray meets among a few: the first one after which
    less than half of the light is left (the median depth), not a blend of distances.

    A capture's table lets some light through where it draws the room's reflection (its
    coverage under 1); an expected depth there mixes the table's distance with the room's
    beneath it, and the table's depth comes out speckled.

    Args:
        t: (n, k) distance of each layer along the ray (any order; ``inf``: not on this
            ray, give it alpha 0); alpha: (n, k) opacity in [0, 1].

    Returns:
        (n,) the distance times ``met`` and (n,) ``met`` in {0, 1} (as a volume's
        unnormalised depth and opacity: divide by it for the distance); ``met`` is 0 where
        more than half of the light passes every layer.
    """
    order = torch.argsort(t, dim=1)
    ts = torch.gather(t, 1, order)
    left = torch.cumprod(1.0 - torch.gather(alpha, 1, order), dim=1)  # (n, k) after each layer
    crossed = (left < 0.5) & torch.isfinite(ts)
    met = crossed.any(dim=1)
    first = torch.gather(ts, 1, crossed.int().argmax(dim=1, keepdim=True))[:, 0]
    return torch.where(met, first, torch.zeros_like(first)), met.to(t.dtype)
