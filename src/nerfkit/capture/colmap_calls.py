"""pycolmap's long calls (feature extraction, matching, mapping, triangulation), each in a
child process (:func:`nerfkit.io.child.in_child`), so that Ctrl-C or SIGTERM ends them at
once, as a stop ends any command. Run here, a stop would wait for the native code's
current block of work (a minute and more of matching), and pycolmap logs a line as it stops.

What these calls make is on disk (the database; the models, written to their output
folder); the objects they return stay in the child. Light to import (no torch): the
child imports it to run :func:`_call`.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import NerfkitError, fail, problem_of
from ..io.child import in_child


def run(name: str, *args: Any, seed: int | None = None, reconstruction: Path | None = None, **kwargs: Any) -> None:
    """``pycolmap.<name>(*args, **kwargs)`` in a child process that logs as COLMAP does here
    (:func:`~nerfkit.capture.points.quiet_colmap`), after ``pycolmap.set_random_seed(seed)``
    when ``seed`` is given. ``reconstruction``: a model folder, read in the child and passed
    as the first argument. Raises what the call raised, or NerfkitError when the child died."""
    import pycolmap  # (imported already: the caller made the options)

    args = tuple(_portable(a) for a in args)
    kwargs = {k: _portable(v) for k, v in kwargs.items()}
    try:
        in_child(_call, name, args, kwargs, pycolmap.logging.minloglevel, seed, reconstruction)
    except NerfkitError as e:  # (pycolmap raises none: its process died, killed or crashed)
        raise fail(f"COLMAP's {name}", problem_of(e)) from None


def _call(
    name: str, args: tuple, kwargs: dict, minloglevel: int, seed: int | None, reconstruction: Path | None
) -> None:
    """The child's side of :func:`run`."""
    import pycolmap

    pycolmap.logging.logtostderr = True  # as quiet_colmap: no log files in the temporary folder
    pycolmap.logging.minloglevel = minloglevel
    if seed is not None:
        pycolmap.set_random_seed(seed)
    args = tuple(_rebuilt(pycolmap, a) for a in args)
    kwargs = {k: _rebuilt(pycolmap, v) for k, v in kwargs.items()}
    if reconstruction is not None:
        args = (pycolmap.Reconstruction(str(reconstruction)), *args)
    getattr(pycolmap, name)(*args, **kwargs)  # (what it returns is on disk)


@dataclass(frozen=True)
class _Options:
    """A pycolmap options object as its type's name and the fields that differ from the
    type's defaults (nested options as nested dicts). Pickled whole, it would come back
    with its empty paths as "." (read as pathlib paths): a mask folder "." that is not there."""

    kind: str
    fields: dict


def _portable(value: Any) -> Any:
    """``value``, or as :class:`_Options` when it is a pycolmap options object."""
    if not (hasattr(value, "todict") and hasattr(value, "mergedict")):
        return value
    return _Options(type(value).__name__, _changed(value.todict(), type(value)().todict()))


def _changed(fields: dict, defaults: dict) -> dict:
    out = {}
    for name, value in fields.items():
        if isinstance(value, dict):
            if inner := _changed(value, defaults[name]):
                out[name] = inner
        elif value != defaults[name]:
            out[name] = value
    return out


def _rebuilt(pycolmap, value: Any) -> Any:
    """``value``, with an :class:`_Options` made a pycolmap options object again (in the child)."""
    if not isinstance(value, _Options):
        return value
    options = getattr(pycolmap, value.kind)()
    options.mergedict(value.fields)
    return options


class SayRegistered:
    """``incremental_mapping``'s next_image_callback (it runs in the child): at every tenth
    photo registered, say how many are (the initial pair's two among them)."""

    def __init__(self) -> None:
        self.n = 0

    def __call__(self) -> None:
        self.n += 1
        if self.n % 10 == 0:
            print(f"sfm:   {self.n + 2} photos registered", file=sys.stderr, flush=True)
