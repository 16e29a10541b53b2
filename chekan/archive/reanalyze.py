"""Batch re-analysis: every calibration input under a folder, one method, into the archive.

    chekan reanalyze DIR --method classical|map|bayes [--jobs N] [--db PATH]
                     [--executor local|dask] [--scheduler ADDR] [--results-dir D]

1. *Discover*: walk DIR (hidden entries skipped) and sniff each file's leading ``# key: value``
   block for ``# format: chekan-record/1`` or ``chekan-protocol/1``; files without a
   ``# format:`` line are not inputs and are ignored; an unreadable file or another
   ``chekan-*`` format is a failure.
2. *Skip* inputs whose content (SHA-256) is already archived with this method and software
   version, and second copies of the same content within DIR.
3. *Analyse* the rest in chunks on an executor: local worker processes (spawn context, one
   BLAS thread each, loading what the executable store holds) or a Dask cluster. A
   malformed input fails on its own (``file:line: problem``); a crashed worker process gets
   its files retried once, one file per task, so only the culprit fails. Classical fits
   are cheap (~10 ms): when starting the workers would cost more than it saves
   (:func:`run_in_process`), they run in this process, chunk by chunk, with the same
   per-file failure isolation.
4. *Archive*: each result JSON is written to the results folder (default
   ``<archive dir>/results``) and added to the archive; the summary lists failures.

Imports here are stdlib only: worker processes import this module before
:func:`configure_worker_env` has set their thread limits.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing as mp
import os
import threading
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from chekan.errors import ChekanError, FormatError

INPUT_FORMATS = {"chekan-record/1": "record", "chekan-protocol/1": "protocol"}
EXECUTORS = ("local", "dask")
_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
_SNIFF_BYTES = 1 << 16
#: Measured on the benchmark's short records (bench/archive_bench.py): one classical fit,
#: and the start of a spawned worker (interpreter, NumPy, SciPy, the pipeline), seconds.
CLASSICAL_FIT_S = 0.01
WORKER_START_S = 2.0


@dataclass
class Failure:
    """An input that could not be analysed; ``reason`` is ``"<file>[:<line>]: <problem>"``."""

    path: str
    reason: str


@dataclass
class BatchReport:
    """What a batch did; ``done`` maps input path → archive session id."""

    method: str
    software_version: str
    found: int = 0
    done: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)  # path → why
    failed: list[Failure] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def summary(self) -> str:
        lines = [
            f"reanalyze ({self.method}, chekan {self.software_version}): {self.found} input(s)",
            f"  done     {len(self.done):5d}",
            f"  skipped  {len(self.skipped):5d}",
            f"  failed   {len(self.failed):5d}",
        ]
        lines += [f"    {f.reason}" for f in self.failed]
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


# ---------------------------------------------------------------------------- discovery
def sniff_format(path: str | os.PathLike) -> tuple[str, int] | None:
    """``(value, line)`` of the ``# format:`` line in the leading ``#`` block, or ``None``."""
    with open(path, "rb") as f:
        head = f.read(_SNIFF_BYTES)
    if head.startswith(b"\xef\xbb\xbf"):
        head = head[3:]
    for lineno, raw in enumerate(head.split(b"\n"), start=1):
        if not raw.startswith(b"#"):
            return None
        line = raw.rstrip(b"\r")
        if line.startswith(b"# format: "):
            return line[len(b"# format: ") :].decode("utf-8", "replace").strip(), lineno
    return None


def _unreadable(path: str | os.PathLike, e: OSError) -> Failure:
    return Failure(str(path), str(FormatError(path, None, f"cannot read: {e.strerror or e}")))


