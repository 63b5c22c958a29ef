"""One process per run folder: an exclusive ``flock`` on ``RUN/.nerfkit.lock``.

The lock file holds the pid of the process that has the lock, so the refusal can say
which process is using the folder. The kernel drops the lock when the process ends, even
on SIGKILL, so a crashed run never leaves its folder locked. The file itself stays (removing
it would let two processes lock two different files of the same name).

The name is nerfkit's own: a ``.lock`` of the user's in an empty ``--out`` is the user's
file (the folder is refused, the file never opened). Runs made by earlier versions hold a
``RUN/.lock``: it stays where it is, unused, and those runs resume, evaluate and render as before.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import stat
from collections.abc import Iterator
from pathlib import Path

from ..errors import fail

LOCK_FILE = ".nerfkit.lock"


def left_by_others(folder: Path) -> list[Path]:
    """The entries of the folder ``folder`` other than nerfkit's lock and its temporaries
    (:func:`~nerfkit.io.atomic.is_temporary`): what a command must not take for its own."""
    from .atomic import is_temporary

    return [p for p in folder.iterdir() if p.name != LOCK_FILE and not is_temporary(p.name)]


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike) -> Iterator[Path]:
    """Hold the exclusive lock of ``folder`` (created if needed) for the ``with`` block."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    try:  # never through a link: truncating it would empty the file it points to
        fd = os.open(folder / LOCK_FILE, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o666)
    except OSError as e:
        raise fail(
            folder / LOCK_FILE,
            "is a link or cannot be opened as nerfkit's lock file" + (f" ({e.strerror})" if e.strerror else ""),
            "Remove it (nerfkit makes its own), or choose another folder",
        ) from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise fail(folder / LOCK_FILE, "is not a regular file", "Remove it (nerfkit makes its own)")
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            other = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "unknown"
            raise fail(
                folder,
                f"is in use by another nerfkit process (pid {other})",
                "Wait for it to finish or stop it; two processes must never write one run",
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        try:
            yield folder
        finally:
            os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def is_locked(folder: str | os.PathLike) -> bool:
    """Whether a process holds ``folder``'s lock now (a run being trained); reads only."""
    try:
        fd = os.open(Path(folder) / LOCK_FILE, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return False
    finally:
        os.close(fd)
