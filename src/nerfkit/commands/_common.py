"""Pieces shared by the subcommands that work on trained runs."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_run_device_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N (default: auto)")
    p.add_argument("--chunk", type=int, default=0, help="rays rendered at once; lower it if memory runs out "
                                                         "(default: the run's render chunk)")


def scene_for_run(info, data: str | None):
    """The run's dataset (or ``data`` when given), with a clear error when it has moved."""
    from ..data.load import load_scene
    from ..errors import fail

    path = data or info.train.data
    if not path:
        raise fail(info.run_dir, "the run does not record its dataset", "Pass --data")
    if not Path(path).exists():
        raise fail(path, "the run's dataset is not there any more", "Pass --data with its new location")
    return load_scene(path)