def find_inputs(root: str | os.PathLike) -> tuple[list[tuple[Path, str]], list[Failure]]:
    """``([(path, kind)], failures)`` for every file under ``root``, sorted by path.

    What this package writes (result JSON, NetCDF, SQLite) has no ``# format:`` line.
    """
    inputs: list[tuple[Path, str]] = []
    failures: list[Failure] = []
    root = Path(root)
    if not root.is_dir():
        raise ChekanError(f"{root}: not a directory")
    for dirpath, dirnames, filenames in os.walk(root):
        d = Path(dirpath)
        dirnames[:] = sorted(n for n in dirnames if not n.startswith("."))
        for name in sorted(filenames):
            p = d / name
            if name.startswith(".") or not p.is_file():
                continue
            try:
                sniffed = sniff_format(p)
            except OSError as e:
                failures.append(_unreadable(p, e))
                continue
            if sniffed is None:
                continue
            fmt, line = sniffed
            if fmt in INPUT_FORMATS:
                inputs.append((p, INPUT_FORMATS[fmt]))
            elif fmt.startswith("chekan-"):
                why = f"unsupported format {fmt!r} (expected {' or '.join(INPUT_FORMATS)})"
                failures.append(Failure(str(p), str(FormatError(p, line, why))))
    return inputs, failures


# ---------------------------------------------------------------------------- workers
def configure_worker_env() -> None:
    """One BLAS thread a worker: call before JAX/NumPy initialise. ``XLA_FLAGS`` stay the
    parent's: they are part of every stored executable's key
    (:mod:`chekan.runtime.store`), so a worker of other flags would compile again what
    ``chekan warmup`` stored (XLA's intra-op threads off changed no warm run:
    docs/development/tuning.md). The worker also ends when its parent does
    (:func:`exit_with_parent`)."""
    exit_with_parent()
    for v in _THREAD_VARS:
        os.environ[v] = "1"


#: How often a worker looks whether its parent is still alive, s.
PARENT_CHECK_S = 0.5


def exit_with_parent() -> None:
    """End this process as soon as its parent is gone (``kill -9`` of ``reanalyze``): a
    daemon thread compares the parent's pid with the one at start-up, so a worker in the
    middle of a calibration does not run on for minutes holding its memory."""
    parent = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(PARENT_CHECK_S)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def _options(opts: dict[str, Any]):
    from chekan.pipeline import CalibrationOptions

    return CalibrationOptions(**opts)


def solve_many_map(paths: Sequence[str | Path], options=None) -> list[dict | Exception]:
    """MAP calibration of many inputs → one result dict (or the exception raised) per path,
    one at a time (records of one padded shape share the compiled solver). A bad input fails
    on its own.
    """
    from dataclasses import replace

    from chekan.pipeline import CalibrationOptions, classical_stage, joint_stage

    opts = replace(options or CalibrationOptions(), method="map", progress=False)
    out: list[dict | Exception] = []
    for p in paths:
        try:
            data, kind, cres, base = classical_stage(p, opts)
            out.append(joint_stage(data, kind, cres, base, opts))
        except Exception as e:  # one bad input never spoils the chunk
            out.append(e)
    return out


def analyse_chunk(
    paths: Sequence[str],
    method: str,
    opts: dict[str, Any],
    netcdf: dict[str, str] | None = None,
) -> dict[str, list]:
    """Worker task: analyse ``paths``; never raises for a bad file.

    Returns ``{"outcomes": [...], "warnings": [...]}``, one outcome per path:
    ``{"path", "ok": True, "result"}`` or ``{"path", "ok": False, "reason"}``; the reason
    of a malformed input is ``file:line: problem``. ``netcdf``: bayes posterior file per path.
    """
    from dataclasses import replace

    from chekan.pipeline import calibrate_file

    base = _options({**opts, "method": method, "progress": False})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if method == "map":
            results = solve_many_map(paths, base)
        else:
            results = []
            for p in paths:
                o = base
                if netcdf and p in netcdf:
                    o = replace(base, netcdf=netcdf[p])
                try:
                    results.append(calibrate_file(p, o))
                except Exception as e:
                    results.append(e)
    outcomes = []
    for p, r in zip(paths, results, strict=True):
        if isinstance(r, Exception):
            why = str(r) if isinstance(r, FormatError) else f"{p}: {type(r).__name__}: {r}"
            outcomes.append({"path": p, "ok": False, "reason": why})
        else:
            outcomes.append({"path": p, "ok": True, "result": r})
    notes = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
    return {"outcomes": outcomes, "warnings": notes}


