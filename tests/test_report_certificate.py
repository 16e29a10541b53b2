"""The certificate as a reader meets it (issues 32 and 33 §6): a decision rule wherever
pass or fail is said, figure 2's residuals about the fitted model with the model's band,
tables not split over pages, and parameters named as in the budget table."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from chekan.report import build_report
from chekan.report.document import Para

DATA = Path(__file__).resolve().parent / "data" / "report"
BAYES_JSON = DATA / "bayes_result.json"


def _bayes() -> dict:
    return json.loads(BAYES_JSON.read_text(encoding="utf-8"))


@pytest.mark.parametrize("lang", ["en", "ru"])
@pytest.mark.parametrize(
    ("tolerance", "problems", "kind"),
    [(1e-6, True, "fail"), (10.0, False, "pass"), (10.0, True, "warn")],
)
def test_every_pass_or_fail_states_its_decision_rule(lang, tolerance, problems, kind):
    """The summary's and the conclusion's verdict, each followed by its decision rule; a
    problem of the diagnostics (this result's weakly identified τ) bars the pass."""
    res = _bayes()
    if not problems:
        res["diagnostics"] = {**res["diagnostics"], "problems": []}
    rep = build_report(res, lang=lang, tolerance_percent=tolerance, figures=False)
    blocks = rep.blocks
    starts = {
        "en": ("PASSED", "NOT PASSED", "NO DECISION"),
        "ru": ("СООТВЕТСТВУЕТ", "НЕ СООТВЕТСТВУЕТ", "РЕШЕНИЕ НЕ ПРИНЯТО"),
    }[lang]
    verdicts = [
        i for i, b in enumerate(blocks) if isinstance(b, Para) and b.text.startswith(starts)
    ]
    assert len(verdicts) == 2  # the summary and the conclusion
    assert {blocks[i].kind for i in verdicts} == {kind}
    for i in verdicts:
        after = [b.text for b in blocks[i + 1 : i + 4] if isinstance(b, Para)]
        assert any("ILAC-G8:09/2019" in text and "4.2.3" in text for text in after), blocks[i].text


@pytest.fixture(scope="module")
def sim_map(tmp_path_factory) -> tuple[dict, Path]:
    """A MAP result of the short simulated session (seed 7) and its record."""
    from chekan.demo import demo_program
    from chekan.pipeline import CalibrationOptions, calibrate_file
    from chekan.records import write_record
    from chekan.records.simulate import Truth, simulate_session

    d = tmp_path_factory.mktemp("simmap")
    rec, _ = simulate_session(demo_program(quick=True), Truth(serial="T-1"), seed=7)
    write_record(d / "rec.csv", rec)
    opts = CalibrationOptions(method="map", settle_s=200, progress=False)
    return calibrate_file(d / "rec.csv", opts), d / "rec.csv"


def _holds(record: Path):
    from chekan.records.holds import segment_record
    from chekan.records.inputs import read_input

    rec = read_input(record)
    return segment_record(rec, settle_s=float(rec.meta.get("program_settle_s", 300.0)))


def test_figure2_residuals_are_about_the_fitted_model_within_its_band(sim_map):
    import numpy as np

    from chekan.report import figures as figs

    res, record = sim_map
    holds = _holds(record)
    tilt = ~holds.is_level
    params = figs.fitted_model(res)
    resid = holds.m_mean_pix - figs.model_at_holds(params, holds)
    # about the model with the axes' inclinations ε the residuals are the noise (< 1 pix);
    # the characteristic without them (the panel before) left ±15 pix of ε·g·sin θ
    assert np.abs(resid[tilt]).max() < 1.0
    no_eps = params._replace(eps_rad=params.eps_rad * 0.0, gamma_rad=params.gamma_rad * 0.0)
    assert np.abs(holds.m_mean_pix - figs.model_at_holds(no_eps, holds))[tilt].max() > 5.0
    band = figs.residual_band_pix(res, params, holds, resid)
    assert band.shape == resid.shape and np.all(band[tilt] > 0)
    assert np.mean(np.abs(resid[tilt]) <= band[tilt]) >= 0.85  # a 95 % band
    rep = build_report(res, lang="en", source=record)
    (cos,) = [f for f in rep.figures if f.name == "cosinusoid"]
    for words in ("minus the model's reading", "against θ", "95 % band", "σ_hold", "σ_θ"):
        assert words in cos.caption, words


def test_figure2_without_a_pendulum_model_is_omitted_with_a_note(sim_map):
    res, record = sim_map
    flat = dict(res, parameters={**res["parameters"], "a": {**res["parameters"]["a"], "mean": 0.0}})
    rep = build_report(flat, lang="en", source=record)
    assert [f.name for f in rep.figures if f.name == "cosinusoid"] == []
    assert any("defines no pendulum model" in getattr(b, "text", "") for b in rep.blocks)


def _every_parameter_result() -> dict:
    """The hand-made bayes result with every parameter a result may report, and messages
    of the fit that name parameters by their keys."""
    from chekan.physics.parameters import LEGACY_UNITS, PARAMETER_UNITS

    res = _bayes()
    params = dict(res["parameters"])
    for name, unit in {**PARAMETER_UNITS, **LEGACY_UNITS}.items():
        params.setdefault(name, {"mean": 0.1234, "sd": 0.0123, "unit": unit})
    res["parameters"] = params
    res["diagnostics"] = {
        **res["diagnostics"],
        "problems": ["r_hat of sigma1_pix 1.02 > 1.01", "slew_error at its bound"],
        "notes": ["dgamma_arcmin is prior-dominated (sd 2.1 vs prior sd 3)"],
    }
    return res


@pytest.mark.parametrize("lang", ["en", "ru"])
def test_no_raw_parameter_names_in_pdf_or_html(lang):
    """Names and symbols as in the budget table, never keys such as b1_0 or sigma1_pix."""
    import re

    pytest.importorskip("typst")
    from pdfread import normalize
    from pypdf import PdfReader

    from chekan.physics.parameters import LEGACY_UNITS, MODEL_UNITS, PARAMETER_UNITS
    from chekan.report.html_page import render_html
    from chekan.report.typst_pdf import render_pdf

    rep = build_report(_every_parameter_result(), lang=lang, figures=False)
    import io

    pdf = " ".join(p.extract_text() for p in PdfReader(io.BytesIO(render_pdf(rep))).pages)
    html = re.sub(r"<[^>]+>", " ", render_html(rep).decode("utf-8"))
    raw = [k for k in (*PARAMETER_UNITS, *LEGACY_UNITS, *MODEL_UNITS) if len(k) > 2]
    for name, text in (("pdf", normalize(pdf)), ("html", html)):
        found = [k for k in raw if re.search(rf"(?<![\w.]){re.escape(k)}(?!\w)", text)]
        assert found == [], (name, found)
    assert "σ₁ (" in html and "κ (" in html and "σ_e (" in html
    reading_noise = {"en": "reading noise", "ru": "шум отсчёта"}[lang]
    assert f"σ₁ ({reading_noise}" in html  # the budget table's word for the same source


def _pages_of(rep) -> list[str]:
    import io

    from pdfread import normalize
    from pypdf import PdfReader

    from chekan.report.typst_pdf import render_pdf

    return [normalize(p.extract_text()) for p in PdfReader(io.BytesIO(render_pdf(rep))).pages]


def _line(cells) -> str:
    from pdfread import normalize

    return normalize(" ".join(c.text for c in cells if c.text))


@pytest.mark.parametrize("which", ["map", "bayes"])
def test_pdf_pages_do_not_split_tables(sim_map, which):
    """Every table with its caption, header and last row on one page; so is every key–value
    block, and a heading with the paragraphs under it."""
    pytest.importorskip("typst")
    from pdfread import normalize

    from chekan.report.document import Heading, KeyValue, Table

    res, record = sim_map
    if which == "bayes":
        res, record = _bayes(), None
    rep = build_report(res, lang="en", source=record)
    pages = _pages_of(rep)
    assert len(pages) >= 3
    tables = [b for b in rep.blocks if isinstance(b, Table)]
    assert len(tables) >= 3
    for n, tb in enumerate(tables, start=1):
        cap = normalize(f"Table {n}: {tb.caption}")
        (page,) = [p for p in pages if cap in p]
        for row in (tb.header[0], tb.rows[0], tb.rows[-1]):
            assert _line(row) in page, (tb.caption, _line(row))
    for kv in (b for b in rep.blocks if isinstance(b, KeyValue)):
        first, last = (normalize(f"{k} {v}") for k, v, _ in (kv.rows[0], kv.rows[-1]))
        assert any(first in p and last in p for p in pages), (first, last)
    for i, b in enumerate(rep.blocks[:-1]):
        nxt = rep.blocks[i + 1]
        if isinstance(b, Heading) and isinstance(nxt, Para):
            assert any(normalize(b.text) in p and normalize(nxt.text)[:40] in p for p in pages)


def test_angle_bound_reading_is_one_truth_in_help_result_and_certificate(sim_map, capsys):
    """--angle-bound-arcsec's help, the result's angle_sensor and the certificate all read
    the bound as rectangular, u = U/√3 (issue 33 §6: the help said one, the budget another)."""
    from chekan.cli.commands import main

    res, record = sim_map
    with pytest.raises(SystemExit):
        main(["calibrate", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "read as rectangular, u = U/√3" in help_text and "triangular" not in help_text
    sensor = res["angle_sensor"]
    assert sensor["distribution"] == "rectangular" and "U/√3" in sensor["reading"]
    rep = build_report(res, lang="en", source=record, figures=False)
    text = " ".join(str(getattr(b, "rows", "")) + getattr(b, "text", "") for b in rep.blocks)
    assert "read as rectangular (u = U/√3" in text and "triangular" not in text


@pytest.mark.parametrize("lang", ["en", "ru"])
def test_map_certificate_states_k_from_the_degrees_of_freedom(sim_map, lang):
    """The MAP's U = k·u with k = t₉₅.₄₅(ν_eff) (issue 29): each statement names its k, the
    note says why it is not 2, the budget table lists ν_eff and k."""
    from chekan.report.i18n import LABELS
    from chekan.report.numbers import coverage_text, value_unc
    from inference.dof import coverage_factor

    res, record = sim_map
    rep = build_report(res, lang=lang, source=record, figures=False)
    paras = [b.text for b in rep.blocks if isinstance(b, Para)]
    for name, label in (("b1", "b₁"), ("b2", "b₂")):
        bud = res["uncertainty_budget"][name]
        k = bud["coverage_factor"]
        assert k == coverage_factor(bud["nu_eff"]) > 2.0
        xs, us = value_unc(res["parameters"][name]["mean"], bud["expanded"])
        assert any(p.startswith(f"{label} = {xs}") and f"U = {us}" in p for p in paras)
        assert any(p.startswith(f"{label} =") and f"(k = {coverage_text(k)})" in p for p in paras)
    assert any(p.startswith(LABELS["statement_budget_t"][lang]) for p in paras)
    rows = [b for b in rep.blocks if hasattr(b, "rows") and hasattr(b, "header")]
    cells = [c.text for t in rows for r in t.rows for c in r]
    assert LABELS["src_nu_eff"][lang] in cells
    assert LABELS["src_coverage_factor"][lang] in cells
    assert LABELS["src_hyperparameters"][lang] in cells
