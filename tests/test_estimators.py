"""The occupancy estimator and the grid box: one value for the box, buffers that round-trip,
a refresh rule the estimator applies itself; and the one way a parameter is swapped in an
optimizer (growth, densification) keeping every other parameter's moments."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nerfkit.estimators.occupancy import OccupancyEstimator, RefreshRule
from nerfkit.kernels.ops import GradSink
from nerfkit.kernels.optim import GridAdam, replace_param
from nerfkit.render.box import GridBox


def test_grid_box_docstring_example():
    box = GridBox((0, 0, 0), 0.5, (3, 5, 2))
    assert box.hi_array.tolist() == [1.0, 2.0, 0.5]
    assert box.cell_shape == (1, 4, 2) and box.n_vertices == 30
    with pytest.raises(ValueError, match="at least 2"):
        GridBox((0, 0, 0), 1.0, (1, 3, 3))


def test_refresh_rule_counts_warmup_then_every():
    rule = RefreshRule(first=16, every=64, warmup_every=16, warmup_until=64)
    assert [n for n in range(1, 200) if rule.due(n)] == [16, 32, 48, 64, 128, 192]
    assert [n for n in range(0, 10) if RefreshRule(first=0, every=4).due(n)] == [0, 4, 8]


def test_update_every_n_steps_refreshes_only_when_due_and_marks_active():
    est = OccupancyEstimator(GridBox((0, 0, 0), 1.0, (3, 3, 3)), RefreshRule(first=2, every=2))
    calls = []
    ran = [est.update_every_n_steps(n, lambda: calls.append(1)) for n in range(5)]
    assert ran == [False, False, True, False, True] and len(calls) == 2 and est.active


def test_occupancy_state_round_trips_and_running_max_measures_every_cell():
    box = GridBox((-1, -1, -1), 0.5, (5, 5, 5))
    est = OccupancyEstimator(box, running_max=True)
    assert not est.measured and est.occupied_fraction == 1.0

    def ball(points):  # density 10 inside the unit ball, 0 outside
        return 10.0 * (points.norm(dim=-1) < 0.6).float()

    torch.manual_seed(0)
    est.measure(ball, step=0.1, alpha_thre=0.01, decay=0.8)
    assert est.measured and 0.0 < est.occupied_fraction < 1.0
    fresh = OccupancyEstimator(box, running_max=True)
    fresh.load_state_dict(est.state_dict())
    fresh.refresh_from_running_max(0.1, 0.01)
    assert torch.equal(fresh.occ, est.occ)
    # a point in the middle is occupied, a corner is not
    assert est.is_occupied(torch.tensor([[0.0, 0.0, 0.0], [-0.95, -0.95, -0.95]])).tolist() == [True, False]


def test_replace_param_keeps_other_moments_and_reindexes_rows():
    a, b = torch.nn.Parameter(torch.ones(4, 2)), torch.nn.Parameter(torch.ones(3))
    opt = torch.optim.Adam([{"params": [a], "lr": 0.1}, {"params": [b], "lr": 0.2}])
    (a.sum() * 2 + (b * torch.arange(3.0)).sum()).backward()
    opt.step()
    moments_a = opt.state[a]["exp_avg"].clone()
    moments_b = opt.state[b]["exp_avg"].clone()
    new_a = torch.nn.Parameter(torch.zeros(3, 2))
    replace_param(opt, a, new_a, rows=torch.tensor([3, 0, -1]))
    assert opt.param_groups[0]["params"][0] is new_a and a not in opt.state
    assert torch.equal(opt.state[new_a]["exp_avg"], torch.stack([moments_a[3], moments_a[0], torch.zeros(2)]))
    assert torch.equal(opt.state[b]["exp_avg"], moments_b)  # untouched
    fresh = torch.nn.Parameter(torch.zeros(5))
    replace_param(opt, b, fresh)  # no rows: starts afresh
    assert fresh not in opt.state and opt.param_groups[1]["lr"] == 0.2
    with pytest.raises(ValueError, match="not in the optimizer"):
        replace_param(opt, b, fresh)


def test_replace_param_moves_a_grid_adam_sink():
    grid = torch.nn.Parameter(torch.zeros(4, 3))
    sink = GradSink(4, 3, lanes=1)
    opt = GridAdam([{"params": [grid], "lr": 0.1}], sinks={grid: sink})
    new, new_sink = torch.nn.Parameter(torch.zeros(6, 3)), GradSink(6, 3, lanes=1)
    replace_param(opt, grid, new, sink=new_sink)
    assert opt.sink_of(new) is new_sink and opt.sink_of(grid) is None
    new_sink.add_dense(torch.ones(6, 3))
    opt.step()
    assert np.allclose(new.detach().numpy(), -0.1)  # Adam's first step moves by lr
