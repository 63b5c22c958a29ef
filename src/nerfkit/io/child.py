"""A call run in a child process, so that a stop signal ends it at once.

Native code that runs for minutes without returning to Python (pycolmap's matching and
mapping) holds up a stop: Python runs its signal handlers only between bytecodes, and
pycolmap stops its worker threads only between blocks of work. Run in a child, such a call
is killed when the stop comes (Ctrl-C or SIGTERM: a KeyboardInterrupt here, see
:mod:`nerfkit.cli`), and the stop goes on as anywhere else. The child never takes a stop
signal itself (they are blocked in it, so a Ctrl-C at the terminal, which reaches every
process of the group, prints nothing there), and it ends should this process die.

The child is a fresh interpreter (``sys.executable``) with this process's ``sys.path``,
not a fork (this process may hold threads, OpenMP's among them) and not multiprocessing's
spawn (which runs the main script again: a user's script without a ``__main__`` guard
would start over).
"""

from __future__ import annotations

import contextlib
import os
import pickle
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any

from ..errors import fail
from .stop import STOP_SIGNALS

# the child's first line: this process's sys.path (the first pickle on its stdin), then serve()
_BOOT = "import pickle, sys; sys.path[:] = pickle.load(sys.stdin.buffer); from nerfkit.io.child import serve; serve()"


def in_child(fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)`` in a child process: its result, or the exception it raised.

    ``fn`` must be a module-level function, and its arguments and result picklable. Any
    exception here while it runs (KeyboardInterrupt: a stop) kills the child at once.
    Raises NerfkitError when the child ends without an answer (killed, or crashed). Off
    POSIX (no descriptors to pass, no signal masks) it runs here.
    """
    if os.name != "posix":
        return fn(*args, **kwargs)
    read_end, write_end = os.pipe()
    with open(read_end, "rb") as answers, _child(write_end) as child:
        answer = _ask(child, answers, (fn, args, kwargs))
    if not answer:
        code = child.returncode
        how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
        raise fail(
            f"{fn.__module__}.{fn.__qualname__}",
            f"its process ended without finishing ({how}{', most often the system out of memory' * (code == -9)})",
            "Run the command again (with smaller inputs if memory ran out)",
        )
    ok, value = pickle.loads(answer)
    if not ok:
        raise value
    return value


@contextlib.contextmanager
def _child(answer_fd: int) -> Iterator[subprocess.Popen]:
    """A fresh interpreter running :func:`serve`, answering on ``answer_fd``; killed should
    the block raise (a stop). It starts with the stop signals blocked, and keeps them so."""
    before = _block_stop_signals()
    try:
        child = subprocess.Popen(
            [sys.executable, "-c", _BOOT, str(answer_fd)], stdin=subprocess.PIPE, pass_fds=(answer_fd,)
        )
    except BaseException:
        _restore_signals(before)
        raise
    finally:
        os.close(answer_fd)  # the child's copy alone: the answer ends when the child closes it
    assert child.stdin is not None  # stdin=PIPE
    try:
        _restore_signals(before)  # a stop that came meanwhile is raised here, with the child guarded
        yield child
        _close(child.stdin)  # the child ends (see serve)
        child.wait()
    except BaseException:
        child.kill()
        child.wait()
        raise
    finally:
        _close(child.stdin)


def _ask(child: subprocess.Popen, answers, call: tuple) -> bytes:
    """Send ``call`` to ``child`` (after this process's sys.path) and wait for its answer:
    b"" when it ended without one."""
    assert child.stdin is not None  # stdin=PIPE
    try:
        pickle.dump(sys.path, child.stdin)
        pickle.dump(call, child.stdin)
        child.stdin.flush()
    except BrokenPipeError:  # it ended before reading (it could not start)
        pass
    return answers.read()


def _close(pipe) -> None:
    with contextlib.suppress(BrokenPipeError):  # (what was left to flush has no reader)
        pipe.close()


def _block_stop_signals() -> set:
    """Block the stop signals (a stop that comes waits till they are unblocked); the mask before."""
    return signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)


def _restore_signals(before: set) -> None:
    signal.pthread_sigmask(signal.SIG_SETMASK, before)


def serve() -> None:
    """The child's side of :func:`in_child`: read the call from stdin, run it, write
    ``(True, result)`` or ``(False, exception)`` to the pipe whose descriptor is ``argv[1]``."""
    fn, args, kwargs = pickle.load(sys.stdin.buffer)
    threading.Thread(target=_end_with_stdin, daemon=True).start()
    try:
        answer: tuple[bool, Any] = (True, fn(*args, **kwargs))
    except Exception as e:  # noqa: BLE001 - any error is the caller's to handle
        answer = (False, e)
    try:
        data = pickle.dumps(answer)
    except Exception as e:  # noqa: BLE001 - what pickle cannot carry is sent in words
        ok, value = answer
        words = f"a result that cannot be sent back ({e})" if ok else f"{type(value).__name__}: {value}"
        data = pickle.dumps((False, RuntimeError(words)))
    with contextlib.suppress(BrokenPipeError), open(int(sys.argv[1]), "wb") as out:  # (broken: the parent is gone)
        out.write(data)


def _end_with_stdin() -> None:
    """End this child as soon as its stdin closes: the parent is gone, or done with it. (Read
    from the descriptor: a thread blocked in sys.stdin's reader would hold the lock that the
    interpreter's exit takes.)"""
    while os.read(0, 1 << 16):
        pass
    os._exit(1)
