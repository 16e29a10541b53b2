"""Batch re-analysis throughput: sessions per second, classical and MAP.

    python bench/archive_bench.py --n 1000 [--jobs J] [--map-n M] [--ref-n R] [--keep DIR]

Simulates N SHORT sessions (4 angles, 120 s dwell, one round; 60 kB records) of N/20
instruments over ten years, then times ``chekan.archive.reanalyze.reanalyze`` into a fresh
archive: classical on all N, the skip pass (everything already archived), and MAP on
``--map-n`` of them (default all N; 0 skips it). The reference for each method, measured in the same
run, is the plain loop a user would write: ``chekan.pipeline.calibrate_file`` on each
file in this one process, no archive (``--ref-n`` files, default all of the pass; MAP's
first call here compiles or loads the persistent cache, as each worker's does).
``--keep DIR`` keeps (and reuses) the simulated records; the archive is new every run.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import multiprocessing as mp
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.table import Row, environment, environment_line, format_table

SESSIONS_PER_INSTRUMENT = 20


def _generate(args: tuple[str, int, int, int]) -> int:
    """Write the sessions ``lo..hi`` of the benchmark archive (worker task)."""
    import numpy as np

    from chekan.archive.synth import InstrumentSpec, session_dates, short_program, write_session

    root, lo, hi, seed = args
    program = short_program()
    for i in range(lo, hi):
        k, j = divmod(i, SESSIONS_PER_INSTRUMENT)
        spec = InstrumentSpec(f"BENCH-{k:04d}", rate_ppm_per_year=10.0 * (k % 5), seed=seed + k)
        dates = session_dates("2010-01-15", 10.0, SESSIONS_PER_INSTRUMENT, np.random.default_rng(k))
        path = Path(root) / spec.serial / f"{spec.serial}_{j:02d}_{dates[j]}.csv"
        write_session(path, spec, dates[j], seed=seed + i, program=program)
    return hi - lo


def generate(root: Path, n: int, jobs: int, seed: int = 0) -> float:
    """Simulate ``n`` records under ``root`` in ``jobs`` spawned processes; seconds."""
    t0 = time.perf_counter()
    step = max(1, -(-n // (4 * jobs)))
    tasks = [(str(root), lo, min(n, lo + step), seed) for lo in range(0, n, step)]
    with cf.ProcessPoolExecutor(jobs, mp_context=mp.get_context("spawn")) as ex:
        assert sum(ex.map(_generate, tasks)) == n
    return time.perf_counter() - t0


def timed_reanalyze(root: Path, method: str, db: Path, jobs: int):
    """``(seconds, BatchReport)`` of one ``reanalyze`` call."""
    from chekan.archive.reanalyze import reanalyze

    t0 = time.perf_counter()
    rep = reanalyze(root, method, db=db, jobs=jobs, progress=False)
    return time.perf_counter() - t0, rep


def timed_loop(paths: list[Path], method: str) -> list[float | None]:
    """The reference: ``calibrate_file`` on each path in this process; seconds per file
    (``None`` where it failed, as ``reanalyze`` counts its failures)."""
    from chekan.pipeline import CalibrationOptions, calibrate_file

    opts = CalibrationOptions(method=method, progress=False)
    out: list[float | None] = []
    for p in paths:
        t0 = time.perf_counter()
        try:
            calibrate_file(p, opts)
            out.append(time.perf_counter() - t0)
        except Exception:
            out.append(None)
    return out


def _rate(n: int, dt: float) -> float:
    return n / dt if dt > 0 else float("nan")


def _pass_row(
    label: str, n_done: int, n_failed: int, dt: float, loop: list[float | None], jobs: int
) -> Row:
    """A row for one re-analysis pass beside the plain loop's seconds per file."""
    note = f"{n_done} sessions in {dt:.1f} s, {jobs} worker(s), {n_failed} failed"
    values: dict[str, object] = {
        "sessions": n_done,
        "seconds": dt,
        "sessions_per_s": _rate(n_done, dt),
    }
    ok = [t for t in loop if t is not None]
    rdt = sum(ok)
    note += f"; loop: {len(ok)}/{len(loop)} files in {rdt:.1f} s, 1 process, no archive"
    if len(ok) > 1:  # the first call compiles (or loads the persistent cache)
        med = statistics.median(ok[1:])
        note += f" (first {ok[0]:.2f} s, then median {med:.3f} s"
        # the steady state of warm workers, without their start-up (imports, executables)
        note += f": {jobs} warm workers ≈ {jobs / med:.1f}/s)"
        values["warm_sessions_per_s_estimate"] = jobs / med
    ratio = _rate(n_done, dt) / _rate(len(ok), rdt) if ok and n_done else float("nan")
    note += f"; {ratio:.2f}× the plain loop's rate"
    values.update(
        reference_seconds=rdt,
        reference_sessions=len(ok),
        reference_sessions_per_s=_rate(len(ok), rdt),
        reference_seconds_per_file=loop,
        ratio_to_plain_loop=ratio,
    )
    return Row(
        label,
        f"{_rate(n_done, dt):.2f}/s ({ratio:.2f}× loop)",
        f"{_rate(len(ok), rdt):.2f}/s plain loop",
        note,
        values,
    )


