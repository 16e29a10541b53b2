"""The classical items from raw and from settled hold means, on simulated platforms.

Made for the unsettled hold means of the designer's programs (``chekan/classical/settling.py``).
Each
session draws a platform of the validation's cases (:func:`chekan.study.scenario.session_truth`,
τ drawn by :func:`chekan.records.simulate.random_truth`, 90 s in ``slow``) and is calibrated by
``map`` under both programs (the designer's best, ``docs/figures/program_design_xy.toml``,
and the paper's). Printed per program and case: the transient left in the hold means, the
RMS error of the classical b₁, b₂ from the raw hold means (Calibr.exe) and from the settled
ones beside the joint b, and the largest reduced error both ways::

    python bench/settled_items.py --sessions 10 --jobs 2 --out docs/figures/settled_items.md
"""

from __future__ import annotations

import argparse
import json
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

CASES = ("typical", "slow", "edge", "x_response")
PROGRAMS = ("xy", "paper")
XY_PROGRAM = Path(__file__).resolve().parents[1] / "docs" / "figures" / "program_design_xy.toml"


def session(job: tuple[str, str, int]) -> dict:
    """One simulated session of ``(program, case, i)`` and its classical items both ways:
    relative errors of b₁, b₂ in ppm, reduced errors in %."""
    from chekan.options import CalibrationOptions
    from chekan.physics.program import default_program, load_program
    from chekan.pipeline import calibrate
    from chekan.records.simulate import simulate_session
    from chekan.study.scenario import DEFAULT_SCENARIO, session_truth

    prog_name, case, i = job
    warnings.simplefilter("ignore")
    program = load_program(XY_PROGRAM) if prog_name == "xy" else default_program()
    truth = session_truth(case, np.random.default_rng([i, 77]), i, DEFAULT_SCENARIO)
    rec, truth = simulate_session(program, truth, seed=1000 + i)
    opts: CalibrationOptions = DEFAULT_SCENARIO.options(method="map", progress=False)
    res = calibrate(rec, opts)
    true_b = np.asarray(truth.b_mgal_per_pix, dtype=float)
    ht = res.get("hold_transient") or {}
    raw = ht.get("calibr_exe") or {**res["classical"], **res}

    def ppm(entry: dict) -> list[float]:
        b = np.array([entry[k]["mean"] for k in ("b1", "b2")])
        return list((b / true_b - 1.0) * 1e6)

    return {
        "program": prog_name,
        "case": case,
        "i": i,
        "tau_s": truth.tau_s,
        "transient_pix": float(ht.get("max_pix", 0.0)),
        "raw_ppm": ppm(raw),
        "settled_ppm": ppm(res["classical"]),
        "joint_ppm": ppm(res["parameters"]),
        "reduced_raw_percent": float(raw["reduced_error_percent"]),
        "reduced_percent": float(res["reduced_error_percent"]),
    }


def table(rows: list[dict]) -> str:
    """The markdown table: per program and case."""
    out = [
        "| program | case | sessions | transient left, pix | RMS error of classical b₁, b₂ "
        "(ppm): raw / settled | joint b₁, b₂ (ppm) | largest reduced error (%): raw / "
        "settled |",
        "|---|---|---|---|---|---|---|",
    ]
    for prog in PROGRAMS:
        for case in CASES:
            sel = [r for r in rows if r["program"] == prog and r["case"] == case]
            if not sel:
                continue

            def rms(key: str, sel: list[dict] = sel) -> str:
                return f"{float(np.sqrt(np.mean(np.square([r[key] for r in sel])))):.0f}"

            left = [r["transient_pix"] for r in sel]
            out.append(
                f"| {prog} | {case} | {len(sel)} | {min(left):.2g}–{max(left):.3g} | "
                f"{rms('raw_ppm')} / {rms('settled_ppm')} | {rms('joint_ppm')} | "
                f"{max(r['reduced_raw_percent'] for r in sel):.3f} / "
                f"{max(r['reduced_percent'] for r in sel):.3f} |"
            )
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sessions", type=int, default=10, help="sessions per program and case")
    p.add_argument("--jobs", type=int, default=2, help="worker processes")
    p.add_argument("--out", type=Path, help="also write the table (markdown) here")
    p.add_argument("--json", type=Path, help="also write every session's figures here")
    args = p.parse_args(argv)
    jobs = [(p_, c, i) for p_ in PROGRAMS for c in CASES for i in range(args.sessions)]
    rows = []
    with ProcessPoolExecutor(args.jobs) as ex:
        for k, row in enumerate(ex.map(session, jobs), 1):
            rows.append(row)
            print(f"{k}/{len(jobs)} {row['program']} {row['case']} {row['i']}", flush=True)
    text = table(rows)
    print(text)
    if args.out:
        args.out.write_text(text, encoding="utf-8")
        print(f"wrote {args.out}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1), encoding="utf-8")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
