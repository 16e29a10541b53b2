"""Write ``snapshot.json``: classical and MAP results on 10 fixed simulated records and the
paper's protocol, the reference that a behaviour-unchanged refactor must reproduce (1e-6)
(``tests/test_regression_snapshot.py``).

    python tests/data/regression/make_snapshot.py   # only when a change is *meant* to move them
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
PROTOCOL = HERE.parents[2] / "examples" / "calibr_46_protocol.csv"
SEEDS = tuple(range(500, 510))


def numbers(result: dict) -> dict[str, float]:
    """The figures a calibration reports, flattened: parameter means and sds, the budget."""
    out: dict[str, float] = {}
    for name, p in result.get("parameters", {}).items():
        for key in ("mean", "sd"):
            v = p.get(key)
            if isinstance(v, int | float) and v is not None and np.isfinite(v):
                out[f"{name}.{key}"] = float(v)
    for name, e in (result.get("uncertainty_budget") or {}).items():
        for key, v in e.items():
            if isinstance(v, int | float) and v is not None:
                out[f"budget.{name}.{key}"] = float(v)
    return out


def records():
    """(label, record path) of the 10 fixed sessions (3 h program, drawn instruments)."""
    from chekan.demo import demo_program
    from chekan.records import write_record
    from chekan.records.simulate import random_truth, simulate_session

    tmp = Path(tempfile.mkdtemp(prefix="chekan-snapshot-"))
    for seed in SEEDS:
        truth = random_truth(
            np.random.default_rng(seed), serial=f"SNAP-{seed}", angle_systematic_arcsec=0.0
        )
        rec, _ = simulate_session(demo_program(quick=True), truth, seed=seed)
        path = tmp / f"rec_{seed}.csv"
        write_record(path, rec)
        yield f"sim{seed}", path


def snapshot(map_solver: str = "lm") -> dict[str, dict[str, float]]:
    """The figures now; ``map_solver`` "lm" is the MAP solver the snapshot was taken with
    (0.3 made Gauss–Newton the default: tests/test_regression_snapshot.py compares both;
    since issue 28 both run the same compiled EM between passes)."""
    from chekan.pipeline import CalibrationOptions, calibrate_file

    out: dict[str, dict[str, float]] = {}
    inputs = [*records(), ("paper46", PROTOCOL)]
    for label, path in inputs:
        for method in ("classical", "map"):
            # the model before systematic angle errors (the redesign kept it as an option)
            opts = CalibrationOptions(
                method=method,
                progress=False,
                angle_errors="independent",
                map_solver=map_solver,
            )
            out[f"{label}.{method}"] = numbers(calibrate_file(path, opts))
            print(label, method, file=sys.stderr)
    return out


if __name__ == "__main__":
    (HERE / "snapshot.json").write_text(json.dumps(snapshot(), indent=1, sort_keys=True) + "\n")
    print(f"wrote {HERE / 'snapshot.json'}")
