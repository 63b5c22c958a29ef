"""Dataclass configs <-> command-line flags <-> JSON.

A config is a dataclass whose fields carry ``metadata={"help": ...}``. Each field becomes
a ``--kebab-case`` flag; the resolved config is saved as JSON into every run folder.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import numbers
import types
import typing
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from .errors import fail
from .io.paths import refuse_special_file

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")

# the largest --seed: every random generator nerfkit seeds (numpy, torch) takes it
MAX_SEED = 2**32 - 1
# Rays per training step or per rendering chunk: far more than fits any memory is refused
# when the command line is parsed (a batch that still does not fit is a one-line error).
MAX_BATCH_RAYS = 1 << 20
# the smallest --downscale: it divides the image size, so 1 keeps it (and less would enlarge it)
MIN_DOWNSCALE = 1
# the smallest side resampled images may have: below it a view holds no scene to train or look at
MIN_RESAMPLED_SIDE = 8


def option(default: Any, help: str, **kwargs) -> Any:  # noqa: A002 - mirrors argparse
    """A dataclass field with a default and a help line; ``min``, ``max`` (inclusive) and
    ``above`` (exclusive) bound a number's flag (``off``: a value allowed besides, that
    switches the option off), checked when the command line is parsed
    (:func:`number`) and for configs built otherwise (:func:`check_ranges`). A yes/no field
    marked ``switch`` has one flag, which switches its default (:func:`switch_flag`; ``help``:
    that flag's), not ``--NAME``/``--no-NAME``. ``parse``: the flag's own argparse ``type``
    (text -> value, raising ArgumentTypeError), which then also checks the field's values given
    otherwise (:func:`check_ranges`), instead of the bounds; ``flag``: the field's flag when it is
    not ``--NAME`` (tags' ``dictionary`` is ``--dict``); ``exclusive``: the name of a set of
    fields of which one at most is given (convert's ``--size`` and ``--downscale``): one
    mutually exclusive group of flags, and :func:`check_exclusive` for values given otherwise."""
    return dataclasses.field(default=default, metadata={"help": help, **kwargs})


def flag_of(name: str) -> str:
    """The command-line flag of config field ``name``: ``principal_point`` -> ``--principal-point``."""
    return "--" + name.replace("_", "-")


def field_flag(f: dataclasses.Field) -> str:
    """The flag of dataclass field ``f``: its ``flag`` metadata (:func:`option`), else :func:`flag_of` its name."""
    return f.metadata.get("flag") or flag_of(f.name)


def parse_problem(parse: Callable[[str], Any], value: Any) -> str | None:
    """What argparse ``type`` ``parse`` says is wrong with ``value`` (given as its text), or None."""
    try:
        parse(str(value))
    except (argparse.ArgumentTypeError, TypeError, ValueError) as e:
        return str(e)
    return None


def switch_flag(f: dataclasses.Field) -> str:
    """The one flag of a yes/no field marked ``switch`` (:func:`option`): ``--no-NAME`` when it
    is True by default, ``--NAME`` when False. Example: export's ``crop`` -> ``--no-crop``."""
    return "--no-" + flag_of(f.name)[2:] if f.default else flag_of(f.name)


def base_type(tp: Any) -> tuple[Any, bool]:
    """(type, optional) for ``X`` or ``X | None``."""
    if isinstance(tp, types.UnionType) or typing.get_origin(tp) is typing.Union:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return args[0], True
    return tp, False


def range_problem(
    value: float,
    kind: type = float,
    min: float | None = None,  # noqa: A002 - reads like a range
    max: float | None = None,
    above: float | None = None,
    shown: str | None = None,
    off: float | None = None,
) -> str | None:
    """What is wrong with a number and its bounds (``min``/``max`` inclusive, ``above``
    exclusive; floats must be finite; ``off``, a value that switches the option off, is
    allowed besides), or None: the one wording of the parser (:func:`number`) and of
    :func:`check_ranges`. ``shown`` is the value as the user wrote it.
    Example: ``range_problem(101, int, 1, 100)`` -> ``"101 is above the maximum 100 (allowed: 1 to 100)"``."""
    shown = str(value) if shown is None else shown
    if kind is float and not math.isfinite(value):
        return f"'{shown}' is not a finite number"
    if off is not None and value == off:
        return None
    if min is not None and value < min:
        problem = f"{shown} is below the minimum {min}"
    elif max is not None and value > max:
        problem = f"{shown} is above the maximum {max}"
    elif above is not None and not value > above:
        problem = f"{shown} must be greater than {above}"
    else:
        return None
    if max is not None and min is not None:
        problem += f" (allowed: {min} to {max})"
    elif max is not None and above is not None:
        problem += f" (allowed: above {above}, up to {max})"
    if off is not None:
        problem += f" (or {off}: off)"
    return problem


def range_of(meta: Any) -> dict[str, float | None]:
    """A field's bounds from its metadata, as keyword arguments of :func:`range_problem` and :func:`number`."""
    return {k: meta.get(k) for k in ("min", "max", "above", "off")}


def _not_a(kind: type, shown: str) -> str:
    return f"'{shown}' is not {'a whole number' if kind is int else 'a number'}"


def number(
    kind: type = float,
    min: float | None = None,
    max: float | None = None,  # noqa: A002 - reads like a range
    above: float | None = None,
    off: float | None = None,
) -> Any:
    """An argparse ``type`` for a finite ``kind`` (int or float) within [min, max] (or > above):
    ``--minutes nan``, ``--fps 0`` or ``--chunk -1`` are refused when the command line is parsed."""

    def parse(text: str):
        try:
            v = kind(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(_not_a(kind, text)) from None
        problem = range_problem(v, kind, min, max, above, shown=text, off=off)
        if problem:
            raise argparse.ArgumentTypeError(problem)
        return v

    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


def output_path(text: str) -> str:
    """The check of a path a command writes (``--out``, ``--to``, ...): not empty or blank,
    which would write into the current folder (an unset shell variable)."""
    if not str(text).strip():
        raise argparse.ArgumentTypeError("is empty: give the path to write")
    return str(text)


# the longest side (metres) taken as a printed tag's: a larger --tag-size is a length in
# other units (60 for a 60 mm tag), which would scale the scene a thousandfold
TAG_SIDE_MAX = 2.0


def tag_side(text: str) -> float:
    """The argparse ``type`` of ``--tag-size``: a printed tag's side in metres, positive
    and at most :data:`TAG_SIDE_MAX`; a larger number is refused with the metres it meant."""
    value = number(float, above=0)(text)
    if value > TAG_SIDE_MAX:
        meant = [
            f"{text} {unit} is {value / per:g}"
            for unit, per in (("mm", 1000), ("cm", 100))
            if value / per <= TAG_SIDE_MAX
        ]
        raise argparse.ArgumentTypeError(
            f"{text} is not a printed tag's side in metres (at most {TAG_SIDE_MAX:g})"
            + (": " + ", ".join(meant) if meant else "")
        )
    return value


def fits(kind: Any, value: Any) -> bool:
    """Whether ``value`` is of a setting's ``kind`` as the command line reads it: True or False
    for bool, text for str, a whole number for int, a number for float (True and False are
    neither); other kinds are not judged here."""
    if kind is bool:
        return isinstance(value, bool)
    if kind in (int, float):
        return isinstance(value, numbers.Integral if kind is int else numbers.Real) and not isinstance(value, bool)
    return isinstance(value, str) if kind is str else True


def check_ranges(cfg: T, source: object = None, owner: str | None = None) -> T:
    """Check every int and float field of dataclass ``cfg`` as its flag is checked when the
    command line is parsed (:func:`number`: finite, the field's ``min``/``max``/``above``),
    for configs built in Python or read from JSON, and for a flag that configs share (parsed
    within the widest of their bounds: :func:`add_alternative_dataclass_args`); returns ``cfg``.
    A bad value is a NerfkitError naming ``source`` (when given), the flag and ``owner`` (when
    given), e.g. ``config.json: 'lr' (--lr): 200.0 is above the maximum 100 (allowed: 0 to 100)`` or
    ``--sh-degree: 3 is above the maximum 2 (allowed: 0 to 2) for the fast model``."""
    hints = typing.get_type_hints(type(cfg))
    for f in dataclasses.fields(cfg):
        kind, optional = base_type(hints[f.name])
        value = getattr(cfg, f.name)
        parse = f.metadata.get("parse")
        if (kind not in (int, float) and parse is None) or (value is None and optional):
            continue
        bounds = range_of(f.metadata)
        problem: str | None
        if kind in (int, float) and not fits(kind, value):
            problem = _not_a(kind, str(value))
        elif parse is not None:  # (the flag's own type: its range and words)
            problem = parse_problem(parse, value)
        else:
            problem = range_problem(
                value, kind, min=bounds["min"], max=bounds["max"], above=bounds["above"], off=bounds["off"]
            )
        if problem:
            if owner:
                problem += f" for {owner}"
            flag = field_flag(f)
            raise fail(flag if source is None else f"{source}: '{f.name}' ({flag})", problem)
    return cfg


def check_exclusive(cfg: T) -> T:
    """Refuse two fields of dataclass ``cfg`` of the same ``exclusive`` set (:func:`option`) both
    given (not their defaults), as the command line refuses both flags (the later field's
    ``exclusive_fix`` metadata: what to do, else "Give one of them"); returns ``cfg``.
    Example: convert's ``size=200, downscale=2`` -> ``--downscale: not allowed with --size``."""
    given: dict[str, dataclasses.Field] = {}
    for f in dataclasses.fields(cfg):
        name = f.metadata.get("exclusive")
        if name is None or getattr(cfg, f.name) == f.default:
            continue
        if name in given:
            fix = f.metadata.get("exclusive_fix", "Give one of them")
            raise fail(field_flag(f), f"not allowed with {field_flag(given[name])}", fix)
        given[name] = f
    return cfg


def check_values(cls: type, values: dict[str, Any], owner: str | None = None) -> None:
    """Refuse a value of ``values`` (settings of dataclass ``cls`` by field name, as Python
    gives them) of the wrong kind for its field, as the command line would: a yes/no field
    takes True or False, a text field text, a number field a number (its range:
    :func:`check_ranges`), a field with choices one of them; None only where the field allows
    it. Names ``cls`` does not have are the caller's to refuse."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for name, value in values.items():
        if name not in fields:
            continue
        kind, optional = base_type(hints[name])
        choices = fields[name].metadata.get("choices")
        if value is None and optional:
            continue
        if not fits(kind, value):
            words = {bool: "True or False", str: "text"}
            problem = f"{value!r} is not {words[kind]}" if kind in words else _not_a(kind, str(value))
        elif choices is not None and value not in choices:
            problem = f"{value!r} is not one of {', '.join(map(str, choices))}"
        else:
            continue
        raise fail(field_flag(fields[name]), problem + (f" for {owner}" if owner else ""))


def _field_type(tp: Any, meta: Any) -> Any:
    """The argparse type of a field: its ``parse`` metadata when it has one; numbers are checked
    (finite, and the field's ``min``/``max``/``above`` metadata); other types pass through."""
    if meta.get("parse") is not None:
        return meta["parse"]
    if tp in (int, float):
        return number(tp, **range_of(meta))
    return tp if tp is str else str


def flag_type(cls: type, name: str) -> Any:
    """The argparse type of field ``name``'s flag in dataclass ``cls`` (for numbers, with its bounds)."""
    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    return _field_type(base_type(typing.get_type_hints(cls)[name])[0], f.metadata)


# (config name, field name, dataclass default) -> what --help says the default is, or None
DefaultHelp = Callable[[str, str, Any], "str | None"]


def _help_line(f: dataclasses.Field, owner: str = "", default_help: DefaultHelp | None = None) -> str:
    default = f.default if f.default is not dataclasses.MISSING else None
    # a default that the command decides where the dataclass cannot (the dataset's kind's)
    default = f.metadata.get("default_help", default)
    if default_help is not None:
        default = default_help(owner, f.name, default) or default
    if default is not None and default != "":
        return f"{f.metadata.get('help', '')} (default: {default})"
    return f.metadata.get("help", "")


def _lower_bound(meta: Any) -> tuple[float, bool] | None:
    """(value, exclusive) of a field's lower bound (the stricter of ``min`` and ``above``), or None."""
    ends = [(meta[k], k == "above") for k in ("min", "above") if meta.get(k) is not None]
    return max(ends, default=None)


def widest_bounds(metas: list[Any]) -> dict[str, float]:
    """The ``min``/``max``/``above`` bounds that take every value any of ``metas`` (fields'
    metadata) takes: the lowest lower end (inclusive at a tie), the highest upper end, and no
    end where one of them has none, and the ``off`` value any of them allows. Example:
    ``max=2`` and ``max=3`` (both ``min=0``) -> ``{"min": 0, "max": 3}``."""
    lows = [_lower_bound(m) for m in metas]
    highs = [m.get("max") for m in metas]
    offs = {m["off"] for m in metas if m.get("off") is not None}
    if len(offs) > 1:
        raise TypeError(f"the fields switch off at different values: {sorted(offs)}")
    out: dict[str, float] = {"off": offs.pop()} if offs else {}
    known = [low for low in lows if low is not None]
    if len(known) == len(lows):
        value, exclusive = min(known)
        out["above" if exclusive else "min"] = value
    if None not in highs:
        out["max"] = max(highs)
    return out


def _add_flag(
    target: Any, name: str, owners: list[tuple[str, Any, dataclasses.Field]], default_help: DefaultHelp | None = None
) -> None:
    """Add field ``name``'s flag to ``target`` for the (owner, type, field) of every config that has it:
    parsed within the widest of their bounds, its help each one's text and default (as
    ``default_help`` words it, where it does)."""
    if len({tp for _, tp, _ in owners}) > 1 or len({str(f.metadata.get("choices")) for _, _, f in owners}) > 1:
        raise TypeError(f"{flag_of(name)}: {', '.join(o for o, _, _ in owners)} give it different types or choices")
    _, tp, first = owners[0]
    helps = [_help_line(f, o, default_help) for o, _, f in owners]
    help_text = helps[0] if len(set(helps)) == 1 else "; ".join(f"{o}: {h}" for (o, _, _), h in zip(owners, helps))
    help_text = help_text.replace("%", "%%")  # argparse %-formats help
    kw: dict[str, Any] = {"dest": name, "default": None, "help": help_text}
    if "choices" in first.metadata:
        kw["choices"] = first.metadata["choices"]
    if tp is bool and first.metadata.get("switch"):  # one flag: the default needs none
        kw["help"] = first.metadata.get("help", "").replace("%", "%%")
        target.add_argument(switch_flag(first), action="store_const", const=not first.default, **kw)
    elif tp is bool:
        target.add_argument(field_flag(first), action=argparse.BooleanOptionalAction, **kw)
    else:
        named = "{" + ",".join(map(str, kw["choices"])) + "}" if "choices" in kw else None  # the choices in --help
        metavar = first.metadata.get("metavar", named or (tp.__name__.upper() if hasattr(tp, "__name__") else "X"))
        target.add_argument(
            field_flag(first),
            type=_field_type(
                tp, {**widest_bounds([f.metadata for _, _, f in owners]), "parse": first.metadata.get("parse")}
            ),
            metavar=metavar,
            **kw,
        )


def _cli_fields(cls: type, skip: tuple[str, ...] = ()) -> list[tuple[Any, dataclasses.Field]]:
    """(type, field) of each field of dataclass ``cls`` that has a flag."""
    hints = typing.get_type_hints(cls)
    return [
        (base_type(hints[f.name])[0], f)
        for f in dataclasses.fields(cls)
        if f.name not in skip and f.metadata.get("cli") is not False
    ]


def add_dataclass_args(
    parser: argparse.ArgumentParser, cls: type, group_title: str | None = None, skip: tuple[str, ...] = ()
) -> None:
    """Add one flag per field of dataclass ``cls`` (defaults left unset: None), in the argument
    group its ``group`` metadata names (in the order they first appear), else in ``group_title``'s
    (or the parser's own options when None); the flags of one ``exclusive`` set are mutually
    exclusive. A flag the parser
    has already is refused (argparse's conflict error); alternative configs that share flags go
    through :func:`add_alternative_dataclass_args`."""
    target = parser.add_argument_group(group_title) if group_title else parser
    groups: dict[str, Any] = {}
    exclusive: dict[str, Any] = {}  # (one mutually exclusive group of flags per ``exclusive`` name)
    for tp, f in _cli_fields(cls, skip):
        group = f.metadata.get("group")
        if group and group not in groups:
            groups[group] = parser.add_argument_group(group)
        where = groups[group] if group else target
        name = f.metadata.get("exclusive")
        if name is not None:
            if name not in exclusive:
                exclusive[name] = where.add_mutually_exclusive_group()
            where = exclusive[name]
        _add_flag(where, f.name, [(cls.__name__, tp, f)])


def _alternative_fields(classes: dict[str, type]) -> dict[str, list[tuple[str, Any, dataclasses.Field]]]:
    """Field name -> (config name, type, field) of each of ``classes`` that has it as a flag."""
    owners: dict[str, list[tuple[str, Any, dataclasses.Field]]] = {}
    for name, cls in classes.items():
        for tp, f in _cli_fields(cls):
            owners.setdefault(f.name, []).append((name, tp, f))
    return owners


def foreign_flags(args: argparse.Namespace, classes: dict[str, type], chosen: str) -> list[tuple[str, list[str]]]:
    """(flag, names of the configs that take it) for each flag of :func:`add_alternative_dataclass_args`
    given in ``args`` that config ``chosen`` does not take (it would be ignored). Example: ``--sh-degree 3``
    with the vanilla model chosen -> ``[("--sh-degree", ["fast", "splat"])]``."""
    return [
        (flag_of(field), [name for name, _, _ in its])
        for field, its in _alternative_fields(classes).items()
        if getattr(args, field, None) is not None and chosen not in [name for name, _, _ in its]
    ]


def add_alternative_dataclass_args(
    parser: argparse.ArgumentParser, classes: dict[str, type], title: str, default_help: DefaultHelp | None = None
) -> None:
    """Add the flags of alternative dataclasses, of which one is used (a model's config, chosen by
    ``--model``): a group each, titled ``title.format(name)``. A field that several have is one flag,
    in a group of its own named after them all: parsed within the widest of their bounds
    (:func:`widest_bounds`), with each one's help and default; :func:`check_ranges` then checks the
    chosen config against its own bounds (e.g. ``--sh-degree``: 0 to 2 for the fast model, 0 to 3
    for splat, so 0 to 3 when parsed)."""
    groups: dict[tuple[str, ...], argparse._ArgumentGroup] = {
        (name,): parser.add_argument_group(title.format(name)) for name in classes
    }
    for field, its in _alternative_fields(classes).items():
        names = tuple(name for name, _, _ in its)
        if names not in groups:  # after the configs' own groups
            groups[names] = parser.add_argument_group(" and ".join(title.format(name) for name in names))
        _add_flag(groups[names], field, its, default_help)


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
            return tuple(int(t[i : i + 2], 16) / 255.0 for i in (1, 3, 5))  # type: ignore[return-value]
        parts = [float(v) for v in t.split(",")]
        if len(parts) == 3 and all(0.0 <= v <= 1.0 for v in parts):
            return tuple(parts)  # type: ignore[return-value]
    except ValueError:
        pass
    raise fail(
        "--background",
        f"'{text}' is not a colour",
        "Use black, white, grey, R,G,B with values in [0, 1] (e.g. 1,0,0) or #rrggbb",
    )


def dataclass_from_args(cls: type[T], args: argparse.Namespace, base: T | None = None) -> T:
    """Build ``cls`` from parsed flags; unset flags keep ``base``'s (or the default) values."""
    values = dataclasses.asdict(base) if base is not None else {}
    for f in dataclasses.fields(cls):
        v = getattr(args, f.name, None)
        if v is not None:
            values[f.name] = v
    return cls(**values)


def dataclass_from_dict(cls: type[T], d: dict, where: str) -> T:
    """Build ``cls`` from JSON data, refusing unknown keys, wrong types and numbers out of
    their fields' range (:func:`check_ranges`) with a clear error."""
    if not isinstance(d, dict):
        raise fail(where, f"expected a JSON object of {cls.__name__} settings, got {type(d).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise fail(where, f"unknown config keys: {', '.join(sorted(map(repr, unknown)))}")
    out: dict[str, Any] = {}
    for k, v in d.items():
        tp, optional = base_type(hints[k])
        if v is None and optional:
            out[k] = None
        elif fits(tp, v):
            out[k] = float(v) if tp is float else v  # (finite and in range: check_ranges below)
        else:
            raise fail(where, f"config key '{k}' should be {tp.__name__}, got {type(v).__name__}")
    return check_ranges(cls(**out), where)


def load_json(
    path: str | Path,
    missing: str = "no such file",
    missing_fix: str | None = None,
    invalid_fix: str = "The file may be truncated; re-create it",
) -> Any:
    """Parse a JSON file; every failure is one NerfkitError naming the file (hints per caller)."""
    path = Path(path)
    try:
        return json.loads(refuse_special_file(path).read_text())
    except FileNotFoundError:
        raise fail(path, missing, missing_fix) from None
    except IsADirectoryError:
        inside = sorted(p.name for p in path.glob("*.json"))[:3]
        held = f" ({path} holds {', '.join(inside)})" if inside else ""
        raise fail(path, "is a folder, not a JSON file", f"Name the JSON file itself{held}") from None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise fail(path, f"not valid JSON ({type(e).__name__}: {e})", invalid_fix) from None
    except (OSError, ValueError) as e:  # a folder, no permission, a NUL byte in the name
        raise fail(path, f"cannot read ({type(e).__name__}: {e})") from None