@contextlib.contextmanager
def make_executor(
    kind: str = "local", jobs: int | None = None, scheduler: str | None = None
) -> Iterator[cf.Executor]:
    """A ``concurrent.futures`` executor: local spawned processes, or Dask workers.

    ``dask``: ``Client(scheduler)`` when an address is given, else a ``LocalCluster`` of
    ``jobs`` single-threaded worker processes; its ``get_executor()`` is used.
    """
    jobs = max(1, jobs or default_jobs())
    if kind == "local":
        ctx = mp.get_context("spawn")
        ex = cf.ProcessPoolExecutor(
            max_workers=jobs, mp_context=ctx, initializer=configure_worker_env
        )
        try:
            yield ex
        except BaseException:  # Ctrl-C (or an error) here: the work in flight is dropped
            _stop_now(ex)
            raise
        ex.shutdown(wait=True)
        return
    if kind != "dask":
        raise ChekanError(f"unknown executor {kind!r}; choose one of {', '.join(EXECUTORS)}")
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise ChekanError(
            "--executor dask needs Dask distributed: pip install 'chekan[dask]'"
        ) from None
    with contextlib.ExitStack() as stack:
        if scheduler:
            client = stack.enter_context(Client(scheduler))
        else:
            cluster = stack.enter_context(
                LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True)
            )
            client = stack.enter_context(Client(cluster))
        client.run(configure_worker_env)
        yield client.get_executor(pure=False)


def _stop_now(ex: cf.ProcessPoolExecutor) -> None:
    """End ``ex`` without waiting for its tasks: a Ctrl-C of the parent alone must not wait
    for a MAP or a sampler to finish (its shutdown waits for every task, minutes)."""
    workers = list((getattr(ex, "_processes", None) or {}).values())  # no public API (< 3.14)
    ex.shutdown(wait=False, cancel_futures=True)
    for w in workers:
        w.terminate()
    for w in workers:
        w.join(timeout=5.0)


class InlineExecutor(cf.Executor):
    """Runs each task at once in this process; its future holds the result or exception."""

    def submit(self, fn, /, *args, **kwargs) -> cf.Future:
        fut: cf.Future = cf.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as e:
            fut.set_exception(e)
        return fut


def run_in_process(method: str, executor: str, n: int, jobs: int) -> bool:
    """Whether ``n`` files are analysed faster here than on ``jobs`` new worker processes.

    Only the classical method on the local executor: ``n`` fits in this process cost
    ``n·t``; on the workers ``WORKER_START_S + n·t/jobs``. MAP and Bayes keep their
    workers (each sets its BLAS threads and loads its bucket's executables once).
    """
    if method != "classical" or executor != "local":
        return False
    return jobs <= 1 or n * CLASSICAL_FIT_S * (1.0 - 1.0 / jobs) < WORKER_START_S


def default_jobs() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


