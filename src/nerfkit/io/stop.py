"""A stop signal remembered: the command line turns SIGTERM into KeyboardInterrupt, and a
library that swallows that exception while it is being imported (a bare ``except:``) must
not make the stop be forgotten. Whoever takes over the signals later (the trainer) asks
:func:`take` whether a stop came first."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

# Signals that stop training cleanly (finish the step, save, exit): Ctrl-C, and what
# `kill`, `timeout`, schedulers and containers send.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

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


def take_back_sigterm() -> None:
    """Put Python's SIGTERM handler back in force. Importing pycolmap installs glog's failure
    handler for SIGTERM below Python (a stack dump, then death by the signal) while Python
    still reports its own: the command line's stop, the default (end quietly) or ignored.
    Off the main thread nothing can be set, and nothing is."""
    try:
        handler = signal.getsignal(signal.SIGTERM)
        if handler is not None:  # (None: not set from Python, so nothing of Python's to put back)
            signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread
        pass


class StopFlag:
    """Whether a stop signal came, set by the handlers :func:`signals_caught` installs:
    call it (``flag()``)."""

    def __init__(self) -> None:
        self.stopped = False

    def __call__(self) -> bool:
        return self.stopped


@contextmanager
def signals_caught(signals: tuple[signal.Signals, ...] = STOP_SIGNALS) -> Iterator[StopFlag]:
    """Within the block, ``signals`` set the yielded :class:`StopFlag` instead of stopping
    the process (the flag starts as :func:`take`: a stop that came while starting up, its
    exception swallowed by an import); the handlers before come back on leaving it.
    Handlers can only be set on the main thread: elsewhere (a GUI's worker, a web handler)
    none is set, and a run stops at its budget. A signal ignored by whoever started us
    (nohup, a script) stays ignored."""
    flag = StopFlag()
    main = threading.current_thread() is threading.main_thread()
    previous = {s: signal.getsignal(s) for s in signals} if main else {}

    def on_stop_signal(signum, frame):  # finish the current step, then save and stop
        flag.stopped = True

    try:
        for s in previous:
            if previous[s] is not signal.SIG_IGN:
                signal.signal(s, on_stop_signal)
        flag.stopped = take()
        yield flag
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
