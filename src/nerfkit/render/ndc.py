"""Normalised device coordinates for forward-facing scenes (the NeRF paper's LLFF space).

A forward-facing capture (every photo taken from about the same place, looking the same
way) sees content from a near plane out to infinity. NDC maps the reference camera's
frustum from depth ``near`` to infinity onto a cube: a point ``(x, y, z)`` of the reference
camera (OpenCV axes: x right, y down, z forward) goes to

    X = ax * x / z + bx,   Y = ay * y / z + by,   Z = 1 - 2 * near / z

with ``ax = 2 fx / W``, ``bx = 2 cx / W - 1`` (and so for y): X and Y are the point's
pixel coordinates in the reference image scaled to [-1, 1], and Z runs from -1 at the
near plane to 1 at infinity, uniformly in disparity. Straight rays stay straight, so a
grid over the NDC cube is sampled finely near the cameras and ever more coarsely far
away, as the photos resolve it.

A ray ``o + t d`` (its origin first moved to the near plane, ``z = near``) becomes
``o' + s d'`` with ``s`` in [0, 1) (``s -> 1`` at infinity):

    o' = (ax ox/oz + bx, ay oy/oz + by, 1 - 2 near / oz)
    d' = (ax (dx/dz - ox/oz), ay (dy/dz - oy/oz), 2 near / oz)

and ``t = s oz / (dz (1 - s))`` measured from the moved origin.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import Tensor

# rays whose direction makes less than this with the reference view's plane never get far
# enough forward to be mapped (they are left empty)
MIN_FORWARD = 1e-4
# smallest half-width (X and Y) of the NDC box: cameras beside the reference one see a
# little beyond its frustum
MIN_EXTENT = 1.25


@dataclass(frozen=True)
class NdcSpace:
    """The NDC of one reference camera.

    Attributes:
        c2w: (4, 4) the reference camera-to-world (OpenCV axes).
        fx, fy, cx, cy, width, height: its intrinsics and image size.
        near: depth (along the reference z) of the plane mapped to Z = -1.
        extent: half-width of the NDC box in X and Y (:meth:`fit_extent`): other cameras
            see beyond the reference camera's frustum (|X|, |Y| <= 1).
    """

    c2w: tuple
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    near: float
    extent: float = MIN_EXTENT

    @staticmethod
    def from_camera(c2w: np.ndarray, K: np.ndarray, width: int, height: int, near: float) -> NdcSpace:
        c2w = np.asarray(c2w, np.float64).reshape(4, 4)
        K = np.asarray(K, np.float64).reshape(3, 3)
        return NdcSpace(
            tuple(map(tuple, c2w.tolist())),
            float(K[0, 0]),
            float(K[1, 1]),
            float(K[0, 2]),
            float(K[1, 2]),
            int(width),
            int(height),
            float(near),
        )

    def fit_extent(self, c2w: np.ndarray, K: np.ndarray, width: int, height: int) -> NdcSpace:
        """The same space with a box wide enough for every pixel of the cameras ``c2w``
        (n, 4, 4) with intrinsics ``K`` (n, 3, 3) (a camera turned about its axis sees
        beyond the reference frustum's corners): the largest |X| or |Y| their image
        corners reach between the near plane and infinity, plus 5%, and at least
        :data:`MIN_EXTENT`."""
        from ..cameras import pixel_to_ray

        corners = torch.tensor([[0.0, 0.0], [width, 0.0], [0.0, height], [width, height]], dtype=torch.float64)
        n = len(c2w)
        o, d = pixel_to_ray(
            torch.as_tensor(np.asarray(K), dtype=torch.float64).reshape(n, 1, 3, 3),
            torch.as_tensor(np.asarray(c2w), dtype=torch.float64).reshape(n, 1, 4, 4),
            corners.expand(n, 4, 2),
        )
        o_ndc, d_ndc, forward = self.rays(o.reshape(-1, 3), d.reshape(-1, 3))
        ends = torch.cat([o_ndc[forward, :2], (o_ndc + d_ndc)[forward, :2]])  # s = 0 and s -> 1
        reach = float(ends.abs().max()) if len(ends) else 0.0
        return replace(self, extent=max(MIN_EXTENT, 1.05 * reach))

    def to_dict(self) -> dict:
        return {
            "c2w": [list(r) for r in self.c2w],
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "width": self.width,
            "height": self.height,
            "near": self.near,
            "extent": self.extent,
        }

    @staticmethod
    def from_dict(d: dict) -> NdcSpace:
        return NdcSpace(
            tuple(tuple(float(v) for v in r) for r in d["c2w"]),
            float(d["fx"]),
            float(d["fy"]),
            float(d["cx"]),
            float(d["cy"]),
            int(d["width"]),
            int(d["height"]),
            float(d["near"]),
            float(d.get("extent", MIN_EXTENT)),
        )

    def _frame(self, like: Tensor) -> tuple[Tensor, Tensor]:
        c2w = torch.tensor(self.c2w, dtype=like.dtype, device=like.device)
        return c2w[:3, :3], c2w[:3, 3]  # rotation (columns: camera axes in world), centre

    def _scale(self) -> tuple[float, float, float, float]:
        return (
            2.0 * self.fx / self.width,
            2.0 * self.fy / self.height,
            2.0 * self.cx / self.width - 1.0,
            2.0 * self.cy / self.height - 1.0,
        )

    def to_camera(self, points: Tensor) -> Tensor:
        """(n, 3) world points -> (n, 3) in the reference camera's frame."""
        R, c = self._frame(points)
        return (points - c) @ R

    def _project(self, p: Tensor) -> Tensor:
        """(n, 3) points of the reference camera's frame (z > 0) -> (n, 3) NDC points."""
        ax, ay, bx, by = self._scale()
        z = p[:, 2].clamp(min=1e-9)
        return torch.stack([ax * p[:, 0] / z + bx, ay * p[:, 1] / z + by, 1.0 - 2.0 * self.near / z], dim=-1)

    def points(self, points: Tensor) -> Tensor:
        """(n, 3) world points in front of the reference camera -> (n, 3) NDC points."""
        return self._project(self.to_camera(points))

    def rays(self, origins: Tensor, dirs: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """World rays (n, 3) each -> ``(o', d', forward)``: NDC rays on which the scene from
        the near plane to infinity is ``s`` in [0, 1), and (n,) bool, False for rays that
        do not head forward of the reference view (their NDC ray is a dummy)."""
        o = self.to_camera(origins)
        d = dirs @ self._frame(dirs)[0]
        forward = d[:, 2] > MIN_FORWARD
        dz = torch.where(forward, d[:, 2], torch.ones_like(d[:, 2]))
        o = o + ((self.near - o[:, 2]) / dz).unsqueeze(-1) * d  # origin onto the near plane: oz = near
        ax, ay, _, _ = self._scale()
        d_ndc = torch.stack(
            [
                ax * (d[:, 0] / dz - o[:, 0] / self.near),
                ay * (d[:, 1] / dz - o[:, 1] / self.near),
                torch.full_like(dz, 2.0),
            ],
            dim=-1,
        )  # (2 near / oz = 2)
        return self._project(o), d_ndc, forward

    def distance(self, origins: Tensor, dirs: Tensor, s: Tensor) -> Tensor:
        """(n,) distance along the world rays (from their origins, in units of ``|d|``) of
        the points at NDC fraction ``s`` (n,) on their NDC rays (:meth:`rays`)."""
        oz = self.to_camera(origins)[:, 2]
        dz = (dirs @ self._frame(dirs)[0])[:, 2].clamp(min=MIN_FORWARD)
        shift = (self.near - oz) / dz  # where the NDC ray starts
        s = s.clamp(0.0, 1.0 - 1e-6)
        return shift + s * self.near / (dz * (1.0 - s))


def grid_scale(width: int, height: int, depth_scale: float, square_pixels: bool) -> tuple[float, float, float]:
    """The factors (X, Y, Z) that take NDC to the grid's space (:func:`to_grid`): Z (the
    disparity axis) times ``depth_scale``; with ``square_pixels`` X times ``width / height``.

    NDC's X and Y both span [-1, 1] across the reference photo, so a cube of NDC spans
    ``width / height`` times more pixels across than down; stretched so, the grid's cubic
    voxels cover as many pixels each way (for the same vertex count, finer across a
    landscape photo). Example: ``grid_scale(504, 378, 0.25, True)`` -> ``(1.333..., 1.0, 0.25)``.
    """
    return (width / height if square_pixels else 1.0), 1.0, float(depth_scale)


def to_grid(v: Tensor, scale: float | tuple[float, float, float]) -> Tensor:
    """(n, 3) NDC points or ray directions -> the grid's space: each axis times its factor of
    ``scale`` (:func:`grid_scale`; a number: the Z factor, X and Y as they are).

    The grid's voxels are cubes in its space, so a Z factor below 1 lays fewer vertices
    along the disparity and, for the same vertex count, more across the view.
    Linear: a straight NDC ray ``o' + s d'`` maps to ``to_grid(o') + s to_grid(d')``, at the
    same ``s``. Example: ``to_grid([[0.5, -0.2, 0.8]], 0.5)`` -> ``[[0.5, -0.2, 0.4]]``.
    """
    factors = (1.0, 1.0, float(scale)) if isinstance(scale, (int, float)) else tuple(scale)
    if factors == (1.0, 1.0, 1.0):
        return v
    return v * v.new_tensor(factors)
