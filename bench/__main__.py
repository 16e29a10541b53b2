"""``python -m bench``: every benchmark in one run, one table, ``bench_results.json``.

    python -m bench [--quick] [--skip-bayes] [--archive-n N] [--archive-map-n M]
                    [--jobs J] [--seed S] [--json PATH]

Runs ``bench/calibration_bench.py`` (classical fit against a plain-NumPy fit, MAP and
one LM pass against scipy ``least_squares``, the posterior and its ESS) and
``bench/archive_bench.py`` (re-analysis sessions/s, classical and MAP, against a plain
``calibrate_file`` loop) in this process, prints one table and writes every figure with
its raw numbers and the machine's description to ``--json``. ``--quick`` (about a minute
with a warm JAX cache): the 3 h record, no posterior, 40 archive sessions, classical only
(``--archive-map-n 2`` adds MAP: its workers compile for minutes on a cold cache).
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import archive_bench, calibration_bench
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
        "--quick", action="store_true", help="small sizes, no posterior, no MAP re-analysis"
    )
    ap.add_argument("--skip-bayes", action="store_true", help="no posterior (saves ~1 min)")
    ap.add_argument("--archive-n", type=int, help="archive sessions (default 200; quick 40)")
    ap.add_argument(
        "--archive-map-n", type=int, help="of which by MAP (default 4; quick 0: skipped)"
    )
    ap.add_argument("--jobs", type=int, default=default_jobs(), help="worker processes")
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
            "calibration",
            lambda: calibration_bench.run(
                args.seed, skip_bayes=args.skip_bayes or args.quick, quick=args.quick
            ),
        ),
        (
            "archive",
            lambda: archive_bench.run(archive_n, args.jobs, map_n, seed=args.seed),
        ),
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
        "skip_bayes": args.skip_bayes or args.quick,
        "archive_n": archive_n,
        "archive_map_n": map_n,
        "jobs": args.jobs,
        "seed": args.seed,
    }
    path = write_json(args.json, rows, environment=env, settings=settings, seconds=seconds)
    print(f"wrote {path}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
