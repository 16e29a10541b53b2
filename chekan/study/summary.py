"""The summary of a validation study (:mod:`chekan.study.coverage`): coverage of the stated
intervals against truth with the binomial band of an honest interval, RMS error, mean z²,
and the markdown report."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from chekan.options import METHODS
from chekan.physics.parameters import unit_of
from chekan.study.scenario import SEED_STRIDE, scenario_line

LEVELS = (0.5, 0.9, 0.95)
PARAMS = ("b1", "b2", "a")
BAND_PROB = 0.999  # probability mass of the binomial band of an honest interval
P_U = 0.9545  # the coverage probability of a stated U (k = 2 for a normal distribution)


def methods_in(rows: Sequence[dict]) -> list[str]:
    """The methods that have estimate columns in ``rows``."""
    return [m for m in METHODS if rows and f"{m}_b1" in rows[0]]


def binomial_band(n: int, level: float, prob: float = BAND_PROB) -> tuple[float, float]:
    """Central ``prob`` band of the coverage fraction of an honest ``level`` interval in n."""
    from scipy.stats import binom

    if n <= 0:
        return (math.nan, math.nan)
    lo, hi = binom.ppf([(1 - prob) / 2, (1 + prob) / 2], n, level) / n
    return float(lo), float(hi)


def coverage_summary(rows: Sequence[dict], methods: Sequence[str] | None = None) -> dict:
    """Coverage, RMS error and mean z² per method and parameter.

    Per ``"<method>/<param>"``: ``n`` (sessions with a finite estimate and sd),
    ``coverage_<L>`` (fraction with |z| ≤ z_L, z = (estimate − truth)/sd, z_L the
    two-sided normal quantile of L), ``bounds_<L>`` (:func:`binomial_band`), ``rms_error``,
    ``bias`` (mean error), ``rms_sd`` (RMS of the stated sds), ``mean_z2``; for ``bayes``
    also ``coverage_hdi95`` (truth inside the stored 95 % HDI); where the rows carry the
    method's coverage factor (``map_<p>_k``), ``coverage_U`` (|z| ≤ k: the stated U covers,
    nominal ``P_U`` = 95.45 %) and ``bounds_U``. ``n_sessions``: all rows.
    """
    from scipy.special import ndtri

    out: dict[str, Any] = {}
    for method in methods if methods is not None else methods_in(rows):
        for p in PARAMS:
            est = np.array([r[f"{method}_{p}"] for r in rows], dtype=np.float64)
            sd = np.array([r[f"{method}_{p}_sd"] for r in rows], dtype=np.float64)
            tr = np.array([r[f"true_{p}"] for r in rows], dtype=np.float64)
            ok = np.isfinite(est) & np.isfinite(sd) & (sd > 0)
            if not ok.any():
                continue
            err = est[ok] - tr[ok]
            z = err / sd[ok]
            n = int(ok.sum())
            entry: dict[str, Any] = {
                "n": n,
                "rms_error": float(np.sqrt(np.mean(err**2))),
                "bias": float(np.mean(err)),
                "rms_sd": float(np.sqrt(np.mean(sd[ok] ** 2))),
                "mean_z2": float(np.mean(z**2)),
            }
            for lev in LEVELS:
                k = float(ndtri(0.5 + lev / 2))
                entry[f"coverage_{round(lev * 100)}"] = float(np.mean(np.abs(z) <= k))
                entry[f"bounds_{round(lev * 100)}"] = list(binomial_band(n, lev))
            if rows and f"{method}_{p}_k" in rows[0]:
                kk = np.array([r[f"{method}_{p}_k"] for r in rows], dtype=np.float64)[ok]
                if np.all(np.isfinite(kk)):
                    entry["coverage_U"] = float(np.mean(np.abs(z) <= kk))
                    entry["bounds_U"] = list(binomial_band(n, P_U))
                    entry["mean_k"] = float(np.mean(kk))
            if method == "bayes":
                lo = np.array([r["bayes_" + p + "_hdi_low"] for r in rows], np.float64)[ok]
                hi = np.array([r["bayes_" + p + "_hdi_high"] for r in rows], np.float64)[ok]
                inside = (lo <= tr[ok]) & (tr[ok] <= hi)
                entry["coverage_hdi95"] = float(np.mean(inside))
            out[f"{method}/{p}"] = entry
    out["n_sessions"] = len(rows)
    return out


def _outside(e: dict, lev: int | str) -> bool:
    lo, hi = e[f"bounds_{lev}"]
    return not lo <= e[f"coverage_{lev}"] <= hi


def _u_cell(e: dict) -> str:
    """The stated U's coverage for the text table (``!`` outside its band), — where the
    method states no k."""
    if "coverage_U" not in e:
        return f"{'—':>7} "
    return f"{e['coverage_U']:>7.2f}" + ("!" if _outside(e, "U") else " ")


def format_summary(s: dict) -> str:
    """A plain-text table of one :func:`coverage_summary`."""
    head = (
        f"{'method/param':<16}{'n':>5}{'50 %':>8}{'90 %':>8}{'95 %':>8}{'U (k)':>8}"
        f"{'RMS error':>12}{'RMS sd':>11}{'mean z²':>9}"
    )
    lines = [head, "-" * len(head)]
    for key, e in s.items():
        if not isinstance(e, dict):
            continue
        cells = "".join(
            f"{e[f'coverage_{lev}']:>7.2f}{'!' if _outside(e, lev) else ' '}"
            for lev in (50, 90, 95)
        )
        lines.append(
            f"{key:<16}{e['n']:>5}{cells}{_u_cell(e)}{e['rms_error']:>12.3g}"
            f"{e['rms_sd']:>11.3g}{e['mean_z2']:>9.2f}"
        )
    lines.append(f"! = outside the binomial {BAND_PROB * 100:.1f} % band of an honest interval")
    lines.append(f"U (k): the stated U = k·sd covers (nominal {P_U * 100:.2f} %)")
    return "\n".join(lines)


def summary_groups(summary: dict) -> list[str]:
    """The keys of the summary's groups (per case and overall), in order."""
    return [k for k, v in summary.items() if isinstance(v, dict) and "n_sessions" in v]


