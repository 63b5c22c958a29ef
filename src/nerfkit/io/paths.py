"""Which paths nerfkit may read and write.

* Readers resolve every name a dataset file gives (a frame's ``file_path``, a COLMAP
  image name, a ``poses.json`` entry) with :func:`resolve_inside`: the file must lie in
  the dataset's folder, symlinks included, unless the user passes
  ``--allow-outside-paths``. The photos a folder lists are held to the same rule
  (:func:`files_inside`): a symlink in the folder to a file elsewhere is outside it.
* Writers name their files with :func:`safe_output_name`: a plain file name, so a
  crafted name never leaves the output folder.
* Commands check their outputs with :func:`guard_outputs` before writing anything: an
  output is never an input or inside one (and never holds one), and an existing output
  is replaced only with ``--force``. A run is never written inside the folder of the
  dataset it trains on (:func:`guard_run_folder`).
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


_SPECIAL = (
    (stat.S_ISFIFO, "a named pipe"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


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
        what = next(
            (f"is {name}, not a regular file" for test, name in _SPECIAL if test(mode)), "is not a regular file"
        )
        raise fail(
            path,
            what,
            "nerfkit reads only regular files (a pipe or device could block or never end); save the data "
            "to a file and pass that",
        )
    return path


def is_within(path: str | os.PathLike, folder: str | os.PathLike) -> bool:
    """True when ``path`` is ``folder`` or inside it, after resolving links and ``..``."""
    return resolved_path(path).is_relative_to(resolved_path(folder))


def resolve_inside(
    root: str | os.PathLike,
    name: str,
    allow_outside: bool = False,
    where: object = None,
    folder: str = "dataset",
    hint: str | None = None,
) -> Path:
    """``root / name`` resolved (links, ``..``); refused when it leaves ``root``: the one
    rule for every file a dataset or a photo folder names (a symlink in ``root`` to a file
    elsewhere leaves it).

    An absolute ``name`` is taken as it is. With ``allow_outside`` any path is accepted
    (the user trusts the dataset file). ``folder`` names what ``root`` is in the message
    (``"dataset"``, ``"photo"``); ``hint`` replaces the advice (for a command without
    ``--allow-outside-paths``).
    """
    name = str(name)
    if "\x00" in name:
        raise fail(where or root, f"file name {name[:100]!r} is not a usable path (it holds a NUL byte)")
    path = resolved_path(Path(root) / name)  # an absolute name replaces root
    if not allow_outside and not path.is_relative_to(resolved_path(root)):
        link = f" (a symlink to {str(path)[:200]})" if Path(root, name).is_symlink() else ""
        raise fail(
            where or root,
            f"file name {name[:200]!r}{link} points outside the {folder} folder {root}",
            hint or f"Keep a dataset's files inside its folder, or pass {OUTSIDE_FLAG} if you trust this dataset",
        )
    return path


def files_inside(
    folder: str | os.PathLike, files: list[Path], allow_outside: bool = False, hint: str | None = None
) -> list[Path]:
    """``files`` (the entries a listing of ``folder`` found), each refused by
    :func:`resolve_inside` when it resolves outside ``folder``: a photo folder's symlink
    to a file elsewhere is not read (``allow_outside``: it is)."""
    for f in files:
        resolve_inside(folder, f.name, allow_outside, f, folder="photo", hint=hint)
    return files


_UNSAFE = re.compile(r"[\x00-\x1f\x7f]")


def safe_output_name(name: str, fallback: str = "view") -> str:
    """A plain file name for ``name``: its last component, no control characters, never
    empty, ``.`` or ``..`` (then ``fallback``). Writers put it inside their output folder."""
    base = _UNSAFE.sub("_", str(name).replace("\\", "/")).rsplit("/", 1)[-1].strip()
    return base if base not in ("", ".", "..") else fallback


def file_sha1(path: str | os.PathLike) -> str:
    """The SHA-1 of the file's bytes (hex), read a megabyte at a time (about a second a gigabyte)."""
    import hashlib

    digest = hashlib.sha1()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def distinct_names(named: list[tuple[str, str]]) -> list[str]:
    """Plain, distinct file names (:func:`safe_output_name`) for views given as (split, name):
    names whose last components collide keep their folders joined by "_" (Blender's
    ``train/r_0`` and ``val/r_0``: ``train_r_0``, ``val_r_0``), or without folders take their
    split's name first (an LLFF view in val and test); a name still taken gets its index."""
    from collections import Counter

    plain = [safe_output_name(n, f"{split}_{i:04d}") for i, (split, n) in enumerate(named)]
    taken = Counter(plain)
    out: list[str] = []
    seen: set[str] = set()
    for i, ((split, name), p) in enumerate(zip(named, plain)):
        if taken[p] > 1:
            path = str(name).replace("\\", "/").strip("/")
            p = safe_output_name(path.replace("/", "_")) if "/" in path else f"{split}_{p}"
        while p in seen:
            stem, dot, suffix = p.rpartition(".")
            p = f"{stem}_{i}.{suffix}" if dot else f"{p}_{i}"
        seen.add(p)
        out.append(p)
    return out


