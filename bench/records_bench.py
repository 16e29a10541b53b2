"""Read speed of ``chekan-record/1`` files (rows/s).

    python bench/records_bench.py [PATH]

Reads PATH, or a synthetic 33 000-row record (9 h at 1 Hz) written for the purpose,
five times and prints the best time.
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from chekan.records import read_record, synthetic_record, write_record


def main(argv: list[str] | None = None) -> None:
    """Print read speed (rows/s) for PATH, or for a synthetic 33 000-row record."""
    args = sys.argv[1:] if argv is None else argv
    with tempfile.TemporaryDirectory() as d:
        if args:
            path = args[0]
        else:
            path = os.path.join(d, "synthetic.csv")
            t0 = time.perf_counter()
            write_record(path, synthetic_record())
            print(f"wrote 33000 rows in {time.perf_counter() - t0:.3f} s")
        best = math.inf
        n = 0
        for _ in range(5):
            t0 = time.perf_counter()
            rec = read_record(path)
            best = min(best, time.perf_counter() - t0)
            n = rec.n
        print(f"{path}: {n} rows in {best * 1e3:.1f} ms (best of 5): {n / best:,.0f} rows/s")


if __name__ == "__main__":
    main()
