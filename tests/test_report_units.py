"""Small parts of chekan.report: number formatting, typst escaping, translations, PDF reader."""

from __future__ import annotations

import pytest
from pdfread import normalize, read_pdf

from chekan.errors import ChekanError
from chekan.report.document import Cell, Figure, Heading, KeyValue, Para, Report, Table
from chekan.report.i18n import LABELS, LANGS, PARAM_NAMES, check_lang, tr
from chekan.report.numbers import fixed, plain, sci, statement, unc, value_unc
from chekan.report.typst_pdf import render_pdf, tstr


def test_metrology_statement():
    assert statement("b1", 6.98034123, 0.000221, "mGal/pix") == (
        "b1 = 6.98034 mGal/pix, U = 0.00022 mGal/pix (k = 2)"
    )
    assert (
        statement("b", 6.9, 0.0014, "mGal/pix")
        == "b = 6.9000 mGal/pix, U = 0.0014 mGal/pix (k = 2)"
    )
    assert value_unc(1.3949819e-4, 1.8778e-6) == ("1.395·10⁻⁴", "1.9·10⁻⁶")
    assert value_unc(3.97, 0.95) == ("3.97", "0.95")


def test_number_formats():
    assert fixed(-0.004, 2) == "0.00"  # no "−0.00"
    assert fixed(-1.4197, 2) == "−1.42"
    assert fixed(0.0331, 3, sign=True) == "+0.033"
    assert fixed(None, 2) == fixed(float("nan"), 2) == "—"
    assert sci(-7.828e-5) == "−7.828·10⁻⁵"
    assert unc(0.0007031) == "0.00070" and unc(1.87e-6) == "1.9·10⁻⁶"
    assert plain(0.05) == "0.05" and plain(1024.0) == "1024" and plain(95.0) == "95"


def test_translations_complete():
    for key, tr_ in LABELS.items():
        assert set(tr_) == set(LANGS), key
        for lang in LANGS:
            assert tr_[lang].strip(), (key, lang)
    for key, tr_ in PARAM_NAMES.items():
        assert set(tr_) == set(LANGS), key
    assert tr("ru")("round_n", n=2) == "Приём 2"
    with pytest.raises(ChekanError, match="unknown language 'fr'; choose one of en, ru"):
        check_lang("fr")


def test_typst_escaping_roundtrip():
    """User text with typst's special characters comes out of the PDF as it went in."""
    nasty = [
        "#set page(width: 1cm) $x^2$ *b* _i_ `c` <l> @r",
        'a\\"b" \\\\ // /* ~ -- ---',
        "Серийный № 46 «Шельф» ε₁ ±1°50′",
    ]
    assert tstr('a"b\\') == '"a\\"b\\\\"'
    rep = Report(lang="ru", title=nasty[0], subtitle=nasty[1], running_head="#x")
    rep.add(
        Heading(nasty[2]),
        Para(nasty[0], "pass"),
        KeyValue([(nasty[1], nasty[0], True)]),
        Table([[Cell("#h", colspan=2, bold=True)]], [[Cell("$1"), Cell("*2*")]], "lr", "cap #"),
    )
    info = read_pdf(render_pdf(rep))
    text = normalize(info.text)
    for s in (*nasty, "#h", "$1", "*2*", "cap #"):
        assert normalize(s) in text, s
    assert len(info.pages) == 1 and info.n_notdef == 0 and info.n_images == 0


def test_pdf_reader_counts_images():
    from chekan.report.figures import drift_figure

    png = drift_figure(
        {"t_h": [0, 1, 2], "m1_pix": [0, 0.1, 0.2], "m2_pix": [0, -0.1, -0.1]}, tr("en")
    )
    rep = Report(lang="en", title="T", subtitle="S", running_head="R")
    rep.add(Figure("a", png, "first"), Figure("b", png, "second", width=0.5))
    info = read_pdf(render_pdf(rep))
    assert info.n_images == 2
    assert "Figure 2: second" in normalize(info.text)


def test_negative_zero_is_never_written():
    from chekan.report.numbers import fixed, plain

    assert fixed(-0.0, 3) == "0.000"
    assert fixed(-0.0004, 3, sign=True) == "+0.000"
    assert fixed(-0.0006, 3, sign=True) == "−0.001"
    assert plain(-0.0) == "0"


def test_status_line_fits_the_terminal(monkeypatch):
    import io
    import os
    import shutil

    from hw.progress import Progress, StatusLine

    class Tty(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(shutil, "get_terminal_size", lambda *a: os.terminal_size((60, 24)))
    out = Tty()
    line = StatusLine(out)
    line(Progress(3, 36, 1, "+1°50'", "dwell", 12, 900, 1234.0, 20000.0, 5000, 1, 0))
    assert len(out.getvalue()) == 1 + 59  # "\r" and a line one narrower than the terminal
