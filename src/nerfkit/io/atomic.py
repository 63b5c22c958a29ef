"""Atomic file writes: write to a temporary name beside the target, fsync, rename.

A crash (or SIGKILL) at any moment leaves either the old file or the new one at the
target path, never a truncated mix (and at worst a temporary beside it, which
:func:`remove_stale_temporaries` deletes). Files get the permissions the umask gives any
new file (0644 under the usual 022), not mkstemp's private 0600.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import fail

TMP_MARK = ".tmp."  # in the name of every temporary file atomic_path makes
# a failed write with less free space than this beside the target is put down to a full disk
# (writers such as torch.save report it as a RuntimeError, not ENOSPC)
FULL_DISK_BYTES = 64 << 20


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``.

    ``suffix`` defaults to the target's suffix, so writers that pick a format from the
    extension (imageio, matplotlib) still work on the temporary name.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}{TMP_MARK}", suffix=path.suffix if suffix is None else suffix, dir=path.parent
    )
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as f:
            os.fchmod(f.fileno(), 0o666 & ~_umask())  # mkstemp makes 0600; outputs follow the umask
            os.fsync(f.fileno())
        os.replace(tmp_path, path)
        _fsync_dir(path.parent)
    except (OSError, RuntimeError) as e:
        tmp_path.unlink(missing_ok=True)
        if _disk_full(e, path.parent):
            raise fail(
                path,
                "could not be written: the disk is full",
                "Free some space and run the command again (a training run continues from its last "
                "checkpoint with nerfkit train --resume RUN)",
            ) from None
        raise
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def all_or_none(paths) -> Iterator[list[Path]]:
    """Yield a temporary path beside each of ``paths`` (same suffix) for the body to write;
    when it succeeds they are renamed onto ``paths``, else removed: a command that writes
    several files leaves all of them, or none and the earlier ones as they were."""
    targets = [Path(p) for p in paths]
    pending: list[Path] = []
    try:
        for path in targets:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, name = tempfile.mkstemp(prefix=f".{path.name}{TMP_MARK}", suffix=path.suffix, dir=path.parent)
            os.close(fd)
            pending.append(Path(name))
        yield pending
        for tmp, path in zip(pending, targets, strict=True):
            os.replace(tmp, path)
            _fsync_dir(path.parent)
    finally:
        for tmp in pending:
            tmp.unlink(missing_ok=True)


def _disk_full(error: BaseException, folder: Path) -> bool:
    if isinstance(error, OSError) and error.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    try:
        return shutil.disk_usage(folder).free < FULL_DISK_BYTES
    except OSError:
        return False


# ``.<name>.tmp.<mkstemp's 8 random characters><suffix>``: a user's ``.notes.tmp.txt`` is not one
_TEMPORARY = re.compile(r"\..+" + re.escape(TMP_MARK) + r"[a-z0-9_]{8}")


def is_temporary(name: str) -> bool:
    """True for the name of a temporary file :func:`atomic_path` makes."""
    return _TEMPORARY.match(name) is not None


def stale_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Temporary files :func:`atomic_path` left in ``folder`` (and below) when a process was
    killed mid-write (SIGKILL, power loss): ``.<name>.tmp.<random><suffix>``."""
    return sorted(p for p in Path(folder).rglob(f".*{TMP_MARK}*") if p.is_file() and is_temporary(p.name))


def remove_stale_temporaries(folder: str | os.PathLike) -> int:
    """Delete :func:`stale_temporaries`; call only while no other process writes ``folder``
    (e.g. holding its :func:`nerfkit.io.lock.folder_lock`). Returns how many were removed."""
    stale = stale_temporaries(folder)
    for p in stale:
        p.unlink(missing_ok=True)
    return len(stale)


def foreign_files(folder: str | os.PathLike, own) -> list[str]:
    """The files in ``folder`` (its subfolders too; relative, ``/``-separated) that are not
    among ``own``, the names an earlier output of nerfkit's recorded there; none when
    ``folder`` is missing or a link (replacing a link replaces the link alone). nerfkit's
    own temporaries are never foreign."""
    folder = Path(folder)
    if folder.is_symlink() or not folder.is_dir():
        return []
    own = set(own)
    names = (p.relative_to(folder).as_posix() for p in folder.rglob("*") if not p.is_dir() or p.is_symlink())
    return sorted(n for n in names if n not in own and not is_temporary(Path(n).name))


def shown_names(names: list[str], most: int = 3) -> str:
    """``names`` for a message: the first ``most``, then how many more. Example:
    ``["a", "b", "c", "d"]`` -> ``"a, b, c and 1 more"``."""
    more = f" and {len(names) - most} more" if len(names) > most else ""
    return ", ".join(names[:most]) + more


def refuse_foreign_files(folder: str | os.PathLike, own, flag: str = "--out") -> None:
    """Refuse to replace ``folder``, ``--force`` or not, while it holds files nerfkit did not
    write there (:func:`foreign_files`): --force replaces an earlier output, never the user's files."""
    foreign = foreign_files(folder, own)
    if foreign:
        raise fail(
            folder,
            f"holds files that no earlier output of nerfkit's wrote there ({shown_names(foreign)})",
            f"Move them away, or choose another {flag}: --force replaces only what nerfkit wrote",
        )


@contextlib.contextmanager
def replacing_folder(folder: str | os.PathLike) -> Iterator[Path]:
    """Yield ``folder`` to be written afresh. An existing one is moved aside first and
    deleted when the body succeeds, or put back when it fails: a replaced output keeps
    no file of the one before it, and a failed write leaves the folder as it was (the
    earlier one, or none).

    Only for folders that are a command's own output, replaced under ``--force``. The
    earlier one waits in a folder of a fresh random name beside it (``.<name>.replaced.<random>``,
    made here), so no folder of the user's is ever taken for it; a replacement killed
    midway leaves that folder behind rather than guess which leftovers are nerfkit's.
    """
    folder = Path(folder)
    moved = folder.is_symlink() or folder.exists()
    aside: Path | None = None
    old: Path | None = None
    if moved:
        aside = Path(tempfile.mkdtemp(prefix=f".{folder.name}.replaced.", dir=folder.parent))
        old = aside / folder.name
        folder.rename(old)
    try:
        yield folder
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        if moved:
            assert old is not None and aside is not None  # both set above whenever moved
            old.rename(folder)
            aside.rmdir()
        raise
    if moved:
        assert old is not None and aside is not None  # both set above whenever moved
        old.unlink() if old.is_symlink() or old.is_file() else shutil.rmtree(old)
        aside.rmdir()


def _umask() -> int:
    """The process umask, read without changing it where Linux allows (no race with threads)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _fsync_dir(directory: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | os.PathLike, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """``obj`` as standard JSON: a NaN or infinite number is written as null (JSON has none)."""
    write_text(path, json.dumps(finite_json(obj), indent=2, default=_json_default, allow_nan=False) + "\n")


def finite_json(obj: Any) -> Any:
    """``obj`` with every non-finite float (NumPy's and arrays' too) replaced by None."""
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return finite_json(obj.tolist())
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    return obj


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_npz(path: str | os.PathLike, **arrays: np.ndarray | np.generic) -> None:
    """Write an uncompressed npz atomically (arrays must not be object arrays)."""
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)  # type: ignore[arg-type]  # numpy's stub: a **kwds key might be allow_pickle
