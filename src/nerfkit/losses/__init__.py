"""Loss terms a model adds to its photometric loss, as functions called from a list.

A term maps a step's :class:`~nerfkit.render.output.RenderOutput` to a scalar tensor, or None
when it takes no part in that step (its render output is missing, or its switch is off).
:func:`total` adds the terms of a list in order; :mod:`nerfkit.losses.tv` holds the total
variation, which a grid adds straight to its gradients.
"""

from __future__ import annotations

from collections.abc import Callable

from torch import Tensor

from ..render.output import RenderOutput

LossTerm = Callable[[RenderOutput], Tensor | None]


def total(loss: Tensor, terms: list[LossTerm], out: RenderOutput) -> Tensor:
    """``loss`` plus every term of ``terms`` that takes part, in order."""
    for term in terms:
        value = term(out)
        if value is not None:
            loss = loss + value
    return loss


def mean_opacity(weight: float) -> LossTerm:
    """``weight`` times the mean opacity of the rays: the volume draws nothing it need not
    (a capture's table stops the rays that miss the object)."""
    return lambda out: weight * out.acc.float().mean()


def mean_extra(key: str, weight: float, on: Callable[[], bool] = lambda: True) -> LossTerm:
    """``weight`` times the mean of the render output's extra ``key``, while ``on()``."""

    def term(out: RenderOutput) -> Tensor | None:
        return weight * out.extras[key].float().mean() if on() and key in out.extras else None

    return term


def distortion(weight: float, radius: float) -> LossTerm:
    """mip-NeRF 360's distortion loss (the kernels compute it per ray), ``weight`` per scene
    radius ``radius`` (scale-free)."""

    def term(out: RenderOutput) -> Tensor | None:
        if weight <= 0 or "distortion" not in out.extras:
            return None
        return weight / radius * out.extras["distortion"].float().mean()

    return term
