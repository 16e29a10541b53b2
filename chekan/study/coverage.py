"""Coverage and accuracy study on simulated sessions: ``python -m chekan.study``.

    python -m chekan.study --sessions 200 --out validation [--quick] [--jobs N]
                              [--cases typical misaligned drift slow edge]
                              [--methods classical map bayes] [--seed S] [--resume]

For each session an instrument is drawn at random (:func:`chekan.records.simulate.random_truth`,
or a hard case), a record of the tilt program is simulated, and each method estimates
b₁, b₂ and a:

- ``classical``: Calibr.exe's least squares (:mod:`chekan.classical.fit`), sd from its fit;
- ``map``: the joint model, MAP + Laplace (the posterior's likelihood), delta-method sds;
- ``bayes``: the posterior (:func:`chekan.pipeline.calibrate` with ``method="bayes"``,
  ``quick=True``) of a record written to a temporary file: 3–50 s per session (2 workers;
  the paper's 9 h program the least, the designer's 9 h xy program the most).

Intervals: the central interval mean ± z·sd at each level (50/90/95 %) for every method,
including ``bayes`` (its posterior mean and sd); for ``bayes`` the coverage of the stored
95 % HDI (``hdi_low``/``hdi_high`` of ``chekan-result/1``) is reported as well. An honest
interval at level L covers the truth in a binomially distributed number of sessions; the
band printed beside each coverage holds 99.9 % of that distribution (a coverage outside it
is flagged ``!``). Also: the RMS error against truth, the RMS of the stated sds and the
mean z² = mean((estimate − truth)/sd)², which is 1 when the stated uncertainty is honest.

Hard cases (``--cases``): ``misaligned`` (|ε| ≈ 8–10′, |Δγ| ≈ 15–20′), ``drift``
(±0.3 pix/h), ``slow`` (τ = 90 s damping lag), ``edge`` (a platform at the edge of its 3″
specification: the systematic angle error reaches 2.5–3″, periodic, scale, graduation or
mixed, with a random part of 0.3–0.8″), ``late_angles`` (the serial protocol's slowest
angle stream: the platform reports once a second at its own phase, and a row carries its
latest report, so the recorded angles are up to 1 s old — 1 800″ along a slew at 0.5°/s —
on a platform that moves continuously; ``Truth.platform_report_period_s``), ``continuous``
(the pendulums see the platform move within a sample — simulated at 0.1 s, the record
keeping each second's sample — where the model holds each sample's: ``Truth.motion_substeps``).
``--calibration-u-arcsec U``: every platform has its own angle calibration (a table every
5′ whose residual error has U at k = 2); ``--calibration-scale-u-arcsec S``: that residual
has a scale part S and the table states it (0: independent, stated as such).

Written into ``--out``: ``validation.csv`` (one row per session, appended as sessions
finish, so that ``--resume`` continues an interrupted study), ``validation.json`` (the
summary and settings), ``validation.md`` (the tables), ``coverage.png`` (nominal against
empirical coverage per case), ``z_hist.png`` (z-scores against N(0, 1) per case) and
``errors.png`` (error against truth, RMS error per case). Sessions are independent and
seeded by their index (``seed·100000 + i``), so the rows do not depend on ``--jobs``;
worker processes are spawned (JAX does not survive ``fork``) with one BLAS thread each.

The scenario and the sessions' instruments: :mod:`chekan.study.scenario`; the summary and
its report: :mod:`chekan.study.summary`; the figures: :mod:`chekan.study.plots`.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import os
import sys
import time
from collections.abc import Callable, Collection, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from chekan import argtypes
from chekan.options import METHODS
from chekan.study.scenario import (
    DEFAULT_SCENARIO,
    SEED_STRIDE,
    Scenario,
    session_calibration,
    session_truth,
)
from chekan.study.summary import (
    PARAMS,
    coverage_summary,
    format_summary,
    markdown_report,
    summary_groups,
)

CASES = (
    "typical",
    "misaligned",
    "drift",
    "slow",
    "edge",
    "late_angles",
    "continuous",
    "x_response",
    "horizontal",
)
X_CASES = ("x_response", "horizontal")  # cases that only programs with rounds about X run

DEFAULT_METHODS = ("classical", "map")
_INT_COLS = ("session", "seed")
_STR_COLS = ("case", "program")


def fieldnames(methods: Sequence[str] = DEFAULT_METHODS) -> list[str]:
    """Columns of ``validation.csv`` for these methods (fixed, so rows can be appended)."""
    cols = ["session", "case", "seed", "program"]
    cols += [f"true_{p}" for p in PARAMS]
    for m in methods:
        for p in PARAMS:
            cols += [f"{m}_{p}", f"{m}_{p}_sd"]
            if m == "map":
                cols.append(f"map_{p}_k")
            if m == "bayes":
                cols += [f"bayes_{p}_hdi_low", f"bayes_{p}_hdi_high"]
        if m == "map":
            cols.append("map_converged")
        cols += [f"{m}_seconds", f"{m}_error"]
    return cols


def _failed_columns(method: str, err: Exception) -> dict[str, Any]:
    """NaN estimates and the message of a method that raised."""
    out: dict[str, Any] = {f"{method}_error": f"{type(err).__name__}: {err}"[:300]}
    for p in PARAMS:
        out[f"{method}_{p}"] = out[f"{method}_{p}_sd"] = math.nan
        if method == "map":
            out[f"map_{p}_k"] = math.nan
        if method == "bayes":
            out[f"bayes_{p}_hdi_low"] = out[f"bayes_{p}_hdi_high"] = math.nan
    if method == "map":
        out["map_converged"] = False
    return out


def run_session(
    i: int,
    case: str,
    program,
    seed: int,
    settle_s: float,
    methods: Sequence[str] = DEFAULT_METHODS,
    scenario: Scenario = DEFAULT_SCENARIO,
) -> dict[str, Any]:
    """One simulated session through ``methods``; returns estimates, sds and truth.

    The classical fit always runs (it starts the MAP). A method that raises leaves NaN
    estimates and its message in ``<method>_error``; the other methods still run.
    """
    from chekan.classical.fit import calibrate_record
    from chekan.records.simulate import simulate_session

    rng = np.random.default_rng(seed)
    truth = session_truth(case, rng, i, scenario)
    rec, truth = simulate_session(program, truth, seed=seed)
    if scenario.calibration_u_arcsec is not None:  # corrected as the pipeline would
        from chekan.records.anglecal import corrected

        rec = corrected(
            rec,
            session_calibration(
                truth,
                program,
                seed,
                scenario.calibration_u_arcsec,
                scenario.calibration_scale_u_arcsec,
            ),
        )
    t = truth.derived()
    row: dict[str, Any] = {"session": i, "case": case, "seed": seed, "program": program.name}
    row.update({f"true_{p}": float(t[p]) for p in PARAMS})
    t0 = time.perf_counter()
    cres, _ = calibrate_record(rec, settle_s=settle_s)
    if "classical" in methods:
        row.update(
            classical_b1=float(cres.b_mean[0]),
            classical_b1_sd=float(cres.b_mean_sd[0]),
            classical_b2=float(cres.b_mean[1]),
            classical_b2_sd=float(cres.b_mean_sd[1]),
            classical_a=float(cres.a),
            classical_a_sd=float(cres.a_sd) if cres.a_sd is not None else math.nan,
            classical_seconds=time.perf_counter() - t0,
            classical_error="",
        )
    joint = (
        ("map", lambda: _map_columns(rec, settle_s, scenario)),
        ("bayes", lambda: _bayes_columns(rec, settle_s, seed, scenario)),
    )
    for method, columns in joint:
        if method not in methods:
            continue
        t0 = time.perf_counter()
        try:
            row.update(columns())
            row[f"{method}_error"] = ""
        except Exception as e:  # one failing session never stops a study
            row.update(_failed_columns(method, e))
        row[f"{method}_seconds"] = time.perf_counter() - t0
    return row


def _map_columns(rec, settle_s: float, scenario: Scenario) -> dict[str, Any]:
    """MAP + Laplace of the in-memory record through the public pipeline, with the
    coverage factor of each value's U (``map_<p>_k``: the certificate's)."""
    from chekan.pipeline import calibrate
    from chekan.report.expanded import coverage_factor_of, expanded_of

    opts = scenario.options(method="map", progress=False, settle_s=settle_s)
    result = calibrate(rec, opts)
    out: dict[str, Any] = {}
    for p in PARAMS:
        e = result["parameters"][p]
        out[f"map_{p}"], out[f"map_{p}_sd"] = float(e["mean"]), float(e["sd"])
        k = expanded_of(result, p)[1] if p in ("b1", "b2") else coverage_factor_of(result, p)
        out[f"map_{p}_k"] = float(k)
    out["map_converged"] = bool(result["diagnostics"]["converged"])
    return out


def _bayes_columns(rec, settle_s: float, seed: int, scenario: Scenario) -> dict[str, Any]:
    """The posterior of the in-memory record through the public pipeline."""
    from chekan.pipeline import calibrate

    opts = scenario.options(
        method="bayes", quick=True, progress=False, settle_s=settle_s, seed=seed
    )
    result = calibrate(rec, opts)
    out: dict[str, Any] = {}
    for p in PARAMS:
        e = result["parameters"].get(p, {})
        for key, col in (
            ("mean", ""),
            ("sd", "_sd"),
            ("hdi_low", "_hdi_low"),
            ("hdi_high", "_hdi_high"),
        ):
            v = e.get(key)
            out[f"bayes_{p}{col}"] = float(v) if v is not None else math.nan
    return out


def session_plan(n: int, cases: Sequence[str], seed: int) -> list[tuple[int, str, int]]:
    """``(index, case, session seed)`` of every session: cases in turn, seeds by index."""
    return [(i, cases[i % len(cases)], seed * SEED_STRIDE + i) for i in range(n)]


# ---------------------------------------------------------------------------- rows on disk
def parse_row(raw: dict[str, str]) -> dict[str, Any]:
    """A ``validation.csv`` row with its numbers as int or float64 (NaN where empty)."""
    row: dict[str, Any] = {}
    for k, v in raw.items():
        if k in _INT_COLS:
            row[k] = int(v)
        elif k in _STR_COLS or k.endswith("_error"):
            row[k] = v
        elif k.endswith("_converged"):
            row[k] = v == "True"
        else:
            row[k] = float(v) if v != "" else math.nan
    return row


def read_rows(path: str | os.PathLike, need: Collection[str] = ()) -> list[dict[str, Any]]:
    """Rows of a ``validation.csv`` with numbers as float64 (NaN for failures). A header
    without the columns ``need`` or a row that is not one is an error naming the file and
    its line; an incomplete last line (a study stopped mid-write) is left out with a
    warning."""
    import warnings

    from chekan.errors import ChekanError

    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        missing = set(need) - set(reader.fieldnames or ())
        if missing:
            raise ChekanError(
                f"{path}: line 1: not a validation.csv of python -m chekan.study "
                f"(no column {', '.join(sorted(missing))})"
            )
        lines = [(reader.line_num, raw) for raw in reader]
        width = len(reader.fieldnames or ())
    rows = []
    for k, (line, raw) in enumerate(lines):
        short = None in raw.values()
        if short and k == len(lines) - 1:
            warnings.warn(f"{path}: line {line}: incomplete last line left out", stacklevel=2)
            continue
        if short or None in raw:
            raise ChekanError(f"{path}: line {line}: not the header's {width} fields")
        try:
            rows.append(parse_row(raw))
        except ValueError as e:
            raise ChekanError(f"{path}: line {line}: {e}") from None
    return rows


def _resumable(path: Path, cols: list[str], plan, program_name: str) -> dict[int, dict]:
    """Rows of an earlier run that match the plan (same columns, case, seed, program)."""
    if not path.is_file():
        return {}
    with open(path, newline="", encoding="utf-8") as f:
        header = next(csv.reader(f), None)
    if header != cols:
        print(f"{path}: other columns (other --methods?); starting afresh")
        return {}
    want = {i: (case, s) for i, case, s in plan}
    keep = {}
    for r in read_rows(path):
        i = r["session"]
        if want.get(i) == (r["case"], r["seed"]) and r["program"] == program_name:
            keep[i] = r
    return keep


def _write_csv(path: Path, cols: list[str], rows: Iterable[dict]) -> None:
    tmp = path.with_suffix(".csv.tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        w.writerows(rows)
    tmp.replace(path)


def _run_sessions(
    plan: Sequence[tuple[int, str, int]],
    program,
    methods: Sequence[str],
    jobs: int,
    progress: bool,
    on_row: Callable[[dict], None],
    scenario: Scenario = DEFAULT_SCENARIO,
) -> None:
    """Run the planned sessions in this process (``jobs`` ≤ 1) or in spawned workers."""
    from tqdm.auto import tqdm

    settle = program.settle_s
    with tqdm(total=len(plan), desc="sessions", unit="session", disable=not progress) as bar:
        if jobs <= 1 or len(plan) <= 1:
            for i, case, s in plan:
                on_row(run_session(i, case, program, s, settle, methods, scenario))
                bar.update()
            return
        import concurrent.futures as cf
        import multiprocessing as mp

        from chekan.archive.reanalyze import configure_worker_env

        ctx = mp.get_context("spawn")  # JAX's threads do not survive fork
        with cf.ProcessPoolExecutor(
            max_workers=min(jobs, len(plan)), mp_context=ctx, initializer=configure_worker_env
        ) as ex:
            futs = [
                ex.submit(run_session, i, case, program, s, settle, methods, scenario)
                for i, case, s in plan
            ]
            for fut in cf.as_completed(futs):
                on_row(fut.result())
                bar.update()


# ---------------------------------------------------------------------------- the study
def run_study(
    n: int,
    out: str | os.PathLike,
    cases: Sequence[str] = ("typical",),
    quick: bool = False,
    seed: int = 0,
    progress: bool = True,
    *,
    methods: Sequence[str] = DEFAULT_METHODS,
    jobs: int = 1,
    program=None,
    resume: bool = False,
    figures: bool = True,
    command: str | None = None,
    scenario: Scenario = DEFAULT_SCENARIO,
) -> dict:
    """Run the study and write its files into ``out``; returns the summary.

    ``program``: a :class:`chekan.physics.program.TiltProgram` (default: the paper's 9 h program,
    or its 3 h variant with ``quick``). ``resume``: keep the rows of an earlier run in
    ``out/validation.csv`` that match this plan and run only the others. ``figures``: write
    the three PNG files (a few seconds). The summary holds
    ``all`` and one entry per case (each a :func:`coverage_summary`), ``settings``,
    ``seconds`` and ``paths`` (every file written).
    """
    from chekan.demo import demo_program
    from chekan.results.document import _clean  # NaN → None: JSON has no NaN

    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise ValueError(f"methods must be among {', '.join(METHODS)}, not {list(methods)}")
    methods = [m for m in METHODS if m in methods]
    if program is None:
        program = demo_program(quick)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "validation.csv"
    cols = fieldnames(methods)
    plan = session_plan(n, tuple(cases), seed)
    done = _resumable(csv_path, cols, plan, program.name) if resume else {}
    todo = [p for p in plan if p[0] not in done]
    t0 = time.perf_counter()
    _write_csv(csv_path, cols, done.values())  # rows appended as sessions finish
    with open(csv_path, "a", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=cols)

        def on_row(row: dict) -> None:
            done[row["session"]] = row
            writer.writerow(row)
            f.flush()

        _run_sessions(todo, program, methods, jobs, progress, on_row, scenario)
    rows = [done[i] for i, _, _ in plan]
    _write_csv(csv_path, cols, rows)  # sorted by session
    seconds = time.perf_counter() - t0

    summary: dict[str, Any] = {"all": coverage_summary(rows, methods)}
    for c in dict.fromkeys(cases):
        sub = [r for r in rows if r["case"] == c]
        if len(set(cases)) > 1 and sub:
            summary[c] = coverage_summary(sub, methods)
    settings = {
        "command": command or f"run_study({n}, {str(out)!r}, cases={tuple(cases)})",
        "sessions": n,
        "sessions_run": len(todo),
        "cases": list(dict.fromkeys(cases)),
        "methods": list(methods),
        "program": program.describe(),
        "program_name": program.name,
        "seed": seed,
        "jobs": jobs,
        "seconds": seconds,
        "mean_seconds": {
            m: float(np.nanmean([r[f"{m}_seconds"] for r in rows])) if rows else math.nan
            for m in methods
        },
        "failures": {m: sum(1 for r in rows if r.get(f"{m}_error")) for m in methods},
        "scenario": dataclasses.asdict(scenario),
    }
    if "map" in methods:
        settings["map_not_converged"] = sum(
            1 for r in rows if not r["map_converged"] and not r["map_error"]
        )
    summary["settings"] = settings
    summary["seconds"] = seconds
    pngs = []
    if figures:
        from chekan.study.plots import plot_coverage, plot_errors, plot_z

        pngs = [
            plot_coverage(summary, out / "coverage.png"),
            plot_z(rows, summary, methods, out / "z_hist.png"),
            plot_errors(rows, methods, out / "errors.png"),
        ]
    md = out / "validation.md"
    from chekan.files.durable import atomic_output

    with atomic_output(md) as f:
        f.write(markdown_report(summary, settings, pngs))
    js = out / "validation.json"
    summary["paths"] = [str(p) for p in (csv_path, js, md, *pngs)]
    with atomic_output(js) as f:
        f.write(json.dumps(_clean(summary), indent=2, allow_nan=False))
    return summary


# ---------------------------------------------------------------------------- command
def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m chekan.study",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 2)[2],
    )
    ap.add_argument(
        "--sessions", type=int, default=200, help="sessions in all, the cases in turn (default 200)"
    )
    ap.add_argument("-o", "--out", default="validation", help="folder for the files (created)")
    ap.add_argument(
        "--cases",
        nargs="+",
        choices=CASES,
        help="cases to run (default: all; x_response and horizontal only for programs with "
        "rounds about X)",
    )
    ap.add_argument(
        "--methods",
        nargs="+",
        choices=METHODS,
        default=list(DEFAULT_METHODS),
        help="estimators to compare (bayes: 3–50 s per session)",
    )
    ap.add_argument("--quick", action="store_true", help="3 h program instead of the paper's 9 h")
    ap.add_argument(
        "--systematic-arcsec",
        type=float,
        default=Scenario.systematic_arcsec,
        help="bound of the simulated systematic angle-sensor error (0: none; default 1.5)",
    )
    ap.add_argument("--shape", default="mixed", help="its shape (mixed, periodic, scale, …)")
    ap.add_argument(
        "--random-arcsec",
        type=float,
        nargs=2,
        metavar=("LO", "HI"),
        help="draw the random angle error's sd per session in [LO, HI] (default 2″)",
    )
    ap.add_argument(
        "--angle-errors",
        choices=("systematic", "independent"),
        default="systematic",
        help="the model's angle errors (default systematic)",
    )
    ap.add_argument("--angle-bound-arcsec", type=float, help="the model's sensor bound (3″)")
    ap.add_argument(
        "--angle-bound-reading",
        choices=("rectangular", "triangular"),
        default="rectangular",
        help="how the model reads the bound (default rectangular, GUM 4.3.7)",
    )
    ap.add_argument(
        "--calibration-u-arcsec",
        type=float,
        metavar="U",
        help="the platforms have their own angle calibration, residual U (k = 2) in arcsec",
    )
    ap.add_argument(
        "--calibration-scale-u-arcsec",
        type=float,
        metavar="S",
        help="with --calibration-u-arcsec: the tables' residual has a scale part S (k = 2, at "
        "the table's largest angle), the rest independent, and the table states S "
        "(0: independent residuals, stated as such)",
    )
    ap.add_argument(
        "--x-cubic",
        type=float,
        default=Scenario.x_cubic,
        metavar="C",
        help="x_response case: the odd unmodelled X response (1 − C)·sin θ + C·sin³ θ (0.3)",
    )
    ap.add_argument(
        "--horizontal-u-pix",
        type=argtypes.real(0.0, 2048.0, open_low=True),
        metavar="U",
        help="the model's standard uncertainty of the pendulums' horizontal (default 100 pix); "
        "the horizontal case's offsets stay within ±U",
    )
    ap.add_argument("--program", help="a tilt program file (TOML) instead of the paper's")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("-j", "--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--resume", action="store_true", help="keep matching rows of validation.csv")
    ap.add_argument(
        "-q",
        "--quiet",
        "--no-progress",
        dest="no_progress",
        action="store_true",
        help="no progress bar",
    )
    from chekan import __version__

    ap.add_argument("-V", "--version", action="version", version=f"chekan {__version__}")
    from chekan.files.outputs import run_command

    return run_command(_main, ap, argv, prog="python -m chekan.study")


def _main(ap: argparse.ArgumentParser, argv: Sequence[str] | None) -> int:
    args = ap.parse_args(argv)
    if args.sessions < 1:
        ap.error("--sessions must be at least 1")
    scale = args.calibration_scale_u_arcsec
    if scale is not None:
        if args.calibration_u_arcsec is None:
            ap.error("--calibration-scale-u-arcsec needs --calibration-u-arcsec (the table's U)")
        if not 0.0 <= scale <= args.calibration_u_arcsec:
            ap.error("--calibration-scale-u-arcsec must be in [0, U]: a part of the table's U")
    from chekan.files.outputs import FOLDER, Output, check_outputs

    out = Path(args.out)
    names = ("validation.csv", "validation.md", "validation.json", "coverage.png")
    files = [out / n for n in (*names, "z_hist.png", "errors.png")]
    check_outputs([args.program], [Output(out, writes=FOLDER), *files])
    program = None
    if args.program:
        from chekan.physics.program import load_program

        program = load_program(args.program)
    about_x = program is not None and "x" in program.tilt_axes
    cases = args.cases or [c for c in CASES if about_x or c not in X_CASES]
    s = run_study(
        args.sessions,
        Path(args.out),
        cases=tuple(cases),
        quick=args.quick,
        seed=args.seed,
        progress=not args.no_progress,
        methods=tuple(args.methods),
        jobs=args.jobs,
        program=program,
        resume=args.resume,
        command="python -m chekan.study " + " ".join(sys.argv[1:] if argv is None else argv),
        scenario=Scenario(
            systematic_arcsec=args.systematic_arcsec,
            shape=args.shape,
            random_arcsec=tuple(args.random_arcsec) if args.random_arcsec else None,
            angle_errors=args.angle_errors,
            angle_bound_arcsec=args.angle_bound_arcsec,
            calibration_u_arcsec=args.calibration_u_arcsec,
            calibration_scale_u_arcsec=args.calibration_scale_u_arcsec,
            angle_bound_reading=args.angle_bound_reading,
            x_cubic=args.x_cubic,
            horizontal_u_pix=args.horizontal_u_pix,
        ),
    )
    for key in summary_groups(s):
        print(f"\n== {key} ==")
        print(format_summary(s[key]))
    print(f"\n{s['settings']['program']}; {s['seconds']:.0f} s")
    for p in s["paths"]:
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