def _occupied(path: Path) -> bool:
    """An existing file, or a folder with something in it."""
    try:
        return path.is_file() or path.is_symlink() or (path.is_dir() and any(path.iterdir()))
    except OSError:
        return path.exists()


def refuse_links(folder: str | os.PathLike, parts) -> None:
    """Refuse to write into ``folder`` while one of its ``parts`` (names of subfolders it
    writes, e.g. a run's ``checkpoints``) is a link: writes through it would land outside."""
    for part in parts:
        p = Path(folder) / part
        if p.is_symlink():
            raise fail(
                p,
                f"is a link (to {os.readlink(p)}): what nerfkit writes there would land outside {folder}",
                "Remove the link (a folder of nerfkit's own is made in its place)",
            )


def guard_outputs(outputs, inputs, force: bool = False, flag: str = "--out") -> None:
    """Refuse to write ``outputs`` (files or folders a command is about to write) when one
    is an input, inside one, or holds one; and when one exists already, unless ``force``.

    Call before writing anything, with every file or folder the command reads as ``inputs``.
    """
    outs = [Path(o) for o in outputs if o is not None]
    ins = [Path(i) for i in inputs if i is not None]
    for o in outs:
        ro = resolved_path(o)
        blocked = next((p for p in ro.parents if p.exists() and not p.is_dir()), None)
        if blocked is not None:
            raise fail(o, f"cannot be written: {blocked} is a file, not a folder", f"Choose another {flag}")
        for i in ins:
            ri = resolved_path(i)
            if ro == ri:
                raise fail(o, "is an input of this command", f"Choose another {flag}; nerfkit never writes its inputs")
            if ro.is_relative_to(ri):
                raise fail(
                    o,
                    f"is inside the input {i}",
                    f"Choose an {flag} outside the inputs; nerfkit never writes into them",
                )
            if ri.is_relative_to(ro):
                raise fail(o, f"holds the input {i}", f"Choose another {flag}; writing it could replace the input")
    if not force:
        for o in outs:
            if _occupied(o):
                raise fail(o, "already exists", f"Pass --force to replace it, or choose another {flag}")


# what marks the folder of a dataset file as the dataset's own: what nerfkit's dataset
# writers put beside the npz (`poses`, `dataset`, `capture`), and what other readers take
DATASET_MARKS = ("images", "transforms.json", "poses.json", "transforms_train.json", "poses_bounds.npy")


def dataset_folder(data: str | os.PathLike) -> Path | None:
    """The folder a dataset at ``data`` lives in: ``data`` itself when it is a folder; the
    folder of a dataset file whose images lie beside it (a ``transforms.json``), or that
    holds the dataset's other parts (:data:`DATASET_MARKS`: ``ds/`` of ``ds/dataset.npz``
    as ``nerfkit poses`` writes it); None for an npz alone among other files (a
    ``scene.npz`` in a working folder, or nothing at ``data``)."""
    path = Path(data)
    kind = path_kind(path)
    if kind is None:
        return None
    if kind == "dir":
        return path
    if path.suffix.lower() != ".npz":
        return path.parent
    return path.parent if any(path_kind(path.parent / m) is not None for m in DATASET_MARKS) else None


def guard_run_folder(run_dir: str | os.PathLike, data: str | os.PathLike, inputs=()) -> None:
    """Refuse to write a run (``train --out``) inside the folder of the dataset ``data``
    (:func:`dataset_folder`), as ``eval`` and ``render`` would then write there too; and,
    as :func:`guard_outputs` does, when it is one of ``inputs`` (what reading the dataset
    reads), inside one or holds one. An existing run folder is the trainer's to check."""
    folder = dataset_folder(data)
    if folder is not None and is_within(run_dir, folder):
        raise fail(
            run_dir,
            f"is inside {folder}, the folder of the dataset {data}",
            "Choose an --out outside the dataset's folder (e.g. runs/NAME): nerfkit never writes a run "
            "among the data it trains on",
        )
    guard_outputs([run_dir], [data, *inputs], force=True)
