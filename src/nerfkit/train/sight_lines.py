"""A capture's sparse points as sight lines: a training photo that saw a point saw nothing
in front of it.

Structure-from-motion leaves each sparse point with the photos whose features it joins (its
track). The ray from such a photo's camera to the point crosses empty space up to the
point, and a surface there stops it; DS-NeRF (Deng et al., CVPR 2022) supervises depth
along such rays. Without them a capture's fur and fabric train half see-through, the table
behind taking the rest of their colour, and the object alone renders pale and hazy.
The model scores the lines (``sight_loss``); this module holds them and draws a batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..cameras import Rays
from ..data.scene import Scene

# Sight lines drawn per training step (labubu: 13.6k lines in all, steve 51k).
SIGHT_LINES_PER_STEP = 1024


@dataclass
class SightLines:
    """Lines from training cameras to the sparse points they saw.

    Attributes:
        origins: (k, 3) the camera centre; directions: (k, 3) unit, toward the point.
        distances: (k,) from the camera to the point.
        views: (k,) the training view of each line (its pose correction applies).
    """

    origins: Tensor
    directions: Tensor
    distances: Tensor
    views: Tensor

    def __len__(self) -> int:
        return len(self.distances)

    @staticmethod
    def from_scene(scene: Scene, device: torch.device | str = "cpu") -> "SightLines | None":
        """The scene's lines (:attr:`Scene.point_views`), or None when it records none."""
        if scene.points is None or scene.point_views is None or len(scene.point_views) == 0:
            return None
        point, view = scene.point_views[:, 0].astype(np.int64), scene.point_views[:, 1].astype(np.int64)
        o = scene.train.c2w[view, :3, 3].astype(np.float64)
        d = scene.points[point].astype(np.float64) - o
        dist = np.linalg.norm(d, axis=1)
        keep = dist > 0

        def kept(a: np.ndarray, dtype: torch.dtype = torch.float32) -> Tensor:
            return torch.as_tensor(a[keep], dtype=dtype, device=device)

        return SightLines(kept(o), kept(d / np.maximum(dist, 1e-12)[:, None]), kept(dist), kept(view, torch.long))

    def sample(self, n: int, generator: torch.Generator) -> tuple[Rays, Tensor, Tensor]:
        """``n`` lines at random (with replacement): ``(rays, distances (n,), views (n,))``."""
        idx = torch.randint(0, len(self), (n,), generator=generator).to(self.distances.device)
        return Rays(self.origins[idx], self.directions[idx]), self.distances[idx], self.views[idx]
