"""The classical method's tables of the certificate, per round and system (the paper's
protocol, Fig. 6): а) the increments Δg, б) the deviations δg with their mean and СКП,
г) b, its uncertainty, b₀, mₕ and СКП of every round.

A table with a column per round and system holds at most :data:`ROUNDS_PER_TABLE` rounds:
a program of more rounds (the designer's, 10 about each axis) gets one such table per group
of rounds, each captioned with its rounds, so that its numbers stay legible on the page.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from chekan.report.document import Cell, Table
from chekan.report.i18n import Translator
from chekan.report.numbers import DASH, fixed, unc

_COL_RE = re.compile(r"^r(\d+)_s(\d+)$")
#: rounds (two columns each) in one table of а) or б): 14 columns fit an A4 page's width
ROUNDS_PER_TABLE = 6


def _cols_by_round(cols: list[str]) -> list[tuple[str, list[tuple[str, str]]]]:
    """Group ``r1_s1``-style columns by round: ``[(round, [(system, col), …]), …]``."""
    groups: dict[str, list[tuple[str, str]]] = {}
    for c in cols:
        m = _COL_RE.match(c)
        r, s = (m.group(1), m.group(2)) if m else ("", c)
        groups.setdefault(r, []).append((s, c))
    return list(groups.items())


def _col_header(cols: list[str], t: Translator) -> tuple[list[Cell], list[Cell]]:
    top: list[Cell] = []
    sub: list[Cell] = []
    for r, items in _cols_by_round(cols):
        top.append(Cell(t("round_n", n=r) if r else "", colspan=len(items), bold=True))
        sub.extend(Cell(t("sys_n", n=s) if r else s) for s, _ in items)
    return top, sub


def _parts(cols: list[str], t: Translator, caption: str) -> list[tuple[list[str], str]]:
    """The columns in groups of at most :data:`ROUNDS_PER_TABLE` rounds, each with its
    caption (the rounds it holds named when there is more than one group)."""
    groups = _cols_by_round(cols)
    chunks = [groups[i : i + ROUNDS_PER_TABLE] for i in range(0, len(groups), ROUNDS_PER_TABLE)]
    if len(chunks) <= 1:
        return [(cols, caption)]
    return [
        (
            [c for _, items in chunk for _, c in items],
            caption + t("cap_rounds_part", a=chunk[0][0], b=chunk[-1][0]),
        )
        for chunk in chunks
    ]


def increments_tables(rs: Mapping[str, Any], t: Translator, caption: str) -> list[Table]:
    """а) da_ref and dg per angle (rows) and round × system (columns), one table per group
    of rounds."""
    return [_increments_table(rs, cols, t, cap) for cols, cap in _parts(rs["columns"], t, caption)]


def _increments_table(rs: Mapping[str, Any], cols: list[str], t: Translator, caption: str) -> Table:
    top, sub = _col_header(cols, t)
    rows = []
    for i, lab in enumerate(rs["angle_label"]):
        rows.append(
            [Cell(str(lab)), Cell(fixed(rs["da_ref_mgal"][i], 2))]
            + [Cell(fixed(rs["dg_mgal"][c][i], 2)) for c in cols]
        )
    return Table(
        [
            [Cell(t("angle"), bold=True), Cell(t("da_ref"), bold=True), *top],
            [Cell(""), Cell(""), *sub],
        ],
        rows,
        "lr" + "r" * len(cols),
        caption,
    )


def deviations_tables(rs: Mapping[str, Any], t: Translator, caption: str) -> list[Table]:
    """б) δg per angle and column and the СКП row, one table per group of rounds; the mean
    over every column (Δg) in the last."""
    parts = _parts(rs["columns"], t, caption)
    return [
        _deviations_table(rs, cols, t, cap, with_mean=k == len(parts) - 1)
        for k, (cols, cap) in enumerate(parts)
    ]


def _deviations_table(
    rs: Mapping[str, Any], cols: list[str], t: Translator, caption: str, *, with_mean: bool
) -> Table:
    top, sub = _col_header(cols, t)
    rows = []
    mean_dg = rs.get("mean_delta_g_mgal") or [None] * len(rs["angle_label"])
    last = [Cell(t("mean_dg"), bold=True)] if with_mean else []
    for i, lab in enumerate(rs["angle_label"]):
        rows.append(
            [Cell(str(lab))]
            + [Cell(fixed(rs["delta_g_mgal"][c][i], 2)) for c in cols]
            + ([Cell(fixed(mean_dg[i], 2), bold=True)] if with_mean else [])
        )
    rms = rs.get("rms_mgal") or {}
    rows.append(
        [Cell(t("rms_row"), bold=True)]
        + [Cell(fixed(rms.get(c), 2)) for c in cols]
        + ([Cell("")] if with_mean else [])
    )
    return Table(
        [
            [Cell(t("angle"), bold=True), *top, *last],
            [Cell(""), *sub, *([Cell("")] if with_mean else [])],
        ],
        rows,
        "l" + "r" * (len(cols) + int(with_mean)),
        caption,
        footer_rows=1,
    )


def rounds_table(rounds: list, t: Translator, caption: str) -> Table:
    """г) b, its uncertainty, b₀, mₕ and СКП per round and system."""
    printed = any("b_printed" in r for r in rounds)
    head = [
        t("round"),
        t("system"),
        t("b_col"),
        t("u_col"),
        t("b0_col"),
        t("mh_col"),
        t("rms_col"),
    ] + ([t("printed_col")] if printed else [])
    rows = []
    for r in rounds:
        for s in (1, 2):
            b = r[f"b{s}"]
            lvl = r.get("level_reading_pix")
            row = [
                Cell(str(r.get("round", ""))),
                Cell(t("sys_n", n=s)),
                Cell(fixed(b["mean"], 6), bold=True),
                Cell(unc(b.get("sd"))),
                Cell(fixed(r.get(f"b{s}_0"), 6)),
                Cell(fixed(lvl[s - 1], 3) if isinstance(lvl, list) and len(lvl) >= s else DASH),
                Cell(fixed((r.get("rms_mgal") or {}).get(f"s{s}"), 2)),
            ]
            if printed:
                bp = r.get("b_printed")
                row.append(
                    Cell(fixed(bp[s - 1], 6) if isinstance(bp, list) and len(bp) >= s else DASH)
                )
            rows.append(row)
    return Table(
        [[Cell(h, bold=True) for h in head]],
        rows,
        "cc" + "r" * (len(head) - 2),
        caption,
    )
