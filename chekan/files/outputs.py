"""What every command does with the files it writes and with its standard output.

- :func:`check_outputs` is called by every command *before* it does any work: it refuses
  (:class:`OutputError`, exit status 2) to write over one of the command's own inputs, to
  write two outputs to one file, to write into a folder that does not exist (nothing is
  created), to overwrite an existing ``chekan-record/1`` or ``chekan-protocol/1`` file
  (measurements cannot be recomputed; results can) or an SQLite database (an archive:
  every session of every instrument), to overwrite any other file of a kind chekan reads
  or writes (a result, a program, a lab file, a DCC, a PDF, …: :mod:`chekan.files.kinds`)
  with anything but a file of the same kind (:class:`Output`), and to write one format
  under another's suffix (JSON into ``x.pdf``). The file is named in the message.
- :func:`run_command` runs a command function the same way in every ``main()``: a
  :class:`~chekan.errors.ChekanError` or an :class:`OSError` (a missing input, a folder
  one cannot write to) is one line on stderr naming the file and exit status 2, Ctrl-C is
  130, and a closed standard output (``chekan archive list | head``) ends the command
  quietly with status 141 (128 + SIGPIPE, what a shell reports for a Unix tool killed by
  SIGPIPE) instead of a ``BrokenPipeError`` traceback. A warning is one line,
  ``chekan: warning: …``, without the source line that Python prints.

- :func:`end_process` ends a command-line process once its command has returned: it
  flushes the standard streams and exits without the interpreter's teardown (0.5 s of
  freeing compiled executables after a MAP calibration), unless a thread still has work.

Writing itself goes through :func:`chekan.files.durable.atomic_output` (temporary file beside
the target, then renamed into place). Stdlib only: cheap to import from every CLI.
"""

from __future__ import annotations

import errno
import os
import shutil
import sys
import threading
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

from chekan.errors import ChekanError
from chekan.files.kinds import (
    FOLDER,
    KNOWN_SUFFIXES,
    PROGRAM,
    PROTECTED_FORMATS,
    RESULT,
    SQLITE,
    SUFFIXES,
    noun,
    sniff_format,
    sniff_kind,
)

PathArg = str | os.PathLike[str]

__all__ = [  # the kinds and sniffers of chekan.files.kinds are used from here too
    "FOLDER",
    "PROGRAM",
    "PROTECTED_FORMATS",
    "RESULT",
    "SQLITE",
    "SYSTEM_ERRNOS",
    "Output",
    "OutputError",
    "check_outputs",
    "check_room",
    "end_process",
    "run_command",
    "sniff_format",
    "sniff_kind",
]

EXIT_OK = 0
EXIT_SOME_FAILED = 1
EXIT_USAGE = 2
EXIT_NOT_CONVERGED = 3
EXIT_ALARM = 4
EXIT_INTERRUPTED = 130
EXIT_CLOSED_PIPE = 141


#: Failures of the system rather than of the input (a full disk, an I/O error): exit 1.
SYSTEM_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO})


class OutputError(ChekanError):
    """An output option names a file the command must not write."""


