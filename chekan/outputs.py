"""What every command does with the files it writes and with its standard output.

- :func:`check_outputs` is called by every command *before* it does any work: it refuses
  (:class:`OutputError`, exit status 2) to write over one of the command's own inputs, to
  write two outputs to one file, to overwrite an existing ``chekan-record/1`` or
  ``chekan-protocol/1`` file (measurements cannot be recomputed; results can) or an SQLite
  database (an archive: every session of every instrument), and to overwrite a file that
  the project reads as input (a ``chekan-result/1`` JSON, a tilt-program TOML) with
  anything but a file of the same kind (:class:`Output`). The file is named in the message.
- :func:`run_command` runs a command function the same way in every ``main()``: a
  :class:`~chekan.errors.ChekanError` or an :class:`OSError` (a missing input, a folder
  one cannot write to) is one line on stderr naming the file and exit status 2, Ctrl-C is
  130, and a closed standard output (``chekan archive list | head``) ends the command
  quietly with status 141 (128 + SIGPIPE, what a shell reports for a Unix tool killed by
  SIGPIPE) instead of a ``BrokenPipeError`` traceback.

- :func:`end_process` ends a command-line process once its command has returned: it
  flushes the standard streams and exits without the interpreter's teardown (0.5 s of
  freeing compiled executables after a MAP calibration), unless a thread still has work.

Writing itself goes through :func:`chekan.durable.atomic_output` (temporary file beside
the target, then renamed into place). Stdlib only: cheap to import from every CLI.
"""

from __future__ import annotations

import errno
import os
import re
import sys
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

from chekan.errors import ChekanError

PathArg = str | os.PathLike[str]

#: Formats of irreplaceable measurement files that no output option may overwrite.
PROTECTED_FORMATS = ("chekan-record/1", "chekan-protocol/1", "chekan-angle-calibration/1")
#: :func:`sniff_kind` of an SQLite database (the archive), which no output option overwrites.
SQLITE = "SQLite database"
#: :func:`sniff_kind` of the inputs that an output may replace only with a file of its kind.
RESULT = "chekan-result/1"
PROGRAM = "tilt program (TOML)"
_SQLITE_MAGIC = b"SQLite format 3\x00"
_SQLITE_SIDECARS = ("-wal", "-shm", "-journal")
_PROGRAM_KEYS = frozenset({"angles", "dwell_s", "rounds", "settle_s", "axis", "order", "sequence"})
_SNIFF_BYTES = 1 << 16

EXIT_OK = 0
EXIT_SOME_FAILED = 1
EXIT_USAGE = 2
EXIT_NOT_CONVERGED = 3
EXIT_ALARM = 4
EXIT_INTERRUPTED = 130
EXIT_CLOSED_PIPE = 141


#: Failures of the system rather than of the input (a full disk, an I/O error): exit 1.
_SYSTEM_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO})


class OutputError(ChekanError):
    """An output option names a file the command must not write."""


def sniff_format(path: PathArg) -> str | None:
    """The ``# format:`` value of the leading ``# key: value`` block, or ``None``.

    Reads at most 64 kB; a file that cannot be read or is not such a file gives ``None``.
    """
    try:
        with open(path, "rb") as f:
            head = f.read(_SNIFF_BYTES)
    except OSError:
        return None
    if head.startswith(b"\xef\xbb\xbf"):
        head = head[3:]
    for raw in head.split(b"\n"):
        if not raw.startswith(b"#"):
            return None
        line = raw.rstrip(b"\r")
        if line.startswith(b"# format:"):
            return line[len(b"# format:") :].decode("utf-8", "replace").strip()
    return None


