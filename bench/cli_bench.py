"""Wall time of a NEW ``chekan calibrate`` process on a 9 h record, first and second run.

    python bench/cli_bench.py [--seed 0] [--skip-bayes] [--fresh-cache]

Simulates the paper's 9 h record once with ``chekan simulate`` into a temporary folder, then
times ``python -m chekan.cli calibrate rec.csv --method map -q --json out.json`` twice as
subprocesses (and ``--method bayes`` twice unless ``--skip-bayes``): what a user waits for,
start-up, imports, tracing, compiling (or loading the persistent JAX cache) and the solve.
There is no reference tool; the goals of the issue "A calibration in seconds" (map ≤ 3 s,
bayes ≤ 15 s) are printed beside. Each row says whether the persistent JAX compilation cache
(``CHEKAN_JAX_CACHE``, see ``chekan/jaxconfig.py``) held entries before the run and how many
the run added (new entries: that run compiled), and the in-process seconds the result reports
(``diagnostics.seconds``: from the prepared record to the result), so that start-up and
tracing show as the difference. ``--fresh-cache`` points the subprocesses at an empty cache
(a truly cold first run; the second then shows the cache alone).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.table import Row, environment, environment_line, format_table

ROOT = Path(__file__).resolve().parents[1]
GOALS_S = {"map": 3.0, "bayes": 15.0}


def cache_dir(env: dict[str, str]) -> Path | None:
    """The persistent cache folder a ``chekan`` process started with ``env`` uses (``None``:
    disabled). Same rule as ``chekan/jaxconfig.py``, read without importing JAX."""
    value = env.get("CHEKAN_JAX_CACHE", "")
    if value == "0":
        return None
    if value and value != "1":
        return Path(value)
    base = env.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "chekan" / "jax"


def _entries(d: Path | None) -> int:
    if d is None or not d.is_dir():
        return 0
    return sum(1 for p in d.rglob("*") if p.is_file())  # XLA's entries and stored executables


def _env(extra: dict[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ)
    path = env.get("PYTHONPATH", "")
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + path if path else "")  # this checkout first
    env.update(extra or {})
    return env


def simulate(out: Path, seed: int, env: dict[str, str]) -> float:
    """``chekan simulate`` (the paper's 9 h program) into ``out``; seconds."""
    cmd = [sys.executable, "-m", "chekan.cli", "simulate", "-o", str(out), "--seed", str(seed)]
    t = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
    return time.perf_counter() - t


def timed_calibrate(rec: Path, method: str, out: Path, env: dict[str, str]) -> dict:
    """One ``chekan calibrate`` subprocess: wall seconds, the cache state, the result's own
    seconds and convergence."""
    cache = cache_dir(env)
    before = _entries(cache)
    cmd = [sys.executable, "-m", "chekan.cli", "calibrate", str(rec), "--method", method]
    cmd += ["-q", "--json", str(out)]
    t = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if proc.returncode not in (0, 3):  # 3: not converged with --strict (not used here)
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"chekan calibrate exited {proc.returncode}: {' | '.join(tail)}")
    diag = json.loads(out.read_text(encoding="utf-8")).get("diagnostics", {})
    return {
        "seconds": wall,
        "inprocess_seconds": diag.get("seconds"),
        "converged": diag.get("converged"),
        "ess_bulk_min": diag.get("ess_bulk_min"),
        "cache_dir": str(cache) if cache else None,
        "cache_entries_before": before,
        "cache_entries_added": _entries(cache) - before,
    }


def _cache_note(r: dict) -> str:
    if r["cache_dir"] is None:
        return "persistent cache off (CHEKAN_JAX_CACHE=0)"
    state = "warm" if r["cache_entries_before"] else "EMPTY (cold)"
    return (
        f"JAX cache {state}: {r['cache_entries_before']} entries before, "
        f"+{r['cache_entries_added']} added"
    )


def _row(method: str, k: int, r: dict) -> Row:
    goal = GOALS_S[method]
    note = _cache_note(r)
    if r["inprocess_seconds"] is not None:
        note += f"; result's own seconds {r['inprocess_seconds']:.1f}"
    if method == "bayes" and r["ess_bulk_min"] is not None:
        note += f"; min bulk ESS {r['ess_bulk_min']:.0f}, converged {r['converged']}"
    which = "first" if k == 0 else "second"
    return Row(
        f"`calibrate --method {method}` new process, {which} run (9 h)",
        f"{r['seconds']:.1f} s",
        f"goal ≤ {goal:g} s",
        note,
        {**r, "goal_seconds": goal},
    )


def run(seed: int = 0, skip_bayes: bool = False, fresh_cache: bool = False) -> list[Row]:
    """Measure the figures (see the module docstring); returns the rows."""
    rows: list[Row] = []
    with tempfile.TemporaryDirectory(prefix="chekan-bench-cli-") as tmp_name:
        tmp = Path(tmp_name)
        env = _env({"CHEKAN_JAX_CACHE": str(tmp / "jax-cache")} if fresh_cache else None)
        rec = tmp / "rec.csv"
        dt = simulate(rec, seed, env)
        rows.append(
            Row(
                "`chekan simulate` new process (9 h)",
                f"{dt:.1f} s",
                note="the record the CLI rows calibrate",
                values={"seconds": dt},
            )
        )
        for method in ("map",) if skip_bayes else ("map", "bayes"):
            for k in range(2):
                r = timed_calibrate(rec, method, tmp / f"{method}_{k}.json", env)
                rows.append(_row(method, k, r))
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog=__doc__.split("\n\n", 2)[2],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip-bayes", action="store_true", help="only --method map")
    ap.add_argument("--fresh-cache", action="store_true", help="an empty JAX cache")
    args = ap.parse_args(argv)
    env = environment()
    rows = run(args.seed, skip_bayes=args.skip_bayes, fresh_cache=args.fresh_cache)
    print(format_table(rows, "CLI bench (new processes)"))
    print(environment_line(env))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
