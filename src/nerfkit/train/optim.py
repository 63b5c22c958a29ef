"""The optimizer the trainer builds for a model, from the model's parameter groups, and the
one way a model swaps a parameter in it (:func:`replace_param`: a grid's growth, splat's
densification and pruning), keeping the moments of everything else."""

from __future__ import annotations

import torch

from ..kernels.optim import GridAdam, replace_param
from ..models.base import NerfModel


def budget_factor(run_steps: float | None, steps: int, power: float, floor: float) -> float:
    """A learning-rate factor by the run's length: 1 for a run of at most ``steps`` steps,
    ``(steps / run_steps) ** power`` for a longer one, never below ``floor``; 1 while the
    length is unknown (None)."""
    if run_steps is None or run_steps <= steps:
        return 1.0
    return max(floor, (steps / run_steps) ** power)


def decay_lr(groups: list[dict], progress: float, run_steps: float | None, final_factor: float) -> None:
    """Set each parameter group's ``lr`` at ``progress`` (0..1) of a run of ``run_steps``
    steps: its ``initial_lr`` decayed exponentially to ``lr_final_factor`` (the group's own,
    else ``final_factor``), times :func:`budget_factor` of the run's length for a group with
    ``lr_budget`` (steps, power, floor)."""
    for g in groups:
        factor = g.get("lr_final_factor", final_factor) ** progress
        if "lr_budget" in g:
            factor *= budget_factor(run_steps, *g["lr_budget"])
        g["lr"] = g["initial_lr"] * factor


def build_optimizer(model: NerfModel, lr: float) -> torch.optim.Optimizer:
    """Adam over ``model.param_groups(lr)``; when the model gathers some gradients in
    GradSinks (:meth:`~nerfkit.models.base.NerfModel.grad_sinks`), :class:`GridAdam`,
    which updates only the rows a step touched (dense parameters get ordinary Adam)."""
    groups = model.param_groups(lr)
    sinks = model.grad_sinks()
    if sinks:
        return GridAdam(groups, sinks=sinks)
    return torch.optim.Adam(groups)


__all__ = ["budget_factor", "build_optimizer", "decay_lr", "replace_param"]
