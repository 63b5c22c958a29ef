"""A 2D neural field: normalised pixel coordinates (x, y) -> RGB (the course warm-up).

Coordinates follow the project convention: pixel (col, row) has its centre at
``uv = (col + 0.5, row + 0.5)``, normalised to ``xy = (u / W, v / H)`` in (0, 1).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from .encoding import encoded_dim, positional_encoding


class ImageField(nn.Module):
    """Positional encoding + MLP with ReLU + sigmoid output.

    With the defaults (``L=10, width=256, depth=3``): 42 inputs, three hidden
    Linear+ReLU layers of width 256, then Linear(256, 3) and a sigmoid.

    Args:
        L: encoding octaves (0 = raw coordinates).
        width: hidden layer width.
        depth: number of hidden Linear+ReLU layers (>= 1).
    """

    def __init__(self, L: int = 10, width: int = 256, depth: int = 3):
        super().__init__()
        if L < 0 or width < 1 or depth < 1:
            raise ValueError(f"ImageField needs L >= 0, width >= 1, depth >= 1 (got {L}, {width}, {depth})")
        self.L = L
        layers: list[nn.Module] = []
        in_dim = encoded_dim(2, L)
        for _ in range(depth):
            layers += [nn.Linear(in_dim, width), nn.ReLU(inplace=True)]
            in_dim = width
        self.hidden = nn.Sequential(*layers)
        self.head = nn.Linear(width, 3)

    def forward(self, xy: Tensor) -> Tensor:
        """(N, 2) normalised coordinates in [0, 1] -> (N, 3) float32 RGB in (0, 1).

        Keep ``xy`` float32: the top octave multiplies by 2^(L-1) pi, which bf16
        coordinates could not resolve (autocast leaves sin/cos in float32). Under
        autocast the hidden layers may run in bf16; the output layer and sigmoid
        always run in float32 so colours keep full precision.
        """
        h = self.hidden(positional_encoding(xy, self.L))
        with torch.autocast(device_type=h.device.type, enabled=False):
            return torch.sigmoid(self.head(h.float()))


def pixel_xy(index: Tensor, height: int, width: int) -> Tensor:
    """Flat pixel indices (row-major) -> (N, 2) float32 normalised pixel-centre coordinates.

    ``index = row * width + col`` gives ``((col + 0.5) / width, (row + 0.5) / height)``.
    """
    row = torch.div(index, width, rounding_mode="floor")
    col = index - row * width
    return torch.stack([(col.float() + 0.5) / width, (row.float() + 0.5) / height], dim=-1)


def grid_xy(rows: Tensor, height: int, width: int) -> Tensor:
    """Coordinates of every pixel centre in the given rows of a (height, width) grid.

    Args:
        rows: (R,) row indices.

    Returns:
        (R * width, 2) float32, row-major, matching ``image[rows].reshape(-1, 3)``.
    """
    cols = torch.arange(width, device=rows.device, dtype=torch.float32)
    x = ((cols + 0.5) / width).expand(len(rows), width)
    y = ((rows.float() + 0.5) / height).unsqueeze(1).expand(len(rows), width)
    return torch.stack([x, y], dim=-1).reshape(-1, 2)
