"""A record too short to estimate its Type A uncertainty (ν_eff < 1).

The designer's last-ranked 9 h program (two angles about X, one round, 5 486 s dwells: six
holds) gave b₁ an effective number of degrees of freedom of 0.025 from the hyperparameters
estimated on six holds; ``calibrate --method map`` ended in a traceback from the coverage
factor. GUM G.4.1 truncates ν_eff to an integer: below 1 nothing is left, so no finite k
exists. The result states b and u, no interval and no U, and says why as a problem (exit 3
under ``--strict``); the certificate prints U and k as "—".
"""

from __future__ import annotations

import copy
import html
import json
import math
import re
from pathlib import Path

import pytest

from chekan.report.expanded import expanded_of
from chekan.results.document import param_entry
from chekan.results.entries import budget_entries
from inference.dof import coverage_factor

DATA = Path(__file__).resolve().parent / "data" / "report"


def test_no_interval_below_one_degree_of_freedom():
    e = param_entry(6.87, 0.018, 0.95, "mGal/pix", nu_eff=0.025)
    assert e["hdi_low"] is None and e["hdi_high"] is None
    assert e["sd"] == 0.018 and e["nu_eff"] == 0.025
    one = param_entry(6.87, 0.018, 0.95, "mGal/pix", nu_eff=1.0)  # one is enough: t₉₅(1)
    assert one["hdi_high"] - 6.87 == pytest.approx(coverage_factor(1.0, 0.95) * 0.018)


def test_the_budget_states_u_without_k_or_expanded():
    raw = {
        s: {"noise": 0.003, "angle_readout": 0.004, "total_linearised": 0.005} for s in ("b1", "b2")
    }
    params = {s: {"sd": 0.005} for s in ("b1", "b2")}
    bud = budget_entries(raw, params, {"b1": 0.025, "b2": 3.5})
    assert bud["b1"]["total"] == 0.005 and bud["b1"]["nu_eff"] == 0.025
    assert bud["b1"]["coverage_factor"] is None and bud["b1"]["expanded"] is None
    k = coverage_factor(3.5)
    assert bud["b2"]["coverage_factor"] == k and bud["b2"]["expanded"] == pytest.approx(k * 0.005)


def test_the_certificate_prints_no_u_and_says_why(tmp_path):
    from chekan.report import render_report

    res = json.loads((DATA / "bayes_result.json").read_text(encoding="utf-8"))
    res = copy.deepcopy(res)
    res["method"] = "map"
    why = (
        "effective degrees of freedom below 1 for b1 (down to 0.025): the record is too short "
        "to estimate the Type A part of their uncertainty"
    )
    res["diagnostics"]["problems"] = [why]
    b1 = res["parameters"]["b1"]
    b1.update(hdi_low=None, hdi_high=None, nu_eff=0.025)
    bud = res["uncertainty_budget"]["b1"]
    bud.pop("expanded_k2")
    bud.update(nu_eff=0.025, coverage_factor=None, expanded=None)
    assert expanded_of(res, "b1") == (None, math.inf)
    out = render_report(res, tmp_path / "cert.html", lang="en")
    page = re.sub(r"<[^>]+>", " ", Path(out).read_text(encoding="utf-8"))
    text = " ".join(html.unescape(page).split())
    assert re.search(r"b₁ = [\d.]+ mGal/pix, U = — mGal/pix \(k = —\)", text), text[:2000]
    assert why in text
    assert re.search(r"effective degrees of freedom ν_eff < 1 ", text), text  # not "0"
    assert not re.search(r"\b(inf|nan|None)\b", text)
