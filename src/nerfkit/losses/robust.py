"""Robust per-pixel weighting of the photometric loss against transients (RobustNeRF-style).

A transient is a patch of a photo that no static scene explains: the photographer's shadow
on the table sheet in some photos, a hand, a moving reflection. Fitted, it leaves a faint
smear where it lay. RobustNeRF (Sabour et al. 2023) trims it from the loss: per batch, a
pixel whose residual ranks above a quantile of the batch's (0.8) is an outlier candidate,
and it gets weight 0 only when most of its neighbours are outliers too; a lone
high-residual pixel among inliers (an edge, fine texture) keeps its weight.

RobustNeRF votes among the neighbours of pixels sampled as patches; nerfkit's fast model
trains on random rays, which seldom have a neighbour in the same batch. So each training
photo keeps a memory of its neighbourhoods (:class:`TransientMemory`): a coarse grid of
cells (:data:`CELLS` across the photo's longer side), each with a running share of the rays
drawn there that were inliers. A ray is trimmed when it is an outlier candidate and its
cell's share is at most one half. Trimming starts after a warm-up share of the run, when
the static scene is fitted well enough that a ranking of residuals means something; the
memory learns from the first step.

Rays are ranked by their error less their photo's mean error (:meth:`TransientMemory.debiased`).
A photo whose exposure or white balance the per-photo colour correction has not yet matched
errs in one direction everywhere; ranked by the raw error, all its rays would rank high, be
trimmed, and the correction would never learn the difference. A shadow stands out from its
photo's mean either way.
"""

from __future__ import annotations

import torch
from torch import Tensor

# cells of a photo's neighbourhood memory across its longer side
CELLS = 16
# how far a cell's memory moves toward the share of inliers among a step's rays in it
MEMORY_RATE = 0.1
# a cell whose share of inliers is at most this is mostly outliers (RobustNeRF's 3x3 vote)
VOTE = 0.5


def outlier_candidates(residual: Tensor, quantile: float) -> Tensor:
    """(n,) bool: the rays whose ``residual`` (n,) ranks above ``quantile`` of the batch's
    (RobustNeRF's inlier threshold). About ``(1 - quantile) n`` of them; none when the batch
    is empty or ``quantile`` >= 1."""
    if residual.numel() == 0 or quantile >= 1.0:
        return torch.zeros_like(residual, dtype=torch.bool)
    threshold = torch.quantile(residual.detach().float(), quantile)
    return residual.detach() > threshold


def trimmed_weights(candidate: Tensor, cell_inliers: Tensor, trimming: bool) -> Tensor:
    """(n,) float weights of a batch's rays in the photometric loss: 0 for a ray that is an
    outlier ``candidate`` (n,) bool in a cell whose share of inliers ``cell_inliers`` (n,) is
    at most :data:`VOTE` (mostly outliers), else 1; all 1 while not ``trimming`` (warm-up)."""
    weights = torch.ones(candidate.shape, dtype=torch.float32, device=candidate.device)
    if trimming:
        weights[candidate & (cell_inliers <= VOTE)] = 0.0
    return weights


def weighted_mean(per_ray: Tensor, weights: Tensor) -> Tensor:
    """The mean over all ``n`` rays of ``weights`` (n,) times ``per_ray`` (n,): a trimmed ray adds
    nothing and the others pull as hard as without trimming (RobustNeRF's masked mean)."""
    return (weights.to(per_ray.dtype) * per_ray).sum() / max(per_ray.numel(), 1)


