"""Sinusoidal positional encoding (NeRF, Mildenhall et al. 2020)."""

from __future__ import annotations

import math
import operator

import torch
from torch import Tensor

from nerfkit.arrays import accepts_numpy


def encoded_dim(in_dim: int, L: int) -> int:
    """Width of ``positional_encoding`` output: ``in_dim * (1 + 2 L)``."""
    return in_dim * (1 + 2 * L)


@accepts_numpy
def positional_encoding(x: Tensor, L: int) -> Tensor:
    """Identity plus sin/cos at L octaves.

    ``PE(x) = [x, sin(2^0 pi x), cos(2^0 pi x), ..., sin(2^{L-1} pi x), cos(2^{L-1} pi x)]``

    Args:
        x: (..., D) coordinates.
        L: number of frequency octaves (L = 0 gives the identity).

    Returns:
        (..., D * (1 + 2 L)); the features for each octave are [sin over D, cos over D].

    Example: a 1-D x = 0 gives [0, 0, 1, 0, 1, ...] (sin 0 = 0, cos 0 = 1); a 3-D x = 0
    gives [0, 0, 0, 0, 0, 0, 1, 1, 1, ...] (x, then sin over D, then cos over D).
    """
    try:
        L = operator.index(L)  # a whole number of octaves (encoded_dim counts them so)
    except TypeError:
        raise ValueError(f"positional_encoding's L is a whole number of octaves, got {L!r}") from None
    if L < 0:
        raise ValueError(f"positional_encoding's L must be 0 or more, got {L}")
    if L == 0:
        return x
    freqs = (2.0 ** torch.arange(L, dtype=x.dtype, device=x.device)) * math.pi  # (L,)
    angles = x.unsqueeze(-2) * freqs.unsqueeze(-1)  # (..., L, D)
    sincos = torch.cat([torch.sin(angles), torch.cos(angles)], dim=-1)  # (..., L, 2D)
    return torch.cat([x, sincos.flatten(-2)], dim=-1)
