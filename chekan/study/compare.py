"""Two validation studies on the same platforms: one program's RMS error against another's.

    python -m chekan.study.compare A/validation.csv B/validation.csv [--method map]
        [--target 0.5] [-o compare.md]

The designer's target: its best program gives an RMS error of b at most half the paper
program's *on the same platforms*. Two studies (:mod:`chekan.study.coverage`) with the same seed
and cases simulate the same instrument and platform in session i whatever the program, so
their rows are paired by (session, case, seed); the paired rows' true b₁ must agree, or the
studies are of different platforms (an error). Per case, per shape of the systematic angle
error in the ``edge`` case (:func:`chekan.study.scenario.edge_platform`) and over all
sessions, for b₁, b₂ and a:

.. math::  r = \\frac{\\mathrm{RMS}(\\hat p_A - p)}{\\mathrm{RMS}(\\hat p_B - p)},

with the 95 % percentile interval of ``BOOTSTRAP`` paired bootstrap resamples of the
sessions (the same resampled sessions in A and B), the share of resamples with r at most
``--target``, and each study's mean z². A session that failed in either study is left out.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from chekan.errors import ChekanError
from chekan.study.scenario import edge_platform
from chekan.study.summary import PARAMS

BOOTSTRAP = 4000  # paired resamples: the interval's ends move by < 0.005 between seeds
BOOTSTRAP_SEED = 20261128
TRUTH_RTOL = 1e-12  # the true b₁ of a paired session must agree: the same platform


@dataclass(frozen=True)
class RatioRow:
    """One group's RMS errors and their ratio A/B with its paired bootstrap interval."""

    group: str
    param: str
    n: int
    rms_a: float
    rms_b: float
    ratio: float
    low: float
    high: float
    p_target: float  # share of bootstrap resamples with ratio ≤ target
    z2_a: float
    z2_b: float


def paired_rows(rows_a: Sequence[dict], rows_b: Sequence[dict], method: str) -> list[tuple]:
    """``(row_a, row_b)`` of the sessions present in both studies, in session order.

    Raises :class:`ChekanError` when a paired session's truth differs (other platforms) or
    when no session is common to both."""
    key = lambda r: (int(r["session"]), str(r["case"]), int(r["seed"]))  # noqa: E731
    b_of = {key(r): r for r in rows_b}
    pairs = []
    for ra in sorted(rows_a, key=key):
        rb = b_of.get(key(ra))
        if rb is None:
            continue
        ta, tb = float(ra["true_b1"]), float(rb["true_b1"])
        if not math.isclose(ta, tb, rel_tol=TRUTH_RTOL):
            raise ChekanError(
                f"session {ra['session']} ({ra['case']}, seed {ra['seed']}): true b1 {ta!r} in "
                f"the first study, {tb!r} in the second: not the same platforms (run both "
                "with the same --seed and --cases)"
            )
        pairs.append((ra, rb))
    if not pairs:
        raise ChekanError(
            "the two studies share no session (index, case and seed): run both with the same "
            "--seed and --cases"
        )
    if f"{method}_b1" not in pairs[0][0] or f"{method}_b1" not in pairs[0][1]:
        raise ChekanError(f"both studies must have run --methods {method}")
    return pairs


def group_of(row: dict) -> str:
    """The finest group of a session: its case, and the edge case split by shape."""
    if row["case"] == "edge":
        return f"edge: {edge_platform(int(row['session']))[0]}"
    return str(row["case"])


