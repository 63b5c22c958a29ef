"""A capture's sparse points as sight lines: a training photo that saw a point saw nothing
in front of it.

Structure-from-motion leaves each sparse point with the photos whose features it joins (its
track). The ray from such a photo's camera to the point crosses empty space up to the
point, and a surface there stops it; DS-NeRF (Deng et al., CVPR 2022) supervises depth
along such rays. Without them a capture's fur and fabric train half see-through, the table
behind taking the rest of their colour, and the object alone renders pale and hazy.
A line aimed at the point itself makes the surface solid only there (a speck a voxel or
two wide), so each draw aims a little beside its point (:func:`spread_lines`): the surface
a feature lies on goes on around it. The model scores the lines (``sight_loss``) and says
how far to spread them (``sight_spread``); this module holds them and draws a batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..cameras import Rays
from ..data.scene import Scene

# Sight lines drawn per training step (a capture has tens of thousands of lines in all).
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
    def from_scene(scene: Scene, device: torch.device | str = "cpu") -> SightLines | None:
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

    def sample(self, n: int, generator: torch.Generator, spread: float = 0.0) -> tuple[Rays, Tensor, Tensor]:
        """``n`` lines at random (with replacement), each aimed within ``spread`` (world
        units) of its point (:func:`spread_lines`): ``(rays, distances (n,), views (n,))``."""
        idx = torch.randint(0, len(self), (n,), generator=generator).to(self.distances.device)
        origins, directions, distances = self.origins[idx], self.directions[idx], self.distances[idx]
        if spread > 0:
            directions, distances = spread_lines(origins, directions, distances, spread, generator)
        return Rays(origins, directions), distances, self.views[idx]


def sight_lines_note(scene: Scene, sight: SightLines | None, weighed: bool) -> str | None:
    """What a new run says about its sight lines: how many ``sight`` holds (None: none), or,
    for a model that ``weighed`` them, why a dataset's sparse points give none; else None."""
    if sight is not None:
        assert scene.points is not None  # (sight lines come from the sparse points)
        return (
            f"sight lines: {len(sight)} from the train photos' cameras to the {len(scene.points)} "
            "sparse points (--points-weight)"
        )
    if weighed and scene.points is not None and scene.point_views is None:
        return (
            f"note: {scene.source} has sparse points but does not record which photos saw them, so they "
            "are not used as sight lines (an older dataset, or not a dataset.npz): rebuild it with "
            "`nerfkit dataset DATASET_DIR --force`"
        )
    return None


def spread_lines(
    origins: Tensor, directions: Tensor, distances: Tensor, radius: float, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Lines turned to aim at a random spot within ``radius`` of their points, uniform over
    the disc across each line through its point.

    Args:
        origins, directions: (n, 3), the directions unit; distances: (n,) to each point.
        radius: the disc's radius (world units).
        generator: a CPU generator for the spots (the draws resume exactly).

    Returns:
        ``(directions (n, 3) unit, distances (n,))`` from the same origins to the spots.
    """
    n = len(distances)
    side = torch.randn(n, 3, generator=generator).to(directions)
    side = side - (side * directions).sum(-1, keepdim=True) * directions  # across the line
    side = side / side.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    reach = radius * torch.rand(n, 1, generator=generator).to(directions).sqrt()  # uniform over the disc
    to_spot = directions * distances.unsqueeze(-1) + side * reach
    length = to_spot.norm(dim=-1)
    return to_spot / length.unsqueeze(-1), length
