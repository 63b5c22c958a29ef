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
    """--device and --chunk (:class:`~nerfkit.commands.options.RunDeviceOptions`), and --allow-outside-paths."""
    from ..config import add_dataclass_args
    from .options import RunDeviceOptions

    add_dataclass_args(p, RunDeviceOptions)
    add_outside_flag(p)


def run_device_options(args: argparse.Namespace) -> dict:
    """The API keywords of a run command's --data, --device, --chunk and --allow-outside-paths
    (--device and --chunk unset: :class:`~nerfkit.commands.options.RunDeviceOptions`' defaults)."""
    import dataclasses

    from ..config import dataclass_from_args
    from .options import RunDeviceOptions

    return {
        "data": args.data,
        **dataclasses.asdict(dataclass_from_args(RunDeviceOptions, args)),
        "allow_outside_paths": args.allow_outside_paths,
    }


def add_outside_flag(p: argparse.ArgumentParser) -> None:
    """``--allow-outside-paths``: the opt-in to read dataset files outside the dataset folder."""
    from ..io.paths import OUTSIDE_FLAG

    p.add_argument(
        OUTSIDE_FLAG,
        action="store_true",
        help="read dataset images that lie outside the dataset's folder (only for a dataset you trust)",
    )


def run_dataset_path(info) -> Path:
    """The dataset a run was trained on (absolute since runs record it so; older runs
    recorded it as typed, relative to the folder train ran in)."""
    from ..errors import fail

    if not info.train.data:
        raise fail(info.run_dir, "the run does not record its dataset", "Pass --data")
    path = Path(info.train.data)
    if not path.exists():
        raise fail(
            info.run_dir,
            f"its dataset {path} is not there any more",
            "Pass --data NEW_PATH with the dataset's new location",
        )
    return path


def load_as_trained(train, path, need: str = "train", allow_outside: bool = False):
    """The dataset at ``path`` loaded as a run with TrainConfig ``train`` sees it: transparent
    pixels on its ``--background`` colour, images divided by its ``--downscale``."""
    from ..config import parse_background
    from ..data.load import load_scene

    downscale = getattr(train, "downscale", 0.0) or None  # (a config without the field: as stored)
    return load_scene(
        path, parse_background(train.background), downscale=downscale, need=need, allow_outside=allow_outside
    )


def scene_for_run(info, data: str | None, need: str = "train", allow_outside: bool = False):
    """The run's dataset (checked against the run's fingerprint), or ``data`` when given;
    loaded as in training (:func:`load_as_trained`)."""
    from ..train.checkpoint import check_dataset

    if data:
        return load_as_trained(info.train, data, need=need, allow_outside=allow_outside)
    allow_outside = allow_outside or getattr(info.train, "allow_outside_paths", False)  # as the run was trained
    scene = load_as_trained(info.train, run_dataset_path(info), allow_outside=allow_outside)
    check_dataset(info, scene)
    return scene


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

        return torch.tensor(
            parse_background(override or self.info.train.background), dtype=torch.float32, device=self.device
        )


@dataclass(frozen=True)
class RunToOpen:
    """Which run :func:`open_run` loads, and how: ``run`` (its folder), ``device`` ("auto", "cpu",
    "cuda" or "cuda:N") and ``chunk`` (rays rendered at once; 0: the run's render chunk).
    The parsed arguments of a command on a run carry the same three names."""

    run: str | Path
    device: str = "auto"
    chunk: int = 0


def open_run(which: RunToOpen) -> OpenRun:
    """Load ``which.run`` on ``which.device`` with the render chunk of ``which.chunk`` or the run."""
    from ..precision import resolve_device, resolve_precision
    from ..train.checkpoint import load_run

    device = resolve_device(which.device)
    model, info, step = load_run(which.run, device)
    chunk = which.chunk or getattr(info.train, "render_chunk", 0) or 8192
    dtype = resolve_precision(info.train.precision, device)
    model.set_precision(dtype)
    return OpenRun(model, info, step, device, chunk, dtype)
