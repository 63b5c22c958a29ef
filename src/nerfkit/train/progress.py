"""How far a run is, by its stopping rule (``--steps``, ``--minutes``, or both: whichever
ends it first), and when it renders its val views: functions of the step and the training
seconds reached, for the trainer to call."""

from __future__ import annotations

import bisect

# a timed run's length in steps is estimated from its rate after this many steps
RATE_STEPS = 20
# the shares of a run (steps or minutes) at which it renders its val views without
# --eval-every: each tenth, and twice before the first, where the held-out score climbs
# fastest (on a real capture it is near its last value by the first tenth:
# benchmarks/capture_real.py)
EVAL_MARKS = (0.01, 0.03) + tuple(k / 10 for k in range(1, 11))


def run_progress(step: int, seconds: float, steps: int, minutes: float) -> float:
    """Fraction of the run done at ``step`` after ``seconds`` of training, by ``steps`` or by
    ``minutes`` (0: not that rule), whichever is further; at most 1."""
    p = 0.0
    if steps:
        p = max(p, step / steps)
    if minutes:
        p = max(p, seconds / (60.0 * minutes))
    return min(p, 1.0)


def run_length(step: int, seconds: float, steps: int, minutes: float) -> float | None:
    """The run's length in steps: ``steps``, or the steps ``minutes`` buys at the rate so far
    (``step`` in ``seconds``), whichever ends the run first (None: a timed run's first
    :data:`RATE_STEPS` steps)."""
    n = float(steps) if steps else None
    if minutes and step >= RATE_STEPS and seconds > 0:
        timed = step * 60.0 * minutes / seconds
        n = timed if n is None else min(n, timed)
    return n


def marks_reached(progress: float) -> int:
    """How many of :data:`EVAL_MARKS` a run at ``progress`` (0..1) has reached."""
    return bisect.bisect_right(EVAL_MARKS, progress + 1e-9)
