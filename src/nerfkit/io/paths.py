"""Which paths nerfkit may read and write.

* Readers resolve every name a dataset file gives (a frame's ``file_path``, a COLMAP
  image name, a ``poses.json`` entry) with :func:`resolve_inside`: the file must lie in
  the dataset's folder, symlinks included, unless the user passes
  ``--allow-outside-paths``.
* Writers name their files with :func:`safe_output_name`: a plain file name, so a
  crafted name never leaves the output folder.
* Commands check their outputs with :func:`guard_outputs` before writing anything: an
  output is never an input or inside one (and never holds one), and an existing output
  is replaced only with ``--force``.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path

from ..errors import NerfkitError, fail

OUTSIDE_FLAG = "--allow-outside-paths"


def _unusable(path, e: Exception) -> NerfkitError:
    """The NerfkitError for a path the operating system refuses (``e``: why)."""
    return fail(repr(str(path)[:200]), f"not a usable path ({type(e).__name__})")


def resolved_path(path: str | os.PathLike) -> Path:
    """``path`` made absolute with links and ``..`` resolved; an unusable path is a NerfkitError."""
    try:
        return Path(path).resolve()
    except (OSError, ValueError, RuntimeError) as e:  # a NUL byte, a loop of links
        raise _unusable(path, e) from None


def path_kind(path: str | os.PathLike) -> str | None:
    """``"file"``, ``"dir"``, ``"other"`` (a device, a socket) or None when nothing is at
    ``path`` (also for a name with a NUL byte, or behind a loop of links: Python's
    ``exists()`` says False); a name the file system refuses (too long) is a NerfkitError."""
    path = Path(path)
    try:
        if not path.exists():
            return None
        return "dir" if path.is_dir() else "file" if path.is_file() else "other"
    except (OSError, ValueError) as e:
        raise _unusable(path, e) from None


_SPECIAL = ((stat.S_ISFIFO, "a named pipe"), (stat.S_ISCHR, "a character device"),
            (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def refuse_special_file(path: str | os.PathLike, kind: str | None = None) -> Path:
    """``path``, refused without opening it when it is a named pipe, a device or a socket
    (``path_kind`` ``"other"``; ``kind``: its :func:`path_kind`, when the caller has it):
    reading one blocks until someone writes to it (a pipe) or never ends (``/dev/zero``). A
    file, a folder or nothing there passes: each reader says what it expected. The one
    check before nerfkit reads a file a user names."""
    path = Path(path)
    if (path_kind(path) if kind is None else kind) == "other":
        try:
            mode = path.stat().st_mode
        except OSError:  # gone since: the reader says so
            return path
        what = next((f"is {name}, not a regular file" for test, name in _SPECIAL if test(mode)), "is not a regular file")
        raise fail(path, what,
                   "nerfkit reads only regular files (a pipe or device could block or never end); save the data "
                   "to a file and pass that")
    return path


def is_within(path: str | os.PathLike, folder: str | os.PathLike) -> bool:
    """True when ``path`` is ``folder`` or inside it, after resolving links and ``..``."""
    return resolved_path(path).is_relative_to(resolved_path(folder))


def resolve_inside(root: str | os.PathLike, name: str, allow_outside: bool = False, where: object = None) -> Path:
    """``root / name`` resolved (links, ``..``); refused when it leaves ``root``.

    An absolute ``name`` is taken as it is. With ``allow_outside`` any path is accepted
    (the user trusts the dataset file).
    """
    name = str(name)
    if "\x00" in name:
        raise fail(where or root, f"file name {name[:100]!r} is not a usable path (it holds a NUL byte)")
    path = resolved_path(Path(root) / name)  # an absolute name replaces root
    if not allow_outside and not path.is_relative_to(resolved_path(root)):
        raise fail(where or root, f"file name {name[:200]!r} points outside the dataset folder {root}",
                   f"Keep a dataset's files inside its folder, or pass {OUTSIDE_FLAG} if you trust this dataset")
    return path


_UNSAFE = re.compile(r"[\x00-\x1f\x7f]")


def safe_output_name(name: str, fallback: str = "view") -> str:
    """A plain file name for ``name``: its last component, no control characters, never
    empty, ``.`` or ``..`` (then ``fallback``). Writers put it inside their output folder."""
    base = _UNSAFE.sub("_", str(name).replace("\\", "/")).rsplit("/", 1)[-1].strip()
    return base if base not in ("", ".", "..") else fallback


def _occupied(path: Path) -> bool:
    """An existing file, or a folder with something in it."""
    try:
        return path.is_file() or path.is_symlink() or (path.is_dir() and any(path.iterdir()))
    except OSError:
        return path.exists()


def guard_outputs(outputs, inputs, force: bool = False, flag: str = "--out") -> None:
    """Refuse to write ``outputs`` (files or folders a command is about to write) when one
    is an input, inside one, or holds one; and when one exists already, unless ``force``.

    Call before writing anything, with every file or folder the command reads as ``inputs``.
    """
    outs = [Path(o) for o in outputs if o is not None]
    ins = [Path(i) for i in inputs if i is not None]
    for o in outs:
        ro = resolved_path(o)
        for i in ins:
            ri = resolved_path(i)
            if ro == ri:
                raise fail(o, "is an input of this command", f"Choose another {flag}; nerfkit never writes its inputs")
            if ro.is_relative_to(ri):
                raise fail(o, f"is inside the input {i}", f"Choose an {flag} outside the inputs; nerfkit never writes "
                                                          "into them")
            if ri.is_relative_to(ro):
                raise fail(o, f"holds the input {i}", f"Choose another {flag}; writing it could replace the input")
    if not force:
        for o in outs:
            if _occupied(o):
                raise fail(o, "already exists", f"Pass --force to replace it, or choose another {flag}")