@dataclass(frozen=True)
class Output:
    """An output of a command and the kind of file it writes (:mod:`chekan.files.kinds`).

    It may replace an existing file of its kind only (a result over a result); its name
    must not carry another kind's suffix (:data:`~chekan.files.kinds.SUFFIXES`). ``writes=
    FOLDER``: a folder of outputs, created by the command if missing (its parent must
    exist); the outputs given inside it need no existing folder. ``makes_folders``: the
    command creates the missing folders itself (a default location nobody named).
    """

    path: PathArg | None  # None: the option was not given (skipped)
    writes: str | None = None
    makes_folders: bool = False


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
    - is to go into a folder that does not exist (nothing is created: a typo in a path
      must not leave folders behind),
    - exists and begins like a ``chekan-record/1``, ``chekan-protocol/1`` or
      ``chekan-angle-calibration/1`` file,
    - exists and is an SQLite database (or one of its journal files), unless the output
      is the database itself (``Output(path, writes=SQLITE)``: an archive to add to),
    - exists and is any other kind of file chekan knows (:func:`sniff_kind`: a result, a
      program, a lab file, a DCC, a PDF, …) that the output would replace with a file of
      another kind (a bare path writes an unnamed kind),
    - has a suffix of another kind than the output writes (JSON into ``x.pdf``).

    Folders among ``inputs`` protect nothing here (a command that reads a folder checks
    its files itself).
    """
    ins = [Path(p) for p in inputs if p is not None]
    given = (o if isinstance(o, Output) else Output(o) for o in outputs if o is not None)
    specs = [(Path(s.path), s) for s in given if s.path is not None]
    folders = [p for p, s in specs if s.writes == FOLDER]
    seen: list[Path] = []
    for out, spec in specs:
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
        if not spec.makes_folders and not any(_same(out.parent, f) for f in folders):
            _check_folder(out)
        if spec.writes == FOLDER:
            if out.exists() and not out.is_dir():
                raise OutputError(f"{out}: exists and is not a folder; choose another folder")
            continue
        if out.is_file():
            _refuse_to_replace(out, sniff_kind(out), spec.writes)
        _check_suffix(out, spec.writes)


def _check_folder(out: Path) -> None:
    """The folder that is to hold ``out`` must exist (no output creates missing folders)."""
    parent = out.parent
    if parent.is_dir():
        return
    why = "is not a folder" if parent.exists() else "no such folder"
    raise OutputError(f"{parent}: {why} (for the output {out}); create it first or choose another")


def _check_suffix(out: Path, writes: str | None) -> None:
    """An output's suffix must not name another format than the one it writes."""
    suffix = out.suffix.lower()
    own = SUFFIXES.get(writes or "")
    if own is None or suffix not in KNOWN_SUFFIXES or suffix in own:
        return
    raise OutputError(
        f"{out}: refusing to write {noun(writes)} under a {suffix} name (the suffix of "
        f"another format); name it {' or '.join(own)}"
    )


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
    if kind is not None and writes != kind:
        raise OutputError(
            f"{out}: exists and is {noun(kind)}, which chekan reads or writes: refusing to "
            f"overwrite it with {noun(writes)}; choose another output file"
        )


def check_room(path: PathArg | None, nbytes: int, what: str) -> None:
    """Before a long computation: an :class:`OSError` (ENOSPC, exit 1) naming ``path`` when
    the disk of its folder has less than ``nbytes`` free for ``what`` (``None``: no file)."""
    if path is None:
        return
    free = shutil.disk_usage(Path(path).parent).free
    if free < nbytes:
        raise OSError(
            errno.ENOSPC,
            f"no room for {what}: it needs about {_mb(nbytes)} and its disk has {_mb(free)} "
            "free (nothing was computed)",
            str(path),
        )


def _mb(nbytes: int) -> str:
    return f"{nbytes / 1e6:.1f} MB" if nbytes < 1e9 else f"{nbytes / 1e9:.1f} GB"


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
    formatwarning = warnings.formatwarning
    warnings.formatwarning = _one_line_warning(prog)
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
        return EXIT_SOME_FAILED if e.errno in SYSTEM_ERRNOS else EXIT_USAGE
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        warnings.formatwarning = formatwarning
        if sys.stdout is guard:
            sys.stdout = guard.stream


def _one_line_warning(prog: str) -> Callable[..., str]:
    """:func:`warnings.formatwarning` for a command: ``prog: warning: message`` on one line,
    without the source file and line (the message names the input); a category other
    than a user or runtime warning (a ResourceWarning, …) is named after it."""

    def format_warning(message, category, filename, lineno, line=None) -> str:
        text = " ".join(str(message).split())
        ours = issubclass(category, UserWarning | RuntimeWarning)
        return f"{prog}: warning: {text}{'' if ours else f' ({category.__name__})'}\n"

    return format_warning


#: Threads that :func:`end_process` may cut short: background loads of compiled executables
#: (:meth:`chekan.runtime.store.ExecutableStore.preload`) that the command turned out not to need.
DISPOSABLE_THREAD_PREFIX = "aot-"


def end_process(status: int) -> NoReturn:
    """Exit with ``status`` as soon as the command has returned (the console scripts' last call).

    The interpreter's own exit frees every object and module one by one: after a MAP
    calibration that is ≈ 0.5 s of tearing down compiled executables (measured, 9 h record,
    jax 0.10.2), a sixth of the command's wall time, with nothing left to do. Here the
    standard streams are flushed and the process ends with ``os._exit``. Every file a command
    writes is closed by then (:func:`chekan.files.durable.atomic_output`). A non-daemon thread
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
