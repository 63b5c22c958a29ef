"""A run's progress by its stopping rule, its length in steps and its evaluation marks
(nerfkit.train.progress), and the learning rate they set (nerfkit.train.optim.decay_lr)."""

from __future__ import annotations

import pytest

from nerfkit.train.optim import decay_lr
from nerfkit.train.progress import EVAL_MARKS, RATE_STEPS, marks_reached, run_length, run_progress


def test_progress_is_the_further_of_steps_and_minutes_and_stops_at_one():
    assert run_progress(50, 6.0, 100, 0) == 0.5
    assert run_progress(50, 45.0, 100, 1.0) == 0.75  # the clock is further
    assert run_progress(500, 1.0, 100, 0) == 1.0
    assert run_progress(10, 30.0, 0, 1.0) == 0.5


def test_a_timed_runs_length_is_estimated_from_its_rate_once_it_has_one():
    assert run_length(5, 1.0, 300, 0) == 300.0
    assert run_length(RATE_STEPS - 1, 1.0, 0, 1.0) is None
    assert run_length(40, 6.0, 0, 1.0) == pytest.approx(400.0)
    assert run_length(40, 6.0, 300, 1.0) == 300.0  # whichever ends it first


def test_the_marks_reached_count_each_share_passed():
    assert marks_reached(0.0) == 0 and marks_reached(EVAL_MARKS[0]) == 1
    assert marks_reached(0.5) == 2 + 5 and marks_reached(1.0) == len(EVAL_MARKS)


def test_the_learning_rate_decays_to_its_final_factor_and_by_the_budget():
    groups = [{"initial_lr": 1.0}, {"initial_lr": 2.0, "lr_final_factor": 0.5, "lr_budget": (100, 1.0, 0.1)}]
    decay_lr(groups, 1.0, 400.0, 0.1)
    assert groups[0]["lr"] == pytest.approx(0.1) and groups[1]["lr"] == pytest.approx(2.0 * 0.5 * 0.25)
    decay_lr(groups, 0.0, None, 0.1)
    assert [g["lr"] for g in groups] == [1.0, 2.0]
