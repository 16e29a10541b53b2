"""Figures of the validation study (:mod:`chekan.study.coverage`): coverage, z-scores, errors."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from chekan.physics.parameters import unit_of
from chekan.report.plotting import new_figure
from chekan.study.summary import BAND_PROB, LEVELS, PARAMS, summary_groups

_COLORS = {"classical": "tab:orange", "map": "tab:blue", "bayes": "tab:green"}
_MARKERS = {"typical": "o", "misaligned": "s", "drift": "^", "slow": "v"}


def plot_coverage(summary: dict, path: Path) -> Path:
    """Nominal against empirical coverage per group (rows) and parameter (columns)."""
    groups = summary_groups(summary)
    fig = new_figure((4 * len(PARAMS), 3 * len(groups)))
    axes = fig.subplots(len(groups), len(PARAMS), squeeze=False)
    levels = np.array(LEVELS) * 100
    for gi, g in enumerate(groups):
        s = summary[g]
        for pi, p in enumerate(PARAMS):
            ax = axes[gi, pi]
            ax.plot([45, 100], [0.45, 1.0], "k:", lw=1, label="nominal")
            entries = [(k.split("/")[0], e) for k, e in s.items() if k.endswith(f"/{p}")]
            for mi, (m, e) in enumerate(entries):
                lo_hi = np.array([e[f"bounds_{round(lev)}"] for lev in levels])
                if mi == 0:  # one band per group: n is the same for every method
                    for lev, (lo, hi) in zip(levels, lo_hi, strict=True):
                        ax.fill_between(
                            [lev - 1.5, lev + 1.5], lo, hi, color="0.85", lw=0, zorder=0
                        )
                cov = [e[f"coverage_{round(lev)}"] for lev in levels]
                x = levels + (mi - (len(entries) - 1) / 2) * 0.8
                ax.plot(x, cov, "o-", color=_COLORS[m], label=m, ms=5)
            ax.set_xlim(45, 100)
            ax.set_ylim(-0.02, 1.02)
            ax.set_title(f"{g}: {p} (n = {s['n_sessions']})", fontsize=9)
            if gi == len(groups) - 1:
                ax.set_xlabel("nominal level, %")
            if pi == 0:
                ax.set_ylabel("empirical coverage")
            if gi == 0 and pi == 0:
                ax.legend(fontsize=7, loc="lower right")
    fig.suptitle(
        f"coverage of central intervals; grey: {BAND_PROB * 100:.1f} % band of an honest interval",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def _z(rows: Sequence[dict], m: str, p: str) -> np.ndarray:
    z = np.array(
        [(r[f"{m}_{p}"] - r[f"true_{p}"]) / r[f"{m}_{p}_sd"] for r in rows], dtype=np.float64
    )
    return z[np.isfinite(z)]


def plot_z(rows: Sequence[dict], summary: dict, methods: Sequence[str], path: Path) -> Path:
    """Histograms of z = (estimate − truth)/sd against N(0, 1), per group and parameter."""
    groups = summary_groups(summary)
    fig = new_figure((4 * len(PARAMS), 2.8 * len(groups)))
    axes = fig.subplots(len(groups), len(PARAMS), squeeze=False)
    x = np.linspace(-6, 6, 200)
    for gi, g in enumerate(groups):
        sub = rows if g == "all" else [r for r in rows if r["case"] == g]
        for pi, p in enumerate(PARAMS):
            ax = axes[gi, pi]
            for m in methods:
                z = _z(sub, m, p)
                if z.size:
                    ax.hist(
                        np.clip(z, -6, 6),
                        bins=24,
                        range=(-6, 6),
                        alpha=0.45,
                        color=_COLORS[m],
                        density=True,
                        label=m,
                    )
            ax.plot(x, np.exp(-x * x / 2) / np.sqrt(2 * np.pi), "k-", lw=1, label="N(0, 1)")
            ax.set_title(f"{g}: z of {p} (clipped to ±6)", fontsize=9)
            if gi == 0 and pi == 0:
                ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def plot_errors(rows: Sequence[dict], methods: Sequence[str], path: Path) -> Path:
    """Top: estimate − truth against truth (colour: method, marker: case).
    Bottom: RMS error per case and method (log scale)."""
    cases = list(dict.fromkeys(r["case"] for r in rows))
    fig = new_figure((4.2 * len(PARAMS), 7))
    axes = fig.subplots(2, len(PARAMS), squeeze=False)
    width = 0.8 / max(len(methods), 1)
    for pi, p in enumerate(PARAMS):
        ax = axes[0, pi]
        for m in methods:
            for c in cases:
                sub = [r for r in rows if r["case"] == c]
                tr = np.array([r[f"true_{p}"] for r in sub], dtype=np.float64)
                err = np.array([r[f"{m}_{p}"] for r in sub], dtype=np.float64) - tr
                ax.scatter(
                    tr,
                    err,
                    s=12,
                    alpha=0.7,
                    color=_COLORS[m],
                    marker=_MARKERS.get(c, "o"),
                    label=f"{m}, {c}",
                )
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xlabel(f"true {p}, {unit_of(p)}")
        ax.set_ylabel(f"estimate − truth, {unit_of(p)}")
        if pi == 0:
            ax.legend(fontsize=6, ncol=2)
        ax = axes[1, pi]
        for mi, m in enumerate(methods):
            rms = []
            for c in cases:
                sub = [r for r in rows if r["case"] == c]
                err = np.array([r[f"{m}_{p}"] - r[f"true_{p}"] for r in sub], dtype=np.float64)
                err = err[np.isfinite(err)]
                rms.append(np.sqrt(np.mean(err**2)) if err.size else np.nan)
            pos = np.arange(len(cases)) + (mi - (len(methods) - 1) / 2) * width
            ax.bar(pos, rms, width=width, color=_COLORS[m], label=m)
        ax.set_xticks(np.arange(len(cases)), cases, fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel(f"RMS error of {p}, {unit_of(p)}")
        if pi == 0:
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path