def sniff_kind(path: PathArg) -> str | None:
    """What an existing file is, as far as the outputs guard cares (``None``: nothing known).

    A ``chekan-record/1`` or ``-protocol/1`` file (:func:`sniff_format`), an SQLite database
    (:data:`SQLITE`, by its 16-byte header; also its ``-wal``/``-shm``/``-journal`` files), a
    ``chekan-result/1`` JSON (:data:`RESULT`) or a tilt program (:data:`PROGRAM`: TOML
    with a program's keys). Reads at most 64 kB.
    """
    p = Path(path)
    try:
        with open(p, "rb") as f:
            head = f.read(_SNIFF_BYTES)
    except OSError:
        return None
    if head.startswith(_SQLITE_MAGIC):
        return SQLITE
    for suffix in _SQLITE_SIDECARS:
        if p.name.endswith(suffix) and sniff_kind(p.with_name(p.name[: -len(suffix)])) == SQLITE:
            return SQLITE
    fmt = sniff_format(p)
    if fmt is not None:
        return fmt
    text = head.decode("utf-8", "replace").lstrip("\ufeff")
    if text.lstrip().startswith("{") and re.search(rf'"format"\s*:\s*"{RESULT}"', text):
        return RESULT
    if _PROGRAM_KEYS & _toml_keys(text):
        return PROGRAM
    return None


def _toml_keys(text: str) -> set[str]:
    """Top-level keys of ``text`` read as TOML (empty when it is not TOML)."""
    import tomllib

    try:
        return set(tomllib.loads(text))
    except (tomllib.TOMLDecodeError, ValueError):
        return set()


@dataclass(frozen=True)
class Output:
    """An output file of a command and the kind of file it writes (:func:`sniff_kind`'s
    names): it may replace an existing file of that kind, e.g. a result over a result."""

    path: PathArg
    writes: str | None = None


