"""The colour a new view is rendered with, from the training photos taken near it.

A real capture's training photos each learn a colour correction (exposure, white balance,
colour mixing: :class:`~nerfkit.train.view_corrections.ExposureCorrection`), the mean over
photos held at none. A phone sets exposure and white balance from what it sees, so photos
taken from nearby look alike: a view is rendered with the corrections of the training photos
whose directions from the scene's centre are near its own, weighted by a Gaussian of the angle
(NeRF-W interpolates its appearance codes the same way). The weights vary smoothly with the
camera, so an orbit's colour drifts as the photos' did, without jumps; no pixel of the view is
used. Far from every photo (or with a wide kernel) the weights even out to the photos' average
colour, the scene's own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

# the Gaussian's width, in multiples of the median angle from a training photo to its third
# nearest (the spacing; BENCHMARKS.md, the table of defaults)
SPACING_WIDTHS = 0.5
NEIGHBOURS = 3


def camera_directions(c2w: np.ndarray, center: np.ndarray) -> np.ndarray:
    """(n, 4, 4) camera-to-world poses -> (n, 3) unit directions from ``center`` (3,) to each
    camera's centre (a camera at the centre: +z)."""
    d = np.asarray(c2w, np.float64)[:, :3, 3] - np.asarray(center, np.float64)
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    return np.where(norm > 1e-12, d / np.maximum(norm, 1e-12), np.array([0.0, 0.0, 1.0]))


def angles_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(m, 3) and (n, 3) unit vectors -> (m, n) angles between them, radians."""
    return np.arccos(np.clip(a @ b.T, -1.0, 1.0))


def neighbour_spacing(directions: np.ndarray, k: int = NEIGHBOURS) -> float:
    """The median over ``directions`` (n, 3) of the angle (radians) from each to its ``k``-th
    nearest other; with ``k`` or fewer others, the largest angle between any two (0 for one)."""
    n = len(directions)
    if n < 2:
        return 0.0
    angles = angles_between(directions, directions)
    np.fill_diagonal(angles, np.inf)
    kth = np.sort(angles, axis=1)[:, min(k, n - 1) - 1]
    return float(np.median(kth))


def direction_weights(train: np.ndarray, directions: np.ndarray, width: float) -> np.ndarray:
    """Weights (m, n), each row summing to 1, of the ``train`` directions (n, 3) for each of
    ``directions`` (m, 3): a Gaussian of the angle between them of standard deviation
    ``width`` (radians). Measured from the nearest photo, so that no row underflows: far from
    every photo, the nearest weighs most."""
    angles = angles_between(directions, train)
    excess = angles**2 - angles.min(axis=1, keepdims=True) ** 2
    w = np.exp(-0.5 * excess / max(width, 1e-6) ** 2)
    return w / w.sum(axis=1, keepdims=True)


@dataclass(frozen=True)
class DirectionalColour:
    """The training photos' colour corrections by direction: ``rgb -> M rgb + b`` per photo.

    Attributes:
        directions: (n, 3) unit directions from ``center`` to each training photo's camera.
        matrices: (n, 3, 3) colour matrices (rows: output channels); offsets: (n, 3).
        center: (3,) the scene's centre; width: the Gaussian's standard deviation, radians.
    """

    directions: np.ndarray
    matrices: np.ndarray
    offsets: np.ndarray
    center: np.ndarray
    width: float

    @classmethod
    def of_photos(
        cls, c2w: np.ndarray, matrices: np.ndarray, offsets: np.ndarray, center: np.ndarray
    ) -> DirectionalColour:
        """From the training photos' poses (n, 4, 4) and corrections, the width set by how far
        apart the photos are (:data:`SPACING_WIDTHS` times :func:`neighbour_spacing`)."""
        directions = camera_directions(c2w, center)
        width = SPACING_WIDTHS * neighbour_spacing(directions)
        return cls(
            directions,
            np.asarray(matrices, np.float64),
            np.asarray(offsets, np.float64),
            np.asarray(center, np.float64),
            max(width, 1e-3),
        )

    def correction(self, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The colour correction of a camera at ``c2w`` (4, 4): ``(M (3, 3), b (3,))``, the
        weighted mean of the photos' (being affine, it equals the weighted mean of the colours
        they would give)."""
        d = camera_directions(np.asarray(c2w)[None], self.center)
        w = direction_weights(self.directions, d, self.width)[0]
        return np.einsum("n,nij->ij", w, self.matrices), w @ self.offsets

    def apply(self, rgb: Tensor, c2w: np.ndarray) -> Tensor:
        """(..., 3) colours rendered at ``c2w`` (4, 4) -> the colours corrected for it."""
        M, b = self.correction(c2w)
        Mt = torch.as_tensor(M.T, dtype=rgb.dtype, device=rgb.device)
        return rgb @ Mt + torch.as_tensor(b, dtype=rgb.dtype, device=rgb.device)

    def payload(self) -> dict[str, Any]:
        """Plain tensors and a float, for a checkpoint (:meth:`from_payload` reads it back)."""
        return {
            "directions": torch.from_numpy(self.directions),
            "matrices": torch.from_numpy(self.matrices),
            "offsets": torch.from_numpy(self.offsets),
            "center": torch.from_numpy(self.center),
            "width": float(self.width),
        }

    @classmethod
    def from_payload(cls, d: Any) -> DirectionalColour:
        """What :meth:`payload` wrote; ValueError when it is malformed."""
        if not isinstance(d, dict):
            raise ValueError("'appearance' is not a dictionary")
        try:
            arrays = [np.asarray(d[k], np.float64) for k in ("directions", "matrices", "offsets", "center")]
            width = float(d["width"])
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"'appearance' is malformed ({type(e).__name__}: {e})") from None
        directions, matrices, offsets, center = arrays
        n = len(directions)
        shapes_ok = (
            n > 0
            and directions.shape == (n, 3)
            and matrices.shape == (n, 3, 3)
            and offsets.shape == (n, 3)
            and center.shape == (3,)
        )
        if not shapes_ok or not all(np.isfinite(a).all() for a in arrays) or not width > 0:
            raise ValueError("'appearance' has arrays of the wrong shapes, non-finite values or no width")
        return cls(directions, matrices, offsets, center, width)
