"""``python -m bench``: every benchmark in one run, one table, ``bench_results.json``.

    python -m bench [--quick] [--skip-bayes] [--fresh-cache] [--archive-n N]
                    [--archive-map-n M] [--jobs J] [--nuts] [--first-run] [--seed S]
                    [--json PATH]

Each figure is printed beside its reference measured in the same run (or the issue's goal
where there is no reference tool):

- ``bench/cli_bench.py``: ``chekan calibrate rec.csv --method map`` on a 9 h record as a NEW
  process (subprocess of the CLI), first and second run, goal ≤ 3 s; the same for
  ``--method bayes``, goal ≤ 15 s (skipped by ``--skip-bayes`` and ``--quick``); each row says
  whether the persistent JAX cache (``CHEKAN_JAX_CACHE``) was warm and how many entries the
  run added (``--fresh-cache``: an empty cache, a truly cold first run);
- ``bench/calibration_bench.py``: the classical fit against a plain-NumPy fit, MAP first and
  warm, one LM pass (optimistix) against ``scipy.optimize.least_squares`` on the same jitted
  residuals;
- ``bench/nuts_bench.py``: the marginal log-density (12 dimensions, jitted), median of many
  warm calls, beside the 0.5 ms goal; ``bayes`` in one warm process (MAP + emcee + derived
  draws: seconds, min bulk ESS, converged?) beside NUTS (blackjax) on the SAME log-density:
  ESS/s of both and the agreement of the posterior means (within 0.1 sd) and sds (10 %)
  (skipped by ``--skip-bayes``; ``--quick`` runs it on the 3 h record with fewer draws);
- ``bench/archive_bench.py``: re-analysis sessions/s, classical and MAP, against a plain
  ``calibrate_file`` loop;
- ``bench/several_records.py``: ``calibrate --method bayes`` and ``--method map`` as new
  processes on four independent records (typical, misaligned and slow-damping platforms on
  the paper's program, and a dual-axis program): per record the wall time, converged, τ_max,
  bulk ESS and ESS/s per parameter; the median and the worst beside a bare JAX start measured
  in the same run (ratio, the issue's targets); ``reanalyze --method bayes`` sessions/s over
  them on ``--jobs`` workers (``--skip-bayes``: map rows only; ``--quick``: 3 h records and a
  6-round dual-axis one; ``--nuts``: NUTS against emcee on the slowest record);
- ``bench/first_run.py`` (``--first-run``, a few minutes more): a fresh executable store
  filled by ``chekan warmup``, then the first ``map`` of three never-seen records (the
  paper's 9 h program, a 3-angle program, the designer's xy program) beside their warm
  runs, goal ≤ 2×.

All figures, with their raw numbers and the machine's description (the load average
matters on a shared machine), go to ``--json``. About 10 minutes on 2 cores with a warm JAX
cache, and the several-records bench about 12 more on a loaded machine; ``--quick`` (about 5
minutes, and about 10 for the several-records bench on a loaded machine): the 3 h record, the
CLI's map rows only, the posterior bench on the 3 h record, 40 archive sessions, classical
only (``--archive-map-n 2`` adds MAP: its workers compile for minutes on a cold cache), the
several-records bench on 3 h records.
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import (
    archive_bench,
    calibration_bench,
    cli_bench,
    first_run,
    nuts_bench,
    several_records,
)
from bench.table import Row, environment, environment_line, format_table, write_json


def main(argv: list[str] | None = None) -> int:
    from chekan.archive.reanalyze import default_jobs

    ap = argparse.ArgumentParser(
        prog="python -m bench",
        description=__doc__.split("\n\n")[0],
        epilog=__doc__.split("\n\n", 2)[2],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="small sizes: 3 h record, CLI map rows only, short posterior, no MAP re-analysis",
    )
    ap.add_argument(
        "--skip-bayes", action="store_true", help="no posterior, no bayes CLI runs (saves minutes)"
    )
    ap.add_argument(
        "--fresh-cache", action="store_true", help="CLI runs start from an empty JAX cache"
    )
    ap.add_argument("--archive-n", type=int, help="archive sessions (default 200; quick 40)")
    ap.add_argument(
        "--archive-map-n", type=int, help="of which by MAP (default 4; quick 0: skipped)"
    )
    ap.add_argument("--jobs", type=int, default=default_jobs(), help="worker processes")
    ap.add_argument(
        "--nuts", action="store_true", help="NUTS against emcee on the slowest of the records"
    )
    ap.add_argument(
        "--first-run", action="store_true", help="the first map after a fresh warmup (minutes)"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default="bench_results.json", help="where to write the figures")
    args = ap.parse_args(argv)
    archive_n = args.archive_n or (40 if args.quick else 200)
    map_n = args.archive_map_n if args.archive_map_n is not None else (0 if args.quick else 4)

    env = environment()
    t0 = time.perf_counter()
    rows: list[Row] = []
    sections = (
        (
            "CLI",
            lambda: cli_bench.run(
                args.seed, skip_bayes=args.skip_bayes or args.quick, fresh_cache=args.fresh_cache
            ),
        ),
        ("calibration", lambda: calibration_bench.run(args.seed, quick=args.quick)),
        (
            "posterior",
            lambda: [] if args.skip_bayes else nuts_bench.run(args.seed, quick=args.quick),
        ),
        (
            "archive",
            lambda: archive_bench.run(archive_n, args.jobs, map_n, seed=args.seed),
        ),
        (
            "several-records",
            lambda: several_records.run(
                args.seed,
                quick=args.quick,
                jobs=args.jobs,
                skip_bayes=args.skip_bayes,
                nuts=args.nuts,
            ),
        ),
        ("first-run", lambda: first_run.run(args.seed) if args.first_run else []),
    )
    failed = 0
    for name, fn in sections:
        print(f"running the {name} bench …", flush=True)
        try:
            rows += fn()
        except Exception as e:  # one broken bench never hides the other's figures
            failed += 1
            traceback.print_exc()
            rows.append(Row(f"{name} bench", "FAILED", note=f"{type(e).__name__}: {e}"))
    seconds = time.perf_counter() - t0
    print()
    print(format_table(rows, f"chekan benchmarks ({seconds:.0f} s)"))
    print(environment_line(env))
    settings = {
        "quick": args.quick,
        "skip_bayes": args.skip_bayes,
        "fresh_cache": args.fresh_cache,
        "archive_n": archive_n,
        "archive_map_n": map_n,
        "jobs": args.jobs,
        "nuts": args.nuts,
        "seed": args.seed,
    }
    path = write_json(args.json, rows, environment=env, settings=settings, seconds=seconds)
    print(f"wrote {path}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
