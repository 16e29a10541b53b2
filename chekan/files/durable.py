"""Durable files: what every writer of the project uses so that a crash loses nothing.

- :func:`fsync_dir` makes a new or renamed name survive a crash (POSIX).
- :func:`atomic_output` writes a whole file to a temporary file in the same folder and
  renames it into place, so an interrupted command never leaves a half-written result,
  certificate or record behind.
- :func:`append_whole` appends to a streaming file (record, journal) whole writes only:
  a write that fails part-way is cut back, so a full disk leaves no torn line.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

PathArg = str | os.PathLike[str]


def fsync_dir(path: PathArg) -> None:
    """fsync the directory holding ``path`` so that a new name survives a crash (POSIX).

    Best effort: a file system that cannot fsync a directory is left as it is.
    """
    d = os.path.dirname(os.path.abspath(path))
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_output(path: PathArg, mode: str = "w", **open_kw) -> Iterator:
    """Open a temporary file beside ``path``; on success fsync it and rename it into place.

    On any exception the temporary file is removed and ``path`` is left as it was; an
    :class:`OSError` that names no file (a full disk while writing) is given ``path``.
    A missing folder is a :class:`FileNotFoundError` naming it (none is created).
    ``mode`` is ``"w"`` (text, UTF-8 unless ``encoding`` is given) or ``"wb"``.
    The file gets the permissions of a plain ``open()`` (0666 less the umask), not the
    owner-only 0600 of :func:`tempfile.mkstemp`.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_output writes whole files: mode 'w' or 'wb', not {mode!r}")
    out = Path(path)
    if "b" not in mode:
        open_kw.setdefault("encoding", "utf-8")
    if not out.parent.is_dir():  # mkstemp would name its temporary file instead
        raise FileNotFoundError(errno.ENOENT, "no such folder", str(out.parent))
    fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=f".{out.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode, **open_kw) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, out)
        fsync_dir(out)
    except BaseException as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(e, OSError) and e.filename is None:
            e.filename = str(out)  # a full disk on write/fsync names no file by itself
        raise


def append_whole(f: IO[bytes] | io.RawIOBase, data: bytes, good: int) -> int:
    """Write all of ``data`` to the unbuffered file ``f``; returns the new end of good data.

    ``good`` is the offset where ``data`` starts (the end of the last complete write). If
    the write fails part-way (a full disk, an I/O error), the file is cut back to ``good``
    — a truncation needs no room — and the error is raised: the file never ends in a torn
    line of our own making.
    """
    view = memoryview(data)
    try:
        while view:
            n = f.write(view)
            if n is None:  # non-blocking file: nothing written now
                raise BlockingIOError(errno.EAGAIN, "write would block")
            view = view[n:]
    except OSError:
        with contextlib.suppress(OSError):
            os.ftruncate(f.fileno(), good)
            f.seek(good)
        raise
    return good + len(data)
