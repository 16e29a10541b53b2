"""Coverage and accuracy study on simulated sessions: ``python -m chekan.validate``.

For each session an instrument is drawn at random (:func:`chekan.simulate.random_truth`,
or a hard case), a record is simulated, and both the classical method and the joint
model (MAP + Laplace, the same likelihood as the posterior) estimate b₁, b₂, a. Printed:
the empirical coverage of the central 50/90/95 % intervals with binomial bounds
(p < 1e-3), the RMS error against truth, and the mean z-score² (1 when the stated
uncertainty is honest). Written: ``validation.csv``, ``validation.json``, ``coverage.png``.

Hard cases (``--cases``): ``misaligned`` (|ε| ≈ 10′, |Δγ| ≈ 20′), ``drift``
(±0.3 pix/h), ``slow`` (τ = 90 s).
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np

CASES = ("typical", "misaligned", "drift", "slow")
LEVELS = (0.5, 0.9, 0.95)
PARAMS = ("b1", "b2", "a")


def _truth(case: str, rng: np.random.Generator, i: int):
    from chekan.simulate import random_truth

    kw = {}
    if case == "misaligned":
        kw = dict(
            eps_arcmin=tuple(rng.choice([-1, 1], 2) * rng.uniform(8, 10, 2)),
            dgamma_arcmin=float(rng.choice([-1, 1]) * rng.uniform(15, 20)),
        )
    elif case == "drift":
        kw = dict(drift_pix_per_h=tuple(rng.choice([-1, 1], 2) * 0.3))
    elif case == "slow":
        kw = dict(tau_s=90.0)
    return random_truth(rng, serial=f"V{i}", **kw)


def run_session(i: int, case: str, program, seed: int, settle_s: float) -> dict:
    """One simulated session through both methods; returns estimates, sds and truth."""
    from chekan import bayes
    from chekan.classical import calibrate_record
    from chekan.pipeline import CalibrationOptions
    from chekan.simulate import simulate_session

    rng = np.random.default_rng(seed)
    truth = _truth(case, rng, i)
    rec, truth = simulate_session(program, truth, seed=seed)
    t = truth.derived()
    row = {"session": i, "case": case, "seed": seed}
    cres, _ = calibrate_record(rec, settle_s=settle_s)
    row.update(
        classical_b1=cres.b_mean[0],
        classical_b1_sd=cres.b_mean_sd[0],
        classical_b2=cres.b_mean[1],
        classical_b2_sd=cres.b_mean_sd[1],
        classical_a=cres.a,
        classical_a_sd=cres.a_sd or np.nan,
    )
    opts = CalibrationOptions(method="map", settle_s=settle_s, progress=False)
    _, model, prob = bayes._setup(rec, cres, opts)
    res, h, _ = bayes.fit_map_em(prob, bayes._initial_values(cres, rec.g_local_mgal))
    md = bayes._map_derived(prob, res, h, {**model.data, "hyper": h})
    for p in PARAMS:
        row[f"map_{p}"], row[f"map_{p}_sd"] = md[p]
        row[f"true_{p}"] = t[p]
    row["map_converged"] = bool(res.converged)
    return row


def coverage_summary(rows: list[dict]) -> dict:
    """Coverage, RMS error and mean z² per method and parameter (Gaussian intervals)."""
    from scipy.stats import binom, norm

    out: dict = {}
    n = len(rows)
    for method in ("classical", "map"):
        for p in PARAMS:
            est = np.array([r[f"{method}_{p}"] for r in rows], float)
            sd = np.array([r[f"{method}_{p}_sd"] for r in rows], float)
            tr = np.array([r[f"true_{p}"] for r in rows], float)
            ok = np.isfinite(sd)
            if not ok.any():
                continue
            z = (est[ok] - tr[ok]) / sd[ok]
            entry = {
                "n": int(ok.sum()),
                "rms_error": float(np.sqrt(np.mean((est - tr) ** 2))),
                "mean_z2": float(np.mean(z**2)),
            }
            for lev in LEVELS:
                k = norm.ppf(0.5 + lev / 2)
                cov = float(np.mean(np.abs(z) <= k))
                lo, hi = binom.ppf([5e-4, 1 - 5e-4], ok.sum(), lev) / ok.sum()
                entry[f"coverage_{int(lev * 100)}"] = cov
                entry[f"bounds_{int(lev * 100)}"] = [float(lo), float(hi)]
            out[f"{method}/{p}"] = entry
    out["n_sessions"] = n
    return out


def format_summary(s: dict) -> str:
    head = (
        f"{'method/param':<16}{'n':>5}{'50 %':>8}{'90 %':>8}{'95 %':>8}"
        f"{'RMS error':>12}{'mean z²':>9}"
    )
    lines = [head, "-" * len(head)]
    for key, e in s.items():
        if not isinstance(e, dict):
            continue
        cells = []
        for lev in (50, 90, 95):
            lo, hi = e[f"bounds_{lev}"]
            flag = "" if lo <= e[f"coverage_{lev}"] <= hi else "!"
            cells.append(f"{e[f'coverage_{lev}']:>7.2f}{flag:1}")
        lines.append(
            f"{key:<16}{e['n']:>5}{''.join(cells)}{e['rms_error']:>12.3g}{e['mean_z2']:>9.2f}"
        )
    lines.append("! = outside the binomial 99.9 % band of an honest interval")
    return "\n".join(lines)


def run_study(
    n: int, out: Path, cases=("typical",), quick: bool = False, seed: int = 0, progress: bool = True
) -> dict:
    from tqdm import tqdm

    from chekan.demo import demo_program
    from chekan.program import default_program

    program = demo_program(True) if quick else default_program()
    settle = program.settle_s
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    t0 = time.perf_counter()
    jobs = [(i, cases[i % len(cases)]) for i in range(n)]
    for i, case in tqdm(jobs, disable=not progress, desc="sessions"):
        rows.append(run_session(i, case, program, seed * 100_000 + i, settle))
    summary = {"all": coverage_summary(rows)}
    for c in cases:
        sub = [r for r in rows if r["case"] == c]
        if len(cases) > 1 and sub:
            summary[c] = coverage_summary(sub)
    summary["seconds"] = time.perf_counter() - t0
    with open(out / "validation.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (out / "validation.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    _plot(rows, out / "coverage.png")
    return summary


def _plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.5))
    for ax, p in zip(axes, PARAMS, strict=True):
        for method, color in (("classical", "tab:orange"), ("map", "tab:blue")):
            z = np.array(
                [(r[f"{method}_{p}"] - r[f"true_{p}"]) / r[f"{method}_{p}_sd"] for r in rows], float
            )
            z = z[np.isfinite(z)]
            if z.size:
                ax.hist(
                    np.clip(z, -6, 6),
                    bins=24,
                    range=(-6, 6),
                    alpha=0.5,
                    color=color,
                    density=True,
                    label=method,
                )
        x = np.linspace(-6, 6, 200)
        ax.plot(x, np.exp(-x * x / 2) / np.sqrt(2 * np.pi), "k-", lw=1, label="N(0, 1)")
        ax.set_title(f"z = (estimate − truth)/sd, {p}")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m chekan.validate", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("--sessions", type=int, default=200)
    ap.add_argument("--out", default="validation")
    ap.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES))
    ap.add_argument("--quick", action="store_true", help="3 h program instead of the paper's 9 h")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    s = run_study(
        args.sessions, Path(args.out), cases=tuple(args.cases), quick=args.quick, seed=args.seed
    )
    for key, sub in s.items():
        if isinstance(sub, dict):
            print(f"\n== {key} ==")
            print(format_summary(sub))
    print(
        f"\nwrote {args.out}/validation.csv, validation.json, coverage.png ({s['seconds']:.0f} s)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