def run(
    n: int = 200,
    jobs: int | None = None,
    map_n: int | None = None,
    ref_n: int | None = None,
    keep: str | None = None,
    seed: int = 0,
) -> list[Row]:
    """Measure the figures (see the module docstring); returns the rows."""
    from chekan.archive.reanalyze import default_jobs

    jobs = jobs or default_jobs()
    work = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="chekan-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    records = work / "records"
    rows: list[Row] = []
    try:
        if not records.exists():
            dt = generate(records, n, jobs, seed)
            rows.append(
                Row(
                    f"simulate {n} short records",
                    f"{dt:.1f} s",
                    note=f"{jobs} process(es); 4 angles × 120 s, one round",
                    values={"seconds": dt, "sessions": n},
                )
            )
        store = work / "store"  # a fresh archive every run (records are kept with --keep)
        shutil.rmtree(store, ignore_errors=True)
        db = store / "archive.sqlite"
        paths = sorted(records.rglob("*.csv"))

        dt, rep = timed_reanalyze(records, "classical", db, jobs)
        k = min(ref_n or len(paths), len(paths))
        loop = timed_loop(paths[:k], "classical")
        rows.append(
            _pass_row("re-analysis classical", len(rep.done), len(rep.failed), dt, loop, jobs)
        )
        dt, rep = timed_reanalyze(records, "classical", db, jobs)
        rows.append(
            Row(
                "re-analysis skip pass",
                f"{_rate(len(rep.skipped), dt):.2f}/s",
                note=f"{len(rep.skipped)} already archived, {dt:.1f} s",
                values={"sessions": len(rep.skipped), "seconds": dt},
            )
        )

        n_map = min(len(paths) if map_n is None else map_n, len(paths))
        if n_map <= 0:
            rows.append(Row("re-analysis MAP", "skipped", note="--map-n 0"))
            return rows
        sub = work / f"map_{n_map}"
        if not sub.exists():
            sub.mkdir()
            for p in paths[:n_map]:
                shutil.copy(p, sub / p.name)
        dt, rep = timed_reanalyze(sub, "map", db, jobs)
        k = min(ref_n or n_map, n_map)
        loop = timed_loop(sorted(sub.glob("*.csv"))[:k], "map")
        row = _pass_row("re-analysis MAP", len(rep.done), len(rep.failed), dt, loop, jobs)
        reasons = sorted({f.reason.split(": ", 1)[-1] for f in rep.failed})[:3]
        if reasons:
            row.note += f"; {'; '.join(reasons)}"
        rows.append(row)
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    from chekan.archive.reanalyze import default_jobs

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--n", type=int, default=1000, help="sessions to simulate and re-analyse")
    ap.add_argument("--jobs", type=int, default=default_jobs(), help="worker processes")
    ap.add_argument("--map-n", type=int, help="sessions for the MAP pass (default: all N; 0: none)")
    ap.add_argument("--ref-n", type=int, help="files for the plain-loop reference (default all)")
    ap.add_argument("--keep", help="keep the records and the archive in this folder")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    env = environment()
    rows = run(args.n, args.jobs, args.map_n, args.ref_n, args.keep, args.seed)
    print(format_table(rows, f"archive bench ({args.jobs} worker(s))"))
    print(environment_line(env))
    return 0


if __name__ == "__main__":
    sys.exit(main())
