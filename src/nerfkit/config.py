"""Dataclass configs <-> command-line flags <-> JSON.

A config is a dataclass whose fields carry ``metadata={"help": ...}``. Each field becomes
a ``--kebab-case`` flag; the resolved config is saved as JSON into every run folder.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from .errors import fail

T = TypeVar("T")

# the largest --seed: every random generator nerfkit seeds (numpy, torch) takes it
MAX_SEED = 2 ** 32 - 1


def option(default: Any, help: str, **kwargs) -> Any:  # noqa: A002 - mirrors argparse
    """A dataclass field with a default and a help line; ``min``, ``max`` (inclusive) and
    ``above`` (exclusive) bound a number's flag, checked when the command line is parsed."""
    return dataclasses.field(default=default, metadata={"help": help, **kwargs})


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def base_type(tp: Any) -> tuple[Any, bool]:
    """(type, optional) for ``X`` or ``X | None``."""
    if isinstance(tp, types.UnionType) or typing.get_origin(tp) is typing.Union:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return args[0], True
    return tp, False


def number(kind: type = float, min: float | None = None, max: float | None = None,  # noqa: A002 - reads like a range
           above: float | None = None) -> Any:
    """An argparse ``type`` for a finite ``kind`` (int or float) within [min, max] (or > above):
    ``--minutes nan``, ``--fps 0`` or ``--chunk -1`` are refused when the command line is parsed."""

    def parse(text: str):
        try:
            v = kind(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"'{text}' is not {'a whole number' if kind is int else 'a number'}") from None
        if kind is float and not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"'{text}' is not a finite number")
        if min is not None and v < min:
            raise argparse.ArgumentTypeError(f"{text} is below the minimum {min}")
        if max is not None and v > max:
            raise argparse.ArgumentTypeError(f"{text} is above the maximum {max}")
        if above is not None and not v > above:
            raise argparse.ArgumentTypeError(f"{text} must be greater than {above}")
        return v

    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


def _field_type(tp: Any, meta: Any) -> Any:
    """The argparse type of a field: numbers are checked (finite, and the field's
    ``min``/``max``/``above`` metadata); other types pass through."""
    if tp in (int, float):
        return number(tp, meta.get("min"), meta.get("max"), meta.get("above"))
    return tp if tp is str else str


def add_dataclass_args(parser: argparse.ArgumentParser, cls: type, group_title: str | None = None,
                       skip: tuple[str, ...] = ()) -> None:
    """Add one flag per field of dataclass ``cls`` (defaults left unset: None)."""
    target = parser.add_argument_group(group_title) if group_title else parser
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name in skip or f.metadata.get("cli") is False or _flag(f.name) in parser._option_string_actions:
            continue  # a flag shared by two configs is added once
        tp, _ = base_type(hints[f.name])
        default = f.default if f.default is not dataclasses.MISSING else None
        help_text = f.metadata.get("help", "").replace("%", "%%")  # argparse %-formats help
        if default is not None and default != "":
            help_text += f" (default: {default})"
        kw: dict[str, Any] = {"dest": f.name, "default": None, "help": help_text}
        if "choices" in f.metadata:
            kw["choices"] = f.metadata["choices"]
        if tp is bool:
            target.add_argument(_flag(f.name), action=argparse.BooleanOptionalAction, **kw)
        else:
            target.add_argument(_flag(f.name), type=_field_type(tp, f.metadata),
                                metavar=f.metadata.get("metavar", tp.__name__.upper() if hasattr(tp, "__name__") else "X"),
                                **kw)


NAMED_COLOURS = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0), "grey": (0.5, 0.5, 0.5), "gray": (0.5, 0.5, 0.5)}


def parse_background(text: str) -> tuple[float, float, float]:
    """A ``--background`` colour -> RGB floats in [0, 1]: ``black``, ``white``, ``grey``,
    ``R,G,B`` with each value in [0, 1], or ``#rrggbb``. Example: ``"#ff0080"`` ->
    ``(1.0, 0.0, 0.502)``."""
    t = text.strip().lower()
    if t in NAMED_COLOURS:
        return NAMED_COLOURS[t]
    try:
        if t.startswith("#") and len(t) == 7:
            return tuple(int(t[i:i + 2], 16) / 255.0 for i in (1, 3, 5))  # type: ignore[return-value]
        parts = [float(v) for v in t.split(",")]
        if len(parts) == 3 and all(0.0 <= v <= 1.0 for v in parts):
            return tuple(parts)  # type: ignore[return-value]
    except ValueError:
        pass
    raise fail("--background", f"'{text}' is not a colour", "Use black, white, grey, R,G,B with values in [0, 1] "
               "(e.g. 1,0,0) or #rrggbb")


def dataclass_from_args(cls: type[T], args: argparse.Namespace, base: T | None = None) -> T:
    """Build ``cls`` from parsed flags; unset flags keep ``base``'s (or the default) values."""
    values = dataclasses.asdict(base) if base is not None else {}
    for f in dataclasses.fields(cls):
        v = getattr(args, f.name, None)
        if v is not None:
            values[f.name] = v
    return cls(**values)


def dataclass_from_dict(cls: type[T], d: dict, where: str) -> T:
    """Build ``cls`` from JSON data, refusing unknown keys and wrong types with a clear error."""
    if not isinstance(d, dict):
        raise fail(where, f"expected a JSON object of {cls.__name__} settings, got {type(d).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise fail(where, f"unknown config keys: {', '.join(sorted(map(repr, unknown)))}")
    out = {}
    for k, v in d.items():
        tp, optional = base_type(hints[k])
        if v is None and optional:
            out[k] = None
        elif tp is float and isinstance(v, (int, float)) and not isinstance(v, bool):
            if v != v:
                raise fail(where, f"config key '{k}' is NaN, expected a number")
            if not math.isfinite(v):
                raise fail(where, f"config key '{k}' is {v}, expected a finite number")
            out[k] = float(v)
        elif tp in (int, str, bool) and type(v) is tp:
            out[k] = v
        elif tp not in (int, float, str, bool):
            out[k] = v
        else:
            raise fail(where, f"config key '{k}' should be {tp.__name__}, got {type(v).__name__}")
    return cls(**out)


def load_json(path: str | Path, missing: str = "no such file", missing_fix: str | None = None,
              invalid_fix: str = "The file may be truncated; re-create it") -> Any:
    """Parse a JSON file; every failure is one NerfkitError naming the file (hints per caller)."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise fail(path, missing, missing_fix) from None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise fail(path, f"not valid JSON ({type(e).__name__}: {e})", invalid_fix) from None
    except (OSError, ValueError) as e:  # a folder, no permission, a NUL byte in the name
        raise fail(path, f"cannot read ({type(e).__name__}: {e})") from None
