"""Batch re-analysis throughput: sessions per second, classical and MAP.

    python bench/archive_bench.py --n 1000 [--jobs J] [--map-n M] [--keep DIR]

Simulates N SHORT sessions (4 angles, 120 s dwell, one round; 60 kB records) of N/20
instruments over ten years, then times ``reanalyze`` into a fresh archive: classical on
all N, the skip pass (everything already archived), and MAP (only when ``chekan/bayes.py``
exists) on ``--map-n`` of them (default all N: expect ~30 s per record per core).
``--keep DIR`` keeps (and reuses) the simulated records; the archive is new every run.
Worker processes use the persistent JAX compilation cache; the first MAP call of each
worker compiles.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import multiprocessing as mp
import shutil
import sys
import tempfile
import time
from pathlib import Path

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
    t0 = time.perf_counter()
    step = max(1, -(-n // (4 * jobs)))
    tasks = [(str(root), lo, min(n, lo + step), seed) for lo in range(0, n, step)]
    with cf.ProcessPoolExecutor(jobs, mp_context=mp.get_context("spawn")) as ex:
        assert sum(ex.map(_generate, tasks)) == n
    return time.perf_counter() - t0


def timed_reanalyze(root: Path, method: str, db: Path, jobs: int):
    from chekan.archive.reanalyze import reanalyze

    t0 = time.perf_counter()
    rep = reanalyze(root, method, db=db, jobs=jobs, progress=False)
    return time.perf_counter() - t0, rep


def line(label: str, n: int, dt: float, extra: str = "") -> str:
    rate = n / dt if dt > 0 else float("inf")
    return f"  {label:<10} {n:6d} sessions {dt:9.1f} s {rate:10.2f} sessions/s  {extra}"


def main(argv: list[str] | None = None) -> int:
    from chekan.archive.reanalyze import default_jobs

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--n", type=int, default=1000, help="sessions to simulate and re-analyse")
    ap.add_argument("--jobs", type=int, default=default_jobs(), help="worker processes")
    ap.add_argument("--map-n", type=int, help="sessions for the MAP pass (default: all N)")
    ap.add_argument("--keep", help="keep the records and the archive in this folder")
    args = ap.parse_args(argv)

    import chekan

    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="chekan-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    records = work / "records"
    try:
        print(
            f"archive bench: {args.n} short sessions, {args.jobs} worker(s), "
            f"chekan {chekan.__version__}, {work}"
        )
        if not records.exists():
            dt = generate(records, args.n, args.jobs)
            print(f"  {'simulate':<10} {args.n:6d} records  {dt:9.1f} s")
        store = work / "store"  # a fresh archive every run (records are kept with --keep)
        shutil.rmtree(store, ignore_errors=True)
        db = store / "archive.sqlite"
        dt, rep = timed_reanalyze(records, "classical", db, args.jobs)
        print(line("classical", len(rep.done), dt, f"({len(rep.failed)} failed)"))
        dt, rep = timed_reanalyze(records, "classical", db, args.jobs)
        print(line("skip", len(rep.skipped), dt, "(all already archived)"))
        if not (Path(chekan.__file__).parent / "bayes.py").exists():
            print("  map: chekan/bayes.py not present, skipped")
            return 0
        n_map = min(args.map_n or args.n, args.n)
        sub = work / f"map_{n_map}"
        if not sub.exists():
            sub.mkdir()
            for p in sorted(records.rglob("*.csv"))[:n_map]:
                shutil.copy(p, sub / p.name)
        dt, rep = timed_reanalyze(sub, "map", db, args.jobs)
        reasons = sorted({f.reason.split(": ", 1)[-1] for f in rep.failed})[:3]
        print(line("map", len(rep.done), dt, f"({len(rep.failed)} failed) {'; '.join(reasons)}"))
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
