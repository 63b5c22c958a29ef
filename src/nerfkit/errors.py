"""The project's one user-facing error type.

Anything a user can cause (a bad file, a bad flag, photos with no tags) raises
:class:`NerfkitError` with one readable line: which file, what is wrong, what to do.
The CLI turns it into that line on stderr and exit code 2.
"""

from __future__ import annotations

import errno
from collections.abc import Iterator
from contextlib import contextmanager


class NerfkitError(Exception):
    """A user error: bad input, bad option, or a missing prerequisite."""


def fail(where: object, problem: str, fix: str | None = None) -> NerfkitError:
    """Build a NerfkitError reading ``<where>: <problem>. <fix>``."""
    msg = f"{where}: {problem}"
    if fix:
        msg += f". {fix}"
    return NerfkitError(msg.replace("\r", " ").replace("\n", " "))


# what to do when the system refuses a file, by errno
OS_ERROR_HINTS: dict[int | None, str] = {
    errno.EACCES: "Check its permissions, or choose another place to write",
    errno.EPERM: "Check its permissions, or choose another place to write",
    errno.EROFS: "The file system is read-only: choose another place to write",
    errno.EISDIR: "It is a folder: name a file there instead",
    errno.ENOTDIR: "A part of the path is a file, not a folder",
    errno.EEXIST: "A part of the path is a file, not a folder",
    errno.ENAMETOOLONG: "Use a shorter name",
    errno.ENOSPC: "The disk is full: free some space",
}


def os_error(e: OSError) -> NerfkitError:
    """The system's refusal of a file (permissions, a folder where a file goes, a full disk)
    as a NerfkitError naming the file (a rename's target first) and what to do."""
    where = next((f for f in (e.filename2, e.filename) if f is not None), "a file")
    hint = OS_ERROR_HINTS.get(e.errno, "Check the path and its permissions")
    return NerfkitError(f"{where}: {e.strerror or e}. {hint}")


def problem_of(error: NerfkitError) -> str:
    """What a :func:`fail` error says is wrong, without the ``<where>: `` it starts with
    (a photo's error beside its name in a table of photos)."""
    return str(error).split(": ", 1)[-1]


@contextmanager
def advice(fix: str) -> Iterator[None]:
    """Append ``fix`` to any NerfkitError raised inside: shared checks say what is wrong,
    the loader of each kind of file says what to do about it."""
    try:
        yield
    except NerfkitError as e:
        raise NerfkitError(f"{e}. {fix}") from None


def is_out_of_memory(e: BaseException) -> bool:
    """A MemoryError, or PyTorch's RuntimeError for an allocation that failed (CPU or CUDA)."""
    if isinstance(e, MemoryError):
        return True
    text = str(e).lower()
    return isinstance(e, RuntimeError) and any(
        s in text for s in ("out of memory", "can't allocate memory", "not enough memory")
    )