def cell_index(uv: Tensor, image_index: Tensor, width: int, height: int, cells: int = CELLS) -> tuple[Tensor, int, int]:
    """``(flat (n,) long, rows, cols)``: the memory cell of each pixel ``uv`` (n, 2) (column,
    row) of photo ``image_index`` (n,), in photos of ``width`` x ``height`` cut into square-ish
    cells, ``cells`` across the longer side (at most one a pixel)."""
    side = max(width, height) / cells
    cols, rows = min(width, max(1, round(width / side))), min(height, max(1, round(height / side)))
    c = (uv[:, 0].long() * cols // width).clamp(0, cols - 1)
    r = (uv[:, 1].long() * rows // height).clamp(0, rows - 1)
    return (image_index.long() * rows + r) * cols + c, rows, cols


def _toward_batch_means(state: Tensor, index: Tensor, values: Tensor) -> None:
    """In place: move each row of ``state`` (m, ...) that ``index`` (n,) hits toward the mean of
    the ``values`` (n, ...) indexed to it, by :data:`MEMORY_RATE` (rows not hit stay)."""
    hits = torch.zeros(len(state), dtype=state.dtype, device=state.device).index_add_(
        0, index, torch.ones(len(index), dtype=state.dtype, device=state.device)
    )
    sums = torch.zeros_like(state).index_add_(0, index, values.to(state.dtype))
    hit = hits > 0
    means = sums[hit] / hits[hit].reshape(-1, *([1] * (state.ndim - 1)))
    state[hit] += MEMORY_RATE * (means - state[hit])


class TransientMemory:
    """Per training photo, a coarse grid of cells each holding the running share of the rays
    drawn in it that were inliers (1 at the start). Saved in resume checkpoints
    (:meth:`state`), not in the model file: a rendered model needs none."""

    def __init__(self, n_images: int, width: int, height: int, device: torch.device | str = "cpu"):
        self.shape = (n_images, width, height)
        _, rows, cols = cell_index(torch.zeros((1, 2)), torch.zeros(1), width, height)
        self.inliers = torch.ones(n_images * rows * cols, device=device)
        # each photo's running mean signed error per channel (render - photo)
        self.bias = torch.zeros((n_images, 3), device=device)

    def state(self) -> dict:
        """The memory as tensors (for a checkpoint): its photos' count and size, cells and means."""
        return {"shape": torch.tensor(self.shape), "inliers": self.inliers, "bias": self.bias}

    @classmethod
    def from_state(cls, state: dict, device: torch.device | str = "cpu") -> TransientMemory:
        """The memory :meth:`state` saved; ValueError when its tensors do not fit one another."""
        shape = state.get("shape")
        if not isinstance(shape, Tensor) or shape.shape != (3,) or shape.is_floating_point() or bool((shape < 1).any()):
            raise ValueError("'shape' is not three positive whole numbers")
        n, width, height = (int(v) for v in shape)
        memory = cls(n, width, height, device)
        for name in ("inliers", "bias"):
            value = state.get(name)
            like = getattr(memory, name)
            if not isinstance(value, Tensor) or value.shape != like.shape or not bool(torch.isfinite(value).all()):
                raise ValueError(f"'{name}' is not {tuple(like.shape)} finite values")
            setattr(memory, name, value.to(like))
        return memory

    def debiased(self, image_index: Tensor, error: Tensor) -> Tensor:
        """(n,) squared error of each ray less its photo's mean, averaged over channels, from the
        signed ``error`` (n, 3) (render - photo) of rays of photos ``image_index`` (n,)."""
        return ((error.detach().float() - self.bias[image_index.long()]) ** 2).mean(-1)

    def learn_bias(self, image_index: Tensor, error: Tensor, inlier: Tensor) -> None:
        """Move each photo's mean toward the mean signed ``error`` (n, 3) of its ``inlier`` (n,)
        bool rays in the batch by :data:`MEMORY_RATE` (outliers left out, so that a shadow does
        not shift its photo's mean)."""
        _toward_batch_means(self.bias, image_index.long()[inlier], error.detach().float()[inlier])

    def update(self, cells: Tensor, candidate: Tensor) -> Tensor:
        """Move each cell hit by rays in flat ``cells`` (n,) toward the share of them that are not
        outlier ``candidate`` (n,) bool, by :data:`MEMORY_RATE`; returns each ray's cell's share
        (n,) before the update (what the step votes with)."""
        before = self.inliers[cells]
        _toward_batch_means(self.inliers, cells, (~candidate).float())
        return before


def robust_weights(
    error: Tensor,
    memory: TransientMemory,
    image_index: Tensor,
    uv: Tensor,
    quantile: float,
    trimming: bool,
) -> Tensor:
    """(n,) weights of a batch's rays (see the module docstring), updating ``memory``: rays
    ranked by their error less their photo's mean (:meth:`TransientMemory.debiased`), and each
    photo's mean learnt from the batch's inliers (:meth:`TransientMemory.learn_bias`).

    Args:
        error: (n, 3) the rays' signed errors (render - photo).
        memory: the training photos' cells and mean errors.
        image_index: (n,) the photo of each ray; uv: (n, 2) its pixel (column, row).
        quantile: outlier candidates rank above this quantile of the batch's residuals.
        trimming: past the warm-up (else every weight is 1; the memory still learns).
    """
    candidate = outlier_candidates(memory.debiased(image_index, error), quantile)
    memory.learn_bias(image_index, error, ~candidate)
    cells, _, _ = cell_index(uv, image_index, *memory.shape[1:])
    share = memory.update(cells, candidate)
    return trimmed_weights(candidate, share, trimming)
