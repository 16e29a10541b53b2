"""The classical method's tables of the certificate, per round and system (the paper's
protocol, Fig. 6): а) the increments Δg, б) the deviations δg with their mean and СКП,
г) b, its uncertainty, b₀, mₕ and СКП of every round."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from chekan.report.document import Cell, Table
from chekan.report.i18n import Translator
from chekan.report.numbers import DASH, fixed, unc

_COL_RE = re.compile(r"^r(\d+)_s(\d+)$")


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


def increments_table(rs: Mapping[str, Any], t: Translator, caption: str) -> Table:
    """а) da_ref and dg per angle (rows) and round × system (columns)."""
    cols = list(rs["columns"])
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


def deviations_table(rs: Mapping[str, Any], t: Translator, caption: str) -> Table:
    """б) δg per angle and column, their mean and the СКП row."""
    cols = list(rs["columns"])
    top, sub = _col_header(cols, t)
    rows = []
    mean_dg = rs.get("mean_delta_g_mgal") or [None] * len(rs["angle_label"])
    for i, lab in enumerate(rs["angle_label"]):
        rows.append(
            [Cell(str(lab))]
            + [Cell(fixed(rs["delta_g_mgal"][c][i], 2)) for c in cols]
            + [Cell(fixed(mean_dg[i], 2), bold=True)]
        )
    rms = rs.get("rms_mgal") or {}
    rows.append(
        [Cell(t("rms_row"), bold=True)] + [Cell(fixed(rms.get(c), 2)) for c in cols] + [Cell("")]
    )
    return Table(
        [
            [Cell(t("angle"), bold=True), *top, Cell(t("mean_dg"), bold=True)],
            [Cell(""), *sub, Cell("")],
        ],
        rows,
        "l" + "r" * (len(cols) + 1),
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
