"""A call in a child process that a stop ends at once (nerfkit.io.child.in_child)."""

from __future__ import annotations

import contextlib
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from nerfkit.errors import NerfkitError
from nerfkit.io.child import in_child

linux_only = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")


def test_the_result_or_the_exception_comes_back():
    assert in_child(math.hypot, 3.0, 4.0) == 5.0
    with pytest.raises(ValueError, match="math domain error"):
        in_child(math.sqrt, -1.0)


def test_a_child_that_dies_is_a_one_line_error_with_how():
    with pytest.raises(NerfkitError, match=r"ended without finishing \(killed by signal 6\)"):
        in_child(os.abort)
    with pytest.raises(NerfkitError, match=r"ended without finishing \(exit code 3\)"):
        in_child(os._exit, 3)


def test_the_child_holds_the_stop_signals_blocked():
    # a Ctrl-C at the terminal reaches the whole process group: the child must not take it
    assert {signal.SIGINT, signal.SIGTERM} <= in_child(signal.pthread_sigmask, signal.SIG_BLOCK, [])


def _children() -> list[int]:
    """The processes whose parent is this one."""
    me, out = os.getpid(), []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == me:
            out.append(int(pid))
    return out


def _stop(signum, frame):
    raise KeyboardInterrupt  # what the command line makes of SIGTERM


@linux_only
def test_a_stop_kills_the_child_at_once():
    before = signal.signal(signal.SIGTERM, _stop)
    timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGTERM))
    try:
        timer.start()
        start = time.monotonic()
        with pytest.raises(KeyboardInterrupt):
            in_child(time.sleep, 60)
        assert time.monotonic() - start < 5  # not the minute the call would take
    finally:
        timer.cancel()
        signal.signal(signal.SIGTERM, before)
    assert _children() == []


@linux_only
def test_the_child_ends_when_its_parent_dies(tmp_path):
    # the parent killed outright (SIGKILL: no chance to kill the child): the child ends by itself
    pids = tmp_path / "pids"
    script = (
        "import os\nfrom nerfkit.io.child import in_child\n"
        f"in_child(os.system, 'echo $PPID $$ > {pids}.tmp && mv {pids}.tmp {pids} && exec sleep 60')\n"
    )
    parent = subprocess.Popen(
        [sys.executable, "-c", script], env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    )
    try:
        deadline = time.monotonic() + 60
        while not pids.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        child, sleeper = map(int, pids.read_text().split())  # the child's Python, and the shell it runs
    finally:
        parent.kill()
        parent.wait()
    try:
        deadline = time.monotonic() + 5
        while _alive(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(child)
    finally:
        for pid in (child, sleeper):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, dead but not yet reaped, does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False
