"""A stop signal remembered: the command line turns SIGTERM into KeyboardInterrupt, and a
library that swallows that exception while it is being imported (a bare ``except:``) must
not make the stop be forgotten. Whoever takes over the signals later (the trainer) asks
:func:`take` whether a stop came first."""

from __future__ import annotations

_requested = False


def request() -> None:
    """Remember that a stop was asked for."""
    global _requested
    _requested = True


def pending() -> bool:
    """Whether a stop was asked for and not yet taken."""
    return _requested


def take() -> bool:
    """Whether a stop was asked for since the last call (and forget it)."""
    global _requested
    asked, _requested = _requested, False
    return asked
