"""Stop signals caught for the length of a block (nerfkit.io.stop.signals_caught)."""

from __future__ import annotations

import os
import signal
import threading

import pytest

from nerfkit.io import stop


def test_a_stop_signal_in_the_block_sets_the_flag_and_the_handler_comes_back():
    before = signal.getsignal(signal.SIGTERM)
    with stop.signals_caught() as interrupted:
        assert not interrupted()
        os.kill(os.getpid(), signal.SIGTERM)
        assert interrupted()
    assert interrupted() and signal.getsignal(signal.SIGTERM) is before


def test_a_stop_asked_for_before_the_block_counts_and_is_taken():
    stop.request()
    with stop.signals_caught() as interrupted:
        assert interrupted() and not stop.pending()


def test_off_the_main_thread_no_handler_is_set():
    seen = []

    def work():
        with stop.signals_caught((signal.SIGUSR1,)) as interrupted:
            seen.append((signal.getsignal(signal.SIGUSR1), interrupted()))

    before = signal.getsignal(signal.SIGUSR1)
    thread = threading.Thread(target=work)
    thread.start()
    thread.join()
    assert seen == [(before, False)]


SIGTERM_AFTER_PYCOLMAP = """
import os, signal, sys
signal.signal(signal.SIGTERM, lambda s, f: print("Python's handler"))
from nerfkit.data.colmap import import_pycolmap
import_pycolmap("test")
os.kill(os.getpid(), signal.SIGTERM)
"""


def test_sigterm_stays_pythons_after_pycolmap_is_imported():
    # pycolmap's import hands SIGTERM to glog: a native stack dump, then death by the signal
    import importlib.util
    import subprocess
    import sys

    if importlib.util.find_spec("pycolmap") is None:
        pytest.skip("pycolmap not installed")
    proc = subprocess.run([sys.executable, "-c", SIGTERM_AFTER_PYCOLMAP], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout == "Python's handler\n", proc
    assert "***" not in proc.stderr, proc.stderr
