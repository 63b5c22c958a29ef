"""nerfkit's OpenMP setting: threads sleep after a parallel region unless the user chose
otherwise (two OpenMP pools, torch's and the compiled kernels', share the cores while the
fast model trains; spinning threads of one starve the other)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


def wait_policy_after_import(env_value: str | None) -> str:
    """OMP_WAIT_POLICY as a fresh interpreter sees it after ``import nerfkit``."""
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if env_value is not None:
        env["OMP_WAIT_POLICY"] = env_value
    env["PYTHONPATH"] = str(SRC) + os.pathsep + env.get("PYTHONPATH", "")
    code = "import os, nerfkit, sys; sys.stdout.write(os.environ.get('OMP_WAIT_POLICY', '<unset>'))"
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout


def test_import_makes_openmp_threads_sleep_by_default():
    assert wait_policy_after_import(None) == "PASSIVE"


@pytest.mark.parametrize("chosen", ["ACTIVE", "passive"])
def test_a_wait_policy_the_user_set_is_kept(chosen):
    assert wait_policy_after_import(chosen) == chosen


def test_the_policy_is_set_before_torch_loads():
    """torch (and numba) read the variable once, when their OpenMP runtime loads: nerfkit's
    package import must not load torch first."""
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    env["PYTHONPATH"] = str(SRC) + os.pathsep + env.get("PYTHONPATH", "")
    code = "import sys, nerfkit; sys.stdout.write(str('torch' in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out == "False"
