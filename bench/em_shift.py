"""How far a change moves the MAP figures, checkout against checkout, on simulated sessions.

Made when one compiled EM replaced the host SciPy EM of ``map_solver="lm"``.
Run ``run`` once with each checkout on ``PYTHONPATH`` (from outside both,
so that the checkout is what gets imported), then ``compare``::

    git worktree add --detach /tmp/before-em main
    cd /tmp && PYTHONPATH=/tmp/before-em nice -n 10 python $REPO/bench/em_shift.py run before.json
    cd /tmp && PYTHONPATH=$REPO nice -n 10 python $REPO/bench/em_shift.py run after.json
    python $REPO/bench/em_shift.py compare before.json after.json

Sessions: ``--n`` drawn instruments (:func:`chekan.records.simulate.random_truth`, seed 1000 + i),
every fourth on the archive's one-round 20 min program (where EM creeps towards a bound),
the others on the 3 h demo program; each calibrated by ``map`` with every solver of
``--solvers``. ``compare`` prints, per solver, the largest |Δ mean| / sd of b₁ and b₂ and of
every parameter with an sd, and the largest relative change of an sd.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

B_NAMES = ("b1", "b2")


def session(i: int):
    """Simulated record ``i`` (seed 1000 + i) and its program's name."""
    from chekan.archive.synth import short_program
    from chekan.demo import demo_program
    from chekan.records.simulate import random_truth, simulate_session

    seed = 1000 + i
    short = i % 4 == 3
    program = short_program() if short else demo_program(quick=True)
    truth = random_truth(np.random.default_rng(seed), serial=f"SHIFT-{seed}")
    rec, _ = simulate_session(program, truth, seed=seed)
    return rec, "short" if short else "3h"


def run(out: Path, n: int, solvers: list[str]) -> None:
    """Calibrate ``n`` sessions by ``map`` with each solver; write their figures to ``out``."""
    from chekan.pipeline import CalibrationOptions, calibrate_file
    from chekan.records import write_record

    tmp = Path(tempfile.mkdtemp(prefix="em-shift-"))
    rows = []
    for i in range(n):
        rec, program = session(i)
        path = tmp / f"rec_{i}.csv"
        write_record(path, rec)
        row: dict = {"i": i, "program": program}
        for solver in solvers:
            opts = CalibrationOptions(method="map", progress=False, map_solver=solver)  # type: ignore[arg-type]
            r = calibrate_file(path, opts)
            row[solver] = {
                "converged": bool(r["diagnostics"]["converged"]),
                "parameters": {k: [p.get("mean"), p.get("sd")] for k, p in r["parameters"].items()},
            }
        rows.append(row)
        print(i, program, file=sys.stderr, flush=True)
    out.write_text(json.dumps({"rows": rows}, indent=0) + "\n")


def shifts(before: dict, after: dict, solver: str) -> dict:
    """Largest |Δ mean| / sd (b and all), largest relative Δ sd, sessions, where, non-converged."""
    worst: dict[str, tuple[float, str | None]] = {k: (0.0, None) for k in ("b", "all", "sd")}
    unconverged = 0
    for rb, ra in zip(before["rows"], after["rows"], strict=True):
        pb, pa = rb[solver]["parameters"], ra[solver]["parameters"]
        unconverged += (not rb[solver]["converged"]) + (not ra[solver]["converged"])
        for name, (mb, sb) in pb.items():
            ma, sa = pa[name]
            if not (sb and np.isfinite(sb) and sb > 0 and mb is not None and ma is not None):
                continue
            z = abs(ma - mb) / sb
            where = f"{rb['program']} #{rb['i']} {name}"
            if name in B_NAMES and z > worst["b"][0]:
                worst["b"] = (z, where)
            if z > worst["all"][0]:
                worst["all"] = (z, where)
            ds = abs(sa - sb) / sb
            if ds > worst["sd"][0]:
                worst["sd"] = (ds, where)
    return {"sessions": len(before["rows"]), "worst": worst, "unconverged": unconverged}


def compare(before_path: Path, after_path: Path) -> None:
    """Print the shift table (markdown) of ``after`` against ``before``."""
    before = json.loads(before_path.read_text())
    after = json.loads(after_path.read_text())
    solvers = [k for k in before["rows"][0] if k not in ("i", "program")]
    head = ["solver", "sessions", "max Δb / sd", "max Δmean / sd, any", "max Δsd / sd"]
    print("| " + " | ".join(head) + " |")
    print("|---" * len(head) + "|")
    for s in solvers:
        r = shifts(before, after, s)
        w = r["worst"]
        cells = [f"{w[k][0]:.2g} ({w[k][1]})" for k in ("b", "all", "sd")]
        print(f"| {s} | {r['sessions']} | " + " | ".join(cells) + " |")
        if r["unconverged"]:
            print(f"({s}: {r['unconverged']} fits not converged, before and after together)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="calibrate the sessions with the checkout on PYTHONPATH")
    r.add_argument("out", type=Path)
    r.add_argument("--n", type=int, default=100)
    r.add_argument("--solvers", default="lm,gn")
    c = sub.add_parser("compare", help="the shift of after against before")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    args = ap.parse_args(argv)
    if args.cmd == "run":
        run(args.out, args.n, args.solvers.split(","))
    else:
        compare(args.before, args.after)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
