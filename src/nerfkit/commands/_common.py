"""Pieces shared by the subcommands that work on trained runs."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any


def add_run_args(p: argparse.ArgumentParser) -> None:
    """RUN, --data, --device and --chunk: the arguments of every command on a trained run."""
    p.add_argument("run", metavar="RUN", help="run folder written by `nerfkit train`")
    p.add_argument("--data", help="dataset (default: the one the run was trained on)")
    add_run_device_args(p)


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


@dataclass
class OpenRun:
    """A trained run loaded for rendering: the model (eval mode) and how to render it."""

    model: Any
    info: Any  # RunInfo: the run's config, model config and bounds
    step: int
    device: Any  # torch.device
    chunk: int  # rays rendered at once
    autocast: Any  # torch dtype or None

    def background(self, override: str | None = None):
        """The run's background colour (or ``override``) as a (3,) tensor on the device."""
        import torch

        from ..train.config import parse_background

        return torch.tensor(parse_background(override or self.info.train.background), dtype=torch.float32,
                            device=self.device)


def open_run(args: argparse.Namespace) -> OpenRun:
    """Load ``args.run`` on ``args.device`` with the render chunk of ``args.chunk`` or the run."""
    from ..train.checkpoint import load_run
    from ..train.config import resolve_autocast, resolve_device

    device = resolve_device(args.device)
    model, info, step = load_run(args.run, device)
    chunk = args.chunk or getattr(info.train, "render_chunk", 0) or 8192
    return OpenRun(model, info, step, device, chunk, resolve_autocast(info.train.precision, device))