def markdown_report(summary: dict, settings: dict, figures: Sequence[str | Path] = ()) -> str:
    """``validation.md``: settings, the honest-interval bands, one table per case and overall."""
    st = settings
    cases = ", ".join(st["cases"]) + (" in turn" if len(st["cases"]) > 1 else "")
    lines = [
        "# Coverage and accuracy on simulated sessions",
        "",
        f"`{st['command']}`",
        "",
        "| setting | value |",
        "|---|---|",
        f"| sessions | {st['sessions']} ({cases}) |",
        f"| methods | {', '.join(st['methods'])} |",
        f"| program | {st['program']} |",
        f"| seed | {st['seed']} (session i: seed·{SEED_STRIDE} + i) |",
        f"| worker processes | {st['jobs']} |",
        f"| angle sensor (simulated; model) | {scenario_line(st.get('scenario'))} |",
        f"| seconds | {st['seconds']:.0f} wall ({st['sessions_run']} sessions run now, "
        f"{st['sessions'] - st['sessions_run']} taken from an earlier run) |",
    ]
    for m in st["methods"]:
        lines.append(
            f"| {m}: mean seconds per session, failures | "
            f"{st['mean_seconds'].get(m, math.nan):.2f}, {st['failures'].get(m, 0)} |"
        )
    if "map_not_converged" in st:
        lines.append(
            f"| map: sessions not converged (kept in the tables) | {st['map_not_converged']} |"
        )
    lines += [
        "",
        "Intervals are central, estimate ± z·sd with z the two-sided normal quantile of the "
        "level; for `bayes` the estimate and sd are the posterior mean and sd, and the column "
        "*95 % HDI* is the coverage of the stored highest-density interval. "
        f"*U (k)* is the coverage of the stated expanded uncertainty U = k·sd (nominal "
        f"{P_U * 100:.2f} %; `map`: k = t₉₅.₄₅(ν_eff), GUM G.4), *mean k* its mean k. "
        "An honest interval at level L covers the truth in a binomial number of the n "
        f"sessions: the coverage falls in the band below with probability {BAND_PROB * 100:.1f} %; "
        "a coverage outside it is **bold** with `!`. "
        "mean z² = mean((estimate − truth)/sd)² is 1 for an honest sd; "
        "RMS sd is the RMS of the stated sds (≈ RMS error when honest).",
        "",
    ]
    for g in summary_groups(summary):
        s = summary[g]
        entries = {k: v for k, v in s.items() if isinstance(v, dict)}
        lines += [f"## {g} ({s['n_sessions']} sessions)", ""]
        if not entries:
            lines += ["no estimates", ""]
            continue
        n0 = next(iter(entries.values()))["n"]
        band = ", ".join(
            f"{lev} %: [{b[0]:.2f}, {b[1]:.2f}]"
            for lev in (50, 90, 95)
            for b in [binomial_band(n0, lev / 100)]
        )
        with_hdi = any("coverage_hdi95" in e for e in entries.values())
        with_u = any("coverage_U" in e for e in entries.values())
        if with_u:
            b = binomial_band(n0, P_U)
            band += f", U ({P_U * 100:.2f} %): [{b[0]:.2f}, {b[1]:.2f}]"
        lines += [
            f"Honest band for n = {n0}: {band}.",
            "",
            "| method | parameter | n | 50 % | 90 % | 95 % |"
            + (" 95 % HDI |" if with_hdi else "")
            + (" U (k) | mean k |" if with_u else "")
            + " RMS error | bias | RMS sd | mean z² |",
            "|---|---|" + "--:|" * (8 + with_hdi + 2 * with_u),
        ]
        for key, e in entries.items():
            method, p = key.split("/")
            cov = []
            for lev in (50, 90, 95):
                c = f"{e[f'coverage_{lev}']:.3f}"
                cov.append(f"**{c}** !" if _outside(e, lev) else c)
            if with_hdi:
                cov.append(f"{e['coverage_hdi95']:.3f}" if "coverage_hdi95" in e else "—")
            if with_u and "coverage_U" in e:
                c = f"{e['coverage_U']:.3f}"
                cov += [f"**{c}** !" if _outside(e, "U") else c, f"{e['mean_k']:.3f}"]
            elif with_u:
                cov += ["—", "—"]
            lines.append(
                f"| {method} | {p} ({unit_of(p)}) | {e['n']} | {' | '.join(cov)} "
                f"| {e['rms_error']:.3g} | {e['bias']:.3g} | {e['rms_sd']:.3g} "
                f"| {e['mean_z2']:.3g} |"
            )
        lines.append("")
    if figures:
        lines += ["## Figures", ""]
        lines += [f"![{Path(f).stem}]({Path(f).name})" for f in figures]
        lines.append("")
    return "\n".join(lines)
