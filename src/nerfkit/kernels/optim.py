"""Adam that updates only the grid rows a step touched (lazy / sparse Adam).

A dense Adam step over a 7M-vertex grid costs more than the whole rendering pass; the
rays of one step touch a few hundred thousand rows. :class:`GridAdam` is a
``torch.optim.Optimizer`` (its ``state_dict`` round-trips, so checkpoints resume):

* parameters registered with a :class:`~nerfkit.kernels.ops.GradSink` are updated on
  the sink's touched rows only (their moments elsewhere are left as they are, as in
  ``torch.optim.SparseAdam``); a dense ``.grad`` (torch path) is folded into the sink
  first. A group may carry ``channel_lr_scale`` (one factor per column) so density and
  colour columns of one tensor get different learning rates.
* other parameters get the ordinary dense Adam update.

A grid row whose gradient is not finite is not updated; ``nonfinite_rows`` counts them
for the last step, so the trainer's numerical guard sees them without a separate pass
over the gradient (which would cost about 15% of a step).
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import numba_kernels
from . import reference as ref
from .ops import GradSink


class GridAdam(torch.optim.Optimizer):
    """Adam with sparse updates for grid parameters.

    Args:
        params: parameter groups (dicts with ``params``, ``lr``, optional ``channel_lr_scale``).
        sinks: ``{parameter: GradSink}`` for the grid parameters.
        betas, eps: as in Adam.
    """

    def __init__(self, params, sinks: dict | None = None, betas=(0.9, 0.99), eps: float = 1e-15):
        super().__init__(params, dict(lr=1e-2, betas=betas, eps=eps, channel_lr_scale=None))
        self._sinks = {id(p): s for p, s in (sinks or {}).items()}
        self.nonfinite_rows = 0

    def sink_of(self, p: Tensor) -> GradSink | None:
        return self._sinks.get(id(p))

    def set_sink(self, old: Tensor, new: Tensor, sink: GradSink | None) -> None:
        """``new`` replaces ``old``: it gathers its gradients in ``sink`` (None: in ``.grad``)."""
        self._sinks.pop(id(old), None)
        if sink is not None:
            self._sinks[id(new)] = sink

    def zero_grad(self, set_to_none: bool = True) -> None:
        super().zero_grad(set_to_none=set_to_none)
        for sink in self._sinks.values():
            sink.clear()

    @torch.no_grad()
    def step(self, closure=None):
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        self.nonfinite_rows = 0
        for group in self.param_groups:
            beta1, beta2 = group["betas"]
            for p in group["params"]:
                sink = self.sink_of(p)
                if sink is None:
                    if p.grad is not None:
                        self._dense_step(p, group)
                    continue
                if p.grad is not None:
                    sink.add_dense(p.grad)
                    p.grad = None
                sink.drop_frozen()
                if not sink.dirty:
                    continue
                state, step = self._next_step(p)
                scale = group.get("channel_lr_scale")
                lr = torch.full((p.shape[1],), float(group["lr"]), dtype=torch.float32, device=p.device)
                if scale is not None:
                    lr = lr * torch.tensor(scale, dtype=torch.float32, device=p.device)
                nb = numba_kernels() if p.device.type == "cpu" else None
                if nb is not None:
                    import numba

                    touched = sink.touched.numpy()
                    with numba.parallel_chunksize(4096):
                        self.nonfinite_rows += nb.adam_rows(
                            p.data.numpy(),
                            sink.grad.numpy(),
                            nb.touched_rows(touched),
                            touched,
                            state["exp_avg"].numpy(),
                            state["exp_avg_sq"].numpy(),
                            lr.numpy(),
                            beta1,
                            beta2,
                            group["eps"],
                            1 - beta1**step,
                            1 - beta2**step,
                        )
                else:
                    rows = sink.touched_rows()
                    self.nonfinite_rows += ref.adam_rows(
                        p.data,
                        sink.total(rows),
                        rows,
                        state["exp_avg"],
                        state["exp_avg_sq"],
                        lr,
                        beta1,
                        beta2,
                        group["eps"],
                        step,
                    )
                    sink.grad[:, rows] = 0.0
                    sink.touched.zero_()
                sink.dirty = False
        return loss

    def _next_step(self, p: Tensor) -> tuple[dict, int]:
        """``p``'s Adam state (moments at zero on its first step) and its step count, advanced by one."""
        state = self.state[p]
        if not state:
            state["step"] = torch.zeros((), dtype=torch.float32)
            state["exp_avg"] = torch.zeros_like(p)
            state["exp_avg_sq"] = torch.zeros_like(p)
        state["step"] += 1
        return state, int(state["step"])

    def _dense_step(self, p: Tensor, group: dict) -> None:
        beta1, beta2 = group["betas"]
        state, step = self._next_step(p)
        g = p.grad
        state["exp_avg"].mul_(beta1).add_(g, alpha=1 - beta1)
        state["exp_avg_sq"].mul_(beta2).addcmul_(g, g, value=1 - beta2)
        denom = (state["exp_avg_sq"] / (1 - beta2**step)).sqrt_().add_(group["eps"])
        p.addcdiv_(state["exp_avg"], denom, value=-group["lr"] / (1 - beta1**step))


def replace_param(
    optimizer: torch.optim.Optimizer, old: Tensor, new: Tensor, rows: Tensor | None = None, sink: GradSink | None = None
) -> None:
    """Put parameter ``new`` in the place of ``old`` in ``optimizer``, in place: every other
    parameter keeps its Adam moments (and the groups their learning rates).

    Args:
        rows: (len(new),) long, for a parameter whose rows were edited (Gaussians added or
            pruned): the row of ``old`` each row of ``new`` continues, whose moments it
            takes; -1 for a new row (moments zero). None: ``new`` starts afresh (no state:
            zero moments, step count 0), as a resampled grid does.
        sink: the :class:`GradSink` ``new`` gathers its gradients in (a :class:`GridAdam`
            parameter), or None.

    Example: rows ``[0, 2, -1]`` keeps old rows 0 and 2 and appends one new row.
    """
    for group in optimizer.param_groups:
        at = [i for i, p in enumerate(group["params"]) if p is old]
        if at:
            group["params"][at[0]] = new
            break
    else:
        raise ValueError("replace_param: the parameter is not in the optimizer")
    state = optimizer.state.pop(old, None)
    if state and rows is not None:
        src = rows >= 0
        for key in ("exp_avg", "exp_avg_sq"):
            moment = state[key]
            carried = moment.new_zeros((len(rows), *moment.shape[1:]))
            carried[src] = moment[rows[src]]
            state[key] = carried
        optimizer.state[new] = state
    if isinstance(optimizer, GridAdam):
        optimizer.set_sink(old, new, sink)