def _same(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return a.resolve() == b.resolve()


def check_outputs(
    inputs: Iterable[PathArg | None] = (),
    outputs: Iterable[PathArg | Output | None] = (),
) -> None:
    """Refuse, before any work, outputs that would destroy something; ``None`` entries skip.

    Raises :class:`OutputError` naming the file when an output

    - is the same file as one of ``inputs`` (also through links or ``..``),
    - is given twice among ``outputs``,
    - exists and begins like a ``chekan-record/1`` or ``chekan-protocol/1`` file,
    - exists and is an SQLite database (or one of its journal files), unless the output
      is the database itself (``Output(path, writes=SQLITE)``: an archive to add to),
    - exists and is a ``chekan-result/1`` JSON or a tilt program that the output would
      replace with a file of another kind (a bare path writes an unnamed kind).

    Folders among ``inputs`` protect nothing here (a command that reads a folder checks
    its files itself); folders among ``outputs`` are left to the command.
    """
    ins = [Path(p) for p in inputs if p is not None]
    seen: list[Path] = []
    for o in outputs:
        if o is None:
            continue
        spec = o if isinstance(o, Output) else Output(o)
        out = Path(spec.path)
        for i in ins:
            if not i.is_dir() and _same(out, i):
                raise OutputError(
                    f"{out}: refusing to write over an input of this command ({i}); "
                    "choose another output file"
                )
        for s in seen:
            if _same(out, s):
                raise OutputError(f"{out}: given for two outputs; choose a file for each")
        seen.append(out)
        if out.is_file():
            _refuse_to_replace(out, sniff_kind(out), spec.writes)


def _refuse_to_replace(out: Path, kind: str | None, writes: str | None) -> None:
    """:func:`check_outputs`' rule for one existing output file of ``kind``."""
    if kind in PROTECTED_FORMATS:
        raise OutputError(
            f"{out}: exists and is a {kind} file: refusing to overwrite it "
            "(measurements cannot be recomputed); choose another output file"
        )
    if kind == SQLITE and writes != SQLITE:
        raise OutputError(
            f"{out}: exists and is an SQLite database (a calibration archive?): refusing to "
            "overwrite it; choose another output file"
        )
    if kind in (RESULT, PROGRAM) and writes != kind:
        raise OutputError(
            f"{out}: exists and is a {kind} file, an input of chekan: refusing to overwrite "
            "it with another kind of file; choose another output file"
        )


def _stdout_closed() -> int:
    """After a ``BrokenPipeError`` on stdout: silence it for good (so that the
    interpreter's final flush cannot raise again) and return :data:`EXIT_CLOSED_PIPE`."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # stdout is no real file (tests)
        pass
    return EXIT_CLOSED_PIPE


class _StdoutGuard:
    """Standard output that, once its reader is gone (``| head``), discards what follows
    instead of raising, so that the command still writes its files; it remembers that."""

    def __init__(self, stream):
        self.stream = stream
        self.closed_early = False

    def write(self, text: str) -> int:
        if not self.closed_early:
            try:
                return self.stream.write(text)
            except BrokenPipeError:
                self._reader_gone()
        return len(text)

    def flush(self) -> None:
        if not self.closed_early:
            try:
                self.stream.flush()
            except BrokenPipeError:
                self._reader_gone()

    def _reader_gone(self) -> None:
        self.closed_early = True
        _stdout_closed()

    def __getattr__(self, name: str):
        return getattr(self.stream, name)


def run_command(func: Callable[..., int | None], *args, prog: str = "chekan") -> int:
    """``func(*args)`` → exit status, the same in every ``main()`` (see the module doc).

    A standard output closed early does not stop the command: what it prints afterwards is
    discarded, its files are written all the same, and the status is
    :data:`EXIT_CLOSED_PIPE` (unless it failed otherwise).
    """
    guard = _StdoutGuard(sys.stdout)
    sys.stdout = guard  # type: ignore[assignment]
    try:
        try:
            status = int(func(*args) or 0)
        finally:
            guard.flush()  # a closed pipe shows here, not at interpreter exit
        return EXIT_CLOSED_PIPE if guard.closed_early and status == EXIT_OK else status
    except BrokenPipeError:
        return _stdout_closed()
    except ChekanError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as e:  # a missing or unreadable input, a folder one cannot write to
        where = f"{e.filename}: " if e.filename else ""
        print(f"{prog}: error: {where}{e.strerror or e}", file=sys.stderr)
        return EXIT_SOME_FAILED if e.errno in _SYSTEM_ERRNOS else EXIT_USAGE
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        if sys.stdout is guard:
            sys.stdout = guard.stream


#: Threads that :func:`end_process` may cut short: background loads of compiled executables
#: (:meth:`inference.aot.ExecutableStore.preload`) that the command turned out not to need.
DISPOSABLE_THREAD_PREFIX = "aot-"


def end_process(status: int) -> NoReturn:
    """Exit with ``status`` as soon as the command has returned (the console scripts' last call).

    The interpreter's own exit frees every object and module one by one: after a MAP
    calibration that is ≈ 0.5 s of tearing down compiled executables (measured, 9 h record,
    jax 0.10.2), a sixth of the command's wall time, with nothing left to do. Here the
    standard streams are flushed and the process ends with ``os._exit``. Every file a command
    writes is closed by then (:func:`chekan.durable.atomic_output`). A non-daemon thread
    still running (other than a preload of executables) means work in flight: then the
    ordinary exit runs, which waits for it. A standard output closed early still ends with
    :data:`EXIT_CLOSED_PIPE`, quietly.
    """
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        status = _stdout_closed()
    except (OSError, ValueError, AttributeError):  # closed or replaced: nothing to flush
        pass
    try:
        sys.stderr.flush()
    except (OSError, ValueError, AttributeError):
        pass
    main = threading.main_thread()
    busy = [
        t
        for t in threading.enumerate()
        if t is not main
        and t.is_alive()
        and not t.daemon
        and not t.name.startswith(DISPOSABLE_THREAD_PREFIX)
    ]
    if busy:
        sys.exit(status)
    if "logging" in sys.modules:  # handlers flush and close their files
        sys.modules["logging"].shutdown()
    os._exit(status)