def ratio_row(
    group: str, param: str, pairs: Sequence[tuple], method: str, target: float
) -> RatioRow | None:
    """:class:`RatioRow` of ``pairs`` for one parameter (None: no session has both)."""

    def cols(i: int, suffix: str) -> np.ndarray:
        return np.array([float(p[i][f"{method}_{param}{suffix}"]) for p in pairs])

    truth = np.array([float(p[0][f"true_{param}"]) for p in pairs])
    est_a, est_b, sd_a, sd_b = cols(0, ""), cols(1, ""), cols(0, "_sd"), cols(1, "_sd")
    ok = np.isfinite(est_a) & np.isfinite(est_b) & (sd_a > 0) & (sd_b > 0)
    n = int(ok.sum())
    if n == 0:
        return None
    err_a, err_b = est_a[ok] - truth[ok], est_b[ok] - truth[ok]
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    idx = rng.integers(0, n, size=(BOOTSTRAP, n))
    with np.errstate(divide="ignore", invalid="ignore"):
        boot = np.sqrt(np.mean(err_a[idx] ** 2, axis=1) / np.mean(err_b[idx] ** 2, axis=1))
    rms_a, rms_b = float(np.sqrt(np.mean(err_a**2))), float(np.sqrt(np.mean(err_b**2)))
    low, high = np.quantile(boot, [0.025, 0.975])
    return RatioRow(
        group,
        param,
        n,
        rms_a,
        rms_b,
        rms_a / rms_b if rms_b > 0 else math.inf,
        float(low),
        float(high),
        float(np.mean(boot <= target)),
        float(np.mean((err_a / sd_a[ok]) ** 2)),
        float(np.mean((err_b / sd_b[ok]) ** 2)),
    )


def compare(
    rows_a: Sequence[dict],
    rows_b: Sequence[dict],
    *,
    method: str = "map",
    target: float = 0.5,
    params: Sequence[str] = PARAMS,
) -> list[RatioRow]:
    """The ratio rows of every case (the edge case by shape too) and of all sessions."""
    pairs = paired_rows(rows_a, rows_b, method)
    groups: dict[str, list[tuple]] = {}
    for pa in pairs:
        case = str(pa[0]["case"])
        groups.setdefault(case, []).append(pa)
        if case == "edge":
            groups.setdefault(group_of(pa[0]), []).append(pa)
    groups["all"] = list(pairs)
    out = []
    for g, members in groups.items():
        for p in params:
            row = ratio_row(g, p, members, method, target)
            if row is not None:
                out.append(row)
    return out


def markdown_table(rows: Sequence[RatioRow], name_a: str, name_b: str, target: float) -> str:
    """The rows as a markdown table, RMS errors in each parameter's own unit."""
    lines = [
        f"A = {name_a}; B = {name_b}. Ratio r = RMS error A / RMS error B on the same "
        f"sessions, 95 % paired bootstrap interval ({BOOTSTRAP} resamples), and the share "
        f"of resamples with r ≤ {target:g}.",
        "",
        "| group | param | n | RMS error A | RMS error B | r | 95 % interval | "
        f"P(r ≤ {target:g}) | mean z² A | mean z² B |",
        "|---|---|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for r in rows:
        lines.append(
            f"| {r.group} | {r.param} | {r.n} | {r.rms_a:.3g} | {r.rms_b:.3g} | {r.ratio:.3f} "
            f"| {r.low:.3f}–{r.high:.3f} | {r.p_target:.2f} | {r.z2_a:.2f} | {r.z2_b:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m chekan.study.compare", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("a", help="the first study's validation.csv (the numerator)")
    ap.add_argument("b", help="the second study's validation.csv, on the same platforms")
    ap.add_argument("--method", default="map", help="the estimator compared (default map)")
    ap.add_argument(
        "--target",
        type=float,
        default=0.5,
        help="the ratio asked for (default 0.5: the designer's target)",
    )
    ap.add_argument("-o", "--out", help="also write the table here (markdown; a new file)")
    from chekan.files.outputs import run_command

    return run_command(_main, ap, argv, prog="python -m chekan.study.compare")


def _main(ap: argparse.ArgumentParser, argv: Sequence[str] | None) -> int:
    args = ap.parse_args(argv)
    from chekan.files.outputs import check_outputs

    check_outputs([args.a, args.b], [args.out])
    if args.out and Path(args.out).exists():
        raise ChekanError(f"{args.out}: exists; choose a new file")
    rows = compare(_rows(args.a), _rows(args.b), method=args.method, target=args.target)
    text = markdown_table(rows, args.a, args.b, args.target)
    print(text, end="")
    if args.out:
        Path(args.out).write_text(text, encoding="utf-8")
        print(f"wrote {args.out}")
    return 0


def _rows(path: str) -> list[dict]:
    """The rows of a ``validation.csv`` (:func:`chekan.study.coverage.read_rows`: a bad line is an
    error naming it), which must have the columns that pair them."""
    from chekan.study.coverage import read_rows

    return read_rows(path, need=("session", "case", "seed", "true_b1"))


if __name__ == "__main__":
    sys.exit(main())
