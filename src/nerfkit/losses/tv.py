"""Total variation of a vertex grid, added straight to the gradients of the rows a step touched
(Plenoxels' in-place regulariser; :func:`~nerfkit.kernels.ops.add_grid_tv`)."""

from __future__ import annotations

import torch
from torch import Tensor

from ..fields.grid import GridField
from ..kernels.ops import add_grid_tv, row_vertices


def tv_weights(n_channels: int, K: int, weight: float, colour: float, view: float) -> Tensor:
    """(n_channels,) the total variation's weight on each grid channel: the density
    ``weight``, every colour coefficient ``weight * colour``, and the coefficients above
    degree 0 (channel ``1 + K * c + k``, k > 0; ``K`` coefficients per colour) ``view`` more."""
    out = torch.full((n_channels,), weight * colour)
    out[0] = weight
    above = (torch.arange(n_channels) - 1) % K != 0  # (channel 1 + K * colour: degree 0)
    out[1:] += view * above[1:]
    return out


class GridTV:
    """Adds a grid's total variation gradient at ``weights`` (:func:`tv_weights`); keeps the
    map from rows to vertices a sparse grid needs until its layout changes."""

    def __init__(self, weights: Tensor):
        self.weights = weights
        self._key: tuple | None = None
        self._row_vertex: Tensor | None = None

    @property
    def on(self) -> bool:
        return bool(self.weights.any())

    def __call__(self, field: GridField) -> int:
        key = (id(field.vertex_rows), field.vertex_rows._version, field.grid.shape[0])
        if self._key != key:
            self._row_vertex = row_vertices(field.geom, field.grid.shape[0]) if field.row_offset < 0 else None
            self._key = key
        return add_grid_tv(field.grid, field.geom, self.weights, field.sink, field.backend(), self._row_vertex)
