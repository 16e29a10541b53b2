"""What a gap in a record costs: MAP on sessions cut at places of every kind, beside the
whole session's estimate, on records the joint model did not generate.

    python -m bench.gaps_study [SEED ...]      (default seeds 3 4; about 3 min on 2 cores warm)
    python -m bench.gaps_study --random N [SEED ...]   (N cuts at random places per session)

The program rounds about both axes (2°30′, 4°00′, 5°10′; 4 rounds of 300 s dwells), the
platform's angle sensors at the edge of their specification (a systematic error up to the
3″ bound, mixed shapes), the platform moving continuously between the samples and its angle
reports up to a second late (effects the model leaves out). Each session is calibrated
whole and with a stretch lost: across a slew and a whole hold, in a slew, at the start of a
hold and inside a hold. Printed per session and cut: z = (b − b_true)/sd of both systems and
the sd beside the whole session's. ``--random N``: N stretches of 20–400 s lost at random
times (uniform over the record) per session instead, and the summary: the largest |z|, the
mean z² and the largest sd beside the whole session's.
"""

from __future__ import annotations

import sys
import warnings

import numpy as np


def cut(rec, t_from: float, t_to: float):
    """``rec`` without its samples at t_from ≤ t ≤ t_to."""
    return rec.rows((rec.t_s < t_from) | (rec.t_s > t_to))


def session(seed: int):
    """(record, truth) of one session (module docstring)."""
    from chekan.physics.program import build_program
    from chekan.records.simulate import Truth, simulate_session

    prog = build_program([2.5, 4.0, 5 + 10 / 60], axis="xy", rounds=4, dwell_s=300, settle_s=120)
    truth = Truth(
        serial="GAPS",
        angle_systematic_arcsec=3.0,
        motion_substeps=10,
        platform_report_period_s=1.0,
    )
    return simulate_session(prog, truth, seed=seed)


def study(seed: int, n_random: int = 0) -> list[tuple[str, float, float, float, float, bool]]:
    """(cut, z₁, z₂, sd₁/sd₁ whole, sd₂/sd₂ whole, converged) for one session: the cuts of
    every kind, or ``n_random`` cuts at random places."""
    from chekan.pipeline import CalibrationOptions, calibrate

    rec, truth = session(seed)
    steps = np.unique(rec.step[rec.step >= 0])
    hold = {
        int(s): (float(rec.t_s[rec.step == s][0]), float(rec.t_s[rec.step == s][-1])) for s in steps
    }
    cuts = {
        "whole": None,
        "a slew and a hold": (hold[9][1] - 12.0, hold[11][0] + 43.0),
        "a slew": (hold[5][1] + 2.0, hold[6][0] + 3.0),
        "a hold's start": (hold[14][0] - 1.0, hold[14][0] + 100.0),
        "inside a hold": (hold[20][0] + 150.0, hold[20][0] + 200.0),
    }
    if n_random:
        rng = np.random.default_rng(seed)
        t_end = float(rec.t_s[-1])
        cuts = {"whole": None}
        for _ in range(n_random):
            length = float(rng.uniform(20.0, 400.0))
            t0 = float(rng.uniform(0.0, t_end - length))
            cuts[f"{t0:.0f}–{t0 + length:.0f} s"] = (t0, t0 + length)
    rows, whole = [], None
    opts = CalibrationOptions(method="map", progress=False)
    for name, span in cuts.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = calibrate(rec if span is None else cut(rec, *span), opts)
        p = res["parameters"]
        whole = whole or p
        z = [(p[f"b{j}"]["mean"] - truth.b_mgal_per_pix[j - 1]) / p[f"b{j}"]["sd"] for j in (1, 2)]
        r = [p[f"b{j}"]["sd"] / whole[f"b{j}"]["sd"] for j in (1, 2)]
        rows.append((name, z[0], z[1], r[0], r[1], bool(res["diagnostics"]["converged"])))
    return rows


def main(argv: list[str]) -> int:
    n_random = 0
    if argv[:1] == ["--random"]:
        n_random, argv = int(argv[1]), argv[2:]
    seeds = [int(a) for a in argv] or [3, 4]
    print(f"{'seed':>4}  {'cut':18s} {'z1':>6} {'z2':>6} {'sd1/whole':>9} {'sd2/whole':>9} conv")
    z, ratio = [], []
    for seed in seeds:
        for name, z1, z2, r1, r2, conv in study(seed, n_random):
            print(
                f"{seed:>4}  {name:18s} {z1:+6.2f} {z2:+6.2f} {r1:9.2f} {r2:9.2f} {conv}",
                flush=True,
            )
            if name != "whole":
                z += [z1, z2]
                ratio += [r1, r2]
    if z:
        za = np.asarray(z)
        print(
            f"{len(z) // 2} cuts: largest |z| {np.max(np.abs(za)):.2f}, mean z² "
            f"{np.mean(za**2):.2f}, sd beside the whole session's up to {max(ratio):.2f}×"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
