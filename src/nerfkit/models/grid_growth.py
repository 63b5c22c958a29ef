"""How the ``fast`` model's grid grows, coarse to fine, and where its box goes.

At each stage the grid is resampled finer over its box. At the first growth the box
shrinks around where opaque training rays ended (:class:`SurfaceMemory`); a capture's box
follows its object out at later growths (:func:`follow_object`). From ``sparse_from``
vertices a side, the grown grid stores rows only for the vertices near cells that were
occupied before the growth.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor, nn

from ..fields.grid import GridField, cells_near, resample_grid
from ..kernels.ops import GridGeom
from ..kernels.optim import replace_param
from ..render.box import GridBox
from ..scene_extent import faces_reached
from .base import StepState
from .fast_config import BOX_FOLLOW, BOX_FOLLOW_OPACITY, BOX_FOLLOW_UNTIL
from .packing import vertices_touching

if TYPE_CHECKING:
    from .fast import FastNeRF

# A growth dips the held-out score until the finer grid has trained for a while (lego,
# 128 -> 192 at step 2000: 70 steps to be back level, +0.25 dB after 300, +0.45 after
# 600): a growth with fewer steps left than this fraction of the steps done only costs.
GROWTH_MIN_STEPS_LEFT = 0.05


def growth_too_late(s: StepState) -> bool:
    """Whether the run has too few steps left for a growth to pay off: fewer than
    ``GROWTH_MIN_STEPS_LEFT`` of the steps done, at the pace so far."""
    return s.progress > 1.0 / (1.0 + GROWTH_MIN_STEPS_LEFT)


class SurfaceMemory(nn.Module):
    """Where opaque training rays ended (a ring buffer of ``capacity`` points), to shrink the
    box around them at the first growth."""

    pts: Tensor
    count: Tensor

    def __init__(self, capacity: int = 1 << 16):
        super().__init__()
        self.register_buffer("pts", torch.zeros(capacity, 3))
        self.register_buffer("count", torch.zeros((), dtype=torch.long))

    @torch.no_grad()
    def remember(self, pts: Tensor) -> None:
        """Keep points ``pts`` (n, 3) (the last ``capacity`` of them)."""
        cap = self.pts.shape[0]
        pts = pts.to(self.pts)[-cap:]
        start = int(self.count) % cap
        idx = (start + torch.arange(len(pts), device=pts.device)) % cap
        self.pts[idx] = pts
        self.count += len(pts)

    @torch.no_grad()
    def box(self, pad_voxels: float, geom: GridGeom) -> tuple[np.ndarray, np.ndarray] | None:
        """A box (lo, hi) around the remembered points, or None with too few.

        The 0.1% and 99.9% quantiles per axis, padded by ``pad_voxels`` voxels of ``geom``
        plus 5% of the extent (kept inside ``geom``'s box).
        """
        n = min(int(self.count), self.pts.shape[0])
        if n < 1000:
            return None
        pts = self.pts[:n].double()
        lo = torch.quantile(pts, 0.001, dim=0).cpu().numpy()
        hi = torch.quantile(pts, 0.999, dim=0).cpu().numpy()
        pad = pad_voxels * geom.voxel + 0.05 * (hi - lo)
        return np.maximum(lo - pad, geom.lo.cpu().numpy()), np.minimum(hi + pad, geom.hi.cpu().numpy())


def faces_reached_by(model: FastNeRF) -> list[tuple[int, int]]:
    """The faces of the grid's box that the object reaches (:func:`faces_reached` over the
    vertices solid at :data:`BOX_FOLLOW_OPACITY`, on the object, not on the paint the
    surroundings' surface leaves: :meth:`~nerfkit.surroundings.Surroundings.above_paint_grid`)."""
    sigma, axes, _ = model.field.density_volume()
    solid = -np.expm1(-sigma * model.field.voxel) > BOX_FOLLOW_OPACITY
    if model.surroundings is not None:
        solid &= model.surroundings.above_paint_grid(axes, model.density_box())
    return faces_reached(solid)


def follow_object(
    lo: np.ndarray, hi: np.ndarray, faces: list[tuple[int, int]], center: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The box ``(lo, hi)`` with each of ``faces`` (axis, side 0: low, 1: high) moved out by
    :data:`BOX_FOLLOW` of the box's size along that axis, within the sphere ``(center,
    radius)``; and the faces moved, as "x-" or "z+" with the distance. The grid's
    resampling extends what crosses a face outward (points outside the old box take its
    nearest value), so the object's cross-section starts the new space and training carves it."""
    c, r = np.asarray(center, np.float64), float(radius)
    lo, hi = np.array(lo, np.float64), np.array(hi, np.float64)
    size = hi - lo
    moved = []
    for axis, side in faces:
        if side == 0:
            new = max(lo[axis] - BOX_FOLLOW * size[axis], c[axis] - r)
            by, lo[axis] = lo[axis] - new, min(new, lo[axis])
        else:
            new = min(hi[axis] + BOX_FOLLOW * size[axis], c[axis] + r)
            by, hi[axis] = new - hi[axis], max(new, hi[axis])
        if by > 0:
            moved.append(f"{'xyz'[axis]}{'-+'[side]} by {by:.3g}")
    return lo.astype(np.float32), hi.astype(np.float32), moved


@torch.no_grad()
def regrid(field: GridField, box: GridBox, old_occ: Tensor | None, sparse_from: int, margin: int) -> nn.Parameter:
    """Resample ``field`` over ``box`` (every vertex stored, or from ``sparse_from`` vertices
    a side those within ``margin`` cells of the cells ``old_occ`` of the old grid marks
    occupied); returns the replaced grid parameter."""
    old_geom, old_grid = replace(field.geom), field.grid.detach()
    device = old_grid.device
    geom = GridGeom.of(box, device=device)
    if old_occ is not None and min(box.res) >= sparse_from:
        keep = vertices_touching(cells_near(old_occ, old_geom, geom, margin))
    else:
        keep = torch.ones(geom.n_vertices, dtype=torch.bool, device=device)
    index = torch.zeros(geom.n_vertices, dtype=torch.int32, device=device)
    index[keep] = torch.arange(1, int(keep.sum()) + 1, dtype=torch.int32, device=device)
    field.set_geometry(box, index)
    points = geom.vertex_positions(torch.nonzero(keep)[:, 0])
    rows = resample_grid(old_grid, old_geom, points, backend=field.backend())
    return field.set_rows(torch.cat([field.empty_rows(1, device), rows]))


@torch.no_grad()
def grow(model: FastNeRF, size: int, shrink: bool, follow: bool, optimizer: torch.optim.Optimizer | None) -> list[str]:
    """Resample the model's grid at about ``size ** 3`` vertices over its box, first shrunk
    around where opaque rays ended (``shrink``) or moved out where the object reaches it
    (``follow``). The new grid takes the old one's place in ``optimizer`` with fresh
    moments; every other parameter keeps its own. Returns notes on what the box did."""
    geom = model.field.geom
    old_occ = model.estimator.occ if model.estimator.active else None
    lo, hi = geom.lo.cpu().numpy(), geom.hi.cpu().numpy()
    notes = []
    surface = model.surfaces.box(model.config.box_pad, geom) if shrink else None
    if surface is not None:
        lo, hi = surface
    if follow:
        lo, hi, moved = follow_object(lo, hi, faces_reached_by(model), model.bounds.center, model.bounds.radius)
        if moved:
            notes.append(f"the box moved out where the object reached it: {', '.join(moved)}")
    box = GridBox.fit(lo, hi, size)
    old = regrid(model.field, box, old_occ, model.config.sparse_from, model.config.sparse_margin)
    model.estimator.set_box(box)
    if optimizer is not None:
        replace_param(optimizer, old, model.field.grid, sink=model.field.sink)
    if model.estimator.active:
        model.refresh_occupancy()
    return notes


def growth_due(model: FastNeRF, s: StepState) -> bool:
    return model.stage < len(model.steps) and s.step >= model.steps[model.stage] and not growth_too_late(s)


def grow_next(model: FastNeRF, s: StepState) -> str:
    """Every growth due (a resumed run catches up on every stage it passed); the log line."""
    notes = []
    while growth_due(model, s):
        follow = (
            model.config.box_follows
            and model.stage > 0
            and s.progress < BOX_FOLLOW_UNTIL
            and model.surroundings is not None
            and model.surroundings.holds_object
            and model.ndc is None
        )
        shrink = model.config.shrink_box and model.stage == 0
        notes += grow(model, model.sizes[model.stage + 1], shrink, follow, s.optimizer)
        model.stage += 1
    return "; ".join([stage_note(model.field), *notes])


def stage_note(field: GridField) -> str:
    rx, ry, rz = field.res
    n, m = field.geom.n_vertices, field.stored_vertices
    mb = field.grid.numel() * 4 / 1e6
    return (
        f"grid {rx}x{ry}x{rz} vertices, {m / 1e6:.2f} M of {n / 1e6:.2f} M stored ({100 * m / n:.0f}%, "
        f"{mb:.0f} MB; {(2 + field.sink.lanes) * mb:.0f} MB more for Adam and gradients)"
    )


def faces_note(model: FastNeRF) -> list[str]:
    """A note when the trained object reaches a face of a capture's box: what crosses it is
    cut off (the box follows the object only in the first half of a run)."""
    s = model.surroundings
    if s is None or not s.holds_object or model.ndc is not None or model.isolated:
        return []
    faces = [f"{'xyz'[axis]}{'-+'[side]}" for axis, side in faces_reached_by(model)]
    if not faces:
        return []
    return [
        f"the object reaches the {', '.join(faces)} face{'s' if len(faces) > 1 else ''} of the model's box "
        "at the end of training, so what reaches past it is cut off there. Look at the object video "
        "(`nerfkit render RUN --object`); if the object is cut, train again with --no-object-box: the box "
        "then starts from the scene's whole sphere, not from the sparse points (room for floaters too)"
    ]