# ---------------------------------------------------------------------------- the batch
def _chunks(items: list[str], jobs: int, size: int | None) -> list[list[str]]:
    """Chunks of ``size`` (default: about 4 per worker, at most 16 files each)."""
    if not items:
        return []
    n = size or max(1, min(16, -(-len(items) // (4 * jobs))))
    return [items[i : i + n] for i in range(0, len(items), n)]


def _notice_first_compile(paths: list[str], method: str, opts: dict[str, Any]) -> None:
    """Say first when the session will compile the joint model (a record shape whose
    bucket is not in the executable store: :func:`chekan.warmup.first_compile`)."""
    from chekan.runtime.engine import FIRST_RUN_NOTICE
    from chekan.warmup import first_compile

    if first_compile(paths, _options({**opts, "method": method, "progress": False})):
        print(f"reanalyze {method}: {FIRST_RUN_NOTICE}", flush=True)


def result_name(path: str | os.PathLike, sha: str, method: str, version: str) -> str:
    """``<stem>.<sha12>.<method>-<version>.json``: unique per archive key."""
    return f"{Path(path).stem}.{sha[:12]}.{method}-{version}.json"


def reanalyze(
    root: str | os.PathLike,
    method: str = "classical",
    *,
    db: str | os.PathLike | None = None,
    jobs: int | None = None,
    executor: str = "local",
    scheduler: str | None = None,
    results_dir: str | os.PathLike | None = None,
    chunk_size: int | None = None,
    options: dict[str, Any] | None = None,
    progress: bool = True,
    in_process: bool | None = None,
) -> BatchReport:
    """Discover, skip, analyse in parallel and archive (see the module docstring).

    ``in_process``: analyse in this process (``True``), on the executor (``False``), or
    whichever is faster (``None``, the default: :func:`run_in_process`).
    """
    import chekan
    from chekan.archive.db import Archive
    from chekan.pipeline import METHODS
    from chekan.results.document import sha256_file, write_result

    if method not in METHODS:
        raise ChekanError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    version = chekan.__version__
    report = BatchReport(method=method, software_version=version)
    jobs = max(1, jobs or default_jobs())
    with Archive(db) as archive:
        out_dir = Path(results_dir) if results_dir else archive.path.parent / "results"
        found, report.failed = find_inputs(Path(root).resolve())
        report.found = len(found)
        known = archive.known_hashes(method, version)
        first_of: dict[str, str] = {}
        todo: dict[str, str] = {}  # path → sha
        for p, _kind in found:
            try:
                sha = sha256_file(p)
            except OSError as e:
                report.failed.append(_unreadable(p, e))
                continue
            if sha in known:
                report.skipped[str(p)] = f"already archived ({method}, chekan {version})"
            elif sha in first_of:
                report.skipped[str(p)] = f"same content as {first_of[sha]}"
            else:
                first_of[sha] = str(p)
                todo[str(p)] = sha

        def finish(o: dict) -> None:
            p = o["path"]
            if not o["ok"]:
                report.failed.append(Failure(p, o["reason"]))
                return
            res = o["result"]
            sha = res.get("record_sha256") or todo[p]
            try:
                rp = write_result(out_dir / result_name(p, sha, method, version), res)
                report.done[p] = archive.add_result(res, rp)
            except (ChekanError, OSError) as e:
                report.failed.append(Failure(p, f"{p}: archiving failed: {e}"))

        opts = dict(options or {})
        nc_paths = None
        if method == "bayes":
            nc_paths = {
                p: str(out_dir / result_name(p, sha, method, version).replace(".json", ".nc"))
                for p, sha in todo.items()
            }
        if todo:
            out_dir.mkdir(parents=True, exist_ok=True)

        def submit(ex: cf.Executor, chunk: list[str]) -> cf.Future:
            nc = {p: nc_paths[p] for p in chunk} if nc_paths else None
            return ex.submit(analyse_chunk, chunk, method, opts, nc)

        def collect(chunk: dict) -> None:
            report.notes.extend(chunk["warnings"])
            for o in chunk["outcomes"]:
                finish(o)
            bar.update(len(chunk["outcomes"]))

        if progress and todo and method in ("map", "bayes"):
            _notice_first_compile(list(todo), method, opts)

        from tqdm.auto import tqdm

        crashed: list[str] = []
        with tqdm(
            total=len(todo), unit="file", desc=f"reanalyze {method}", disable=not progress
        ) as bar:
            if in_process is None:
                in_process = run_in_process(method, executor, len(todo), jobs)
            pool: contextlib.AbstractContextManager[cf.Executor]
            if in_process:
                pool = contextlib.nullcontext(InlineExecutor())
            else:
                pool = make_executor(executor, jobs, scheduler)
            with pool as ex:
                futs = {submit(ex, c): c for c in _chunks(list(todo), jobs, chunk_size)}
                for fut in cf.as_completed(futs):
                    try:
                        collect(fut.result())
                    except Exception:  # the worker died (or the result could not travel)
                        crashed.extend(futs[fut])
            # a dead worker breaks every task in flight: retry those one by one, on one
            # worker, so that only the culprit fails (and the pool is rebuilt after it)
            with contextlib.ExitStack() as stack:
                alone: cf.Executor | None = None
                for path in crashed:
                    if alone is None:
                        alone = stack.enter_context(make_executor(executor, 1, scheduler))
                    try:
                        collect(submit(alone, [path]).result())
                    except Exception as e:
                        reason = f"{path}: worker crashed: {e!r}"
                        finish({"path": path, "ok": False, "reason": reason})
                        bar.update(1)
                        stack.close()
                        alone = None
        report.notes = sorted(set(report.notes))
    return report
