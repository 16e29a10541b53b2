"""The calibration certificate (chekan.report): PDF and HTML, ru and en, against the JSON.

Text is read back from the PDFs with pypdf (tests/pdfread.py), so these tests need no
poppler; one cross-check with pdftotext runs when it is installed.
"""

from __future__ import annotations

import argparse
import base64
import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from pdfread import normalize, read_pdf

from chekan.errors import ChekanError, FormatError
from chekan.report import build_report, render_report, verdict_of
from chekan.report.cli import add_report_parser

REPO = Path(__file__).resolve().parents[1]
PAPER_CSV = Path(__file__).resolve().parents[1] / "examples" / "calibr_46_protocol.csv"
DATA = Path(__file__).resolve().parent / "data" / "report"
BAYES_JSON = DATA / "bayes_result.json"
LAB_TOML = DATA / "lab.toml"  # a certificate with its laboratory (without one: a draft)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def f6(x: float) -> str:
    return f"{x:.6f}"


def f2(x: float) -> str:
    return f"{x:.2f}"


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def paper(tmp_path_factory) -> tuple[dict, Path]:
    """The paper's protocol (Fig. 6), calibrated with the classical method."""
    from chekan.pipeline import CalibrationOptions, calibrate_file
    from chekan.results.document import write_result

    res = calibrate_file(PAPER_CSV, CalibrationOptions(progress=False))
    path = write_result(tmp_path_factory.mktemp("paper") / "r46.json", res)
    return res, path


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> tuple[dict, Path]:
    """A simulated 9 h session (seed 0), calibrated with the classical method."""
    from chekan.physics.program import default_program
    from chekan.pipeline import CalibrationOptions, calibrate_file
    from chekan.records import write_record
    from chekan.records.simulate import Truth, simulate_session
    from chekan.results.document import write_result

    d = tmp_path_factory.mktemp("sim")
    rec, _ = simulate_session(default_program(), Truth(), seed=0)
    write_record(d / "sim.csv", rec)
    res = calibrate_file(d / "sim.csv", CalibrationOptions(progress=False))
    return res, write_result(d / "sim.json", res)


@pytest.fixture(scope="module")
def bayes(tmp_path_factory) -> tuple[dict, Path]:
    """The hand-made Bayesian result with its posterior NetCDF (made with ArviZ) beside it."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "make_bayes_fixture", DATA / "make_bayes_fixture.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    d = tmp_path_factory.mktemp("bayes")
    mod.write_posterior_netcdf(d / "posterior.nc")
    path = d / "bayes_result.json"
    shutil.copy(BAYES_JSON, path)
    return json.loads(path.read_text(encoding="utf-8")), path


_PDFS: dict[tuple, tuple[Path, str, int, Path]] = {}


def pdf_of(kind: str, lang: str, result_path: Path, tmp_root: Path) -> tuple[Path, str, int, Path]:
    """Render once per (kind, lang): (pdf, normalized text, images drawn, figure folder)."""
    key = (kind, lang, str(result_path))
    if key not in _PDFS:
        out = tmp_root / f"calibr_{kind}_{lang}.pdf"
        figs = tmp_root / f"figs_{kind}_{lang}"
        written = render_report(result_path, out, lang=lang, keep_figures=figs, lab=LAB_TOML)
        assert written == out and out.stat().st_size > 10_000
        info = read_pdf(out)
        assert info.n_notdef == 0, "glyphs missing from the fonts (tofu)"
        assert "\ufffd" not in info.text
        _PDFS[key] = (out, normalize(info.text), info.n_images, figs)
    return _PDFS[key]


@pytest.fixture(scope="module")
def outdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("certificates")


def assert_in(needle: str, text: str) -> None:
    assert normalize(needle) in text, f"{needle!r} not in the certificate text"


# --------------------------------------------------------------------------- the paper's protocol


@pytest.mark.parametrize("lang", ["ru", "en"])
def test_paper_protocol_certificate(paper, outdir, lang):
    res, path = paper
    _pdf, text, n_img, figs = pdf_of("paper", lang, path, outdir)
    # header: serial, platform serial, SHA-256 of the input, software, method
    assert_in(str(res["serial"]), text)
    assert_in("123456", text)
    assert re.fullmatch(r"[0-9a-f]{64}", res["record_sha256"])
    assert_in(res["record_sha256"], text)
    assert_in(f"chekan {res['software']['version']}", text)
    # а) reference and measured increments; б) deviations and СКП — every value of the JSON
    rs = res["residuals_mgal"]
    for i, lab in enumerate(rs["angle_label"]):
        row = [lab, f2(rs["da_ref_mgal"][i])] + [f2(rs["dg_mgal"][c][i]) for c in rs["columns"]]
        assert_in(" ".join(row), text)
        row = [lab] + [f2(rs["delta_g_mgal"][c][i]) for c in rs["columns"]]
        row.append(f2(rs["mean_delta_g_mgal"][i]))
        assert_in(" ".join(row), text)
    rms = " ".join(f2(rs["rms_mgal"][c]) for c in rs["columns"])
    assert rms == "0.62 0.69 0.54 0.75"  # the paper's СКП
    assert_in(("СКП " if lang == "ru" else "RMS (СКП) ") + rms, text)
    # в) reduced error 0.019 %
    assert f"{res['reduced_error_percent']:.3f}" == "0.019"
    assert_in("0.019 %", text)
    # г) b per round and system (6.980339 …) next to the value printed by Calibr.exe
    r1 = res["rounds"][0]
    assert f6(r1["b1"]["mean"]) == "6.980339"
    sys1 = "КС1" if lang == "ru" else "S1"
    assert_in(f"1 {sys1} 6.980339", text)
    for r in res["rounds"]:
        for s in (1, 2):
            assert_in(f6(r[f"b{s}"]["mean"]), text)
            assert_in(f6(r["b_printed"][s - 1]), text)
    for name in ("b1", "b2"):
        assert_in(f6(res["parameters"][name]["mean"]), text)
    assert_in(f6(res["mean_b_mgal_per_pix"]), text)
    assert_in(f"{res['discrepancy_between_rounds_percent']:.3f} %", text)
    assert_in("7.828·10⁻⁵", text)  # a, fixed by the protocol
    # labels of the items а)–е)
    labels = {
        "ru": [
            "Свидетельство о калибровке",
            "а) Заданные и измеренные приращения",
            "б) Отклонения δg",
            "в) Приведённая погрешность",
            "г) Коэффициенты a, b₁, b₂",
            "д) Отклонения b₁, b₂",
            "е) Запас по диапазону измерений",
            "Заводской номер УСГ",
            "Приём 1",
            "КС2",
            "Заключение",
            "СООТВЕТСТВИЕ НЕ УСТАНАВЛИВАЕТСЯ (допуск 0.05 %)",
            "повторяемость Calibr.exe",
        ],
        "en": [
            "Calibration certificate",
            "a) Reference and measured increments",
            "b) Deviations δg",
            "c) Reduced error",
            "d) Coefficients a, b₁, b₂",
            "e) Deviations of b₁, b₂",
            "f) Margin of the measuring range",
            "Gyro-platform serial no.",
            "Round 1",
            "Conclusion",
            "NO STATEMENT OF CONFORMITY (tolerance 0.05 %)",
            "Calibr.exe's repeatability",
        ],
    }[lang]
    for lab in labels:
        assert_in(lab, text)
    # a protocol has no raw record: the residual figure only, and a note saying so
    assert n_img == 1
    assert_in(
        "таблица протокола без исходных отсчётов"
        if lang == "ru"
        else "protocol table without raw readings",
        text,
    )
    pngs = sorted(figs.glob("*.png"))
    assert [p.name for p in pngs] == ["fig1-residuals.png"]
    assert pngs[0].read_bytes().startswith(PNG_MAGIC) and pngs[0].stat().st_size > 10_000


# --------------------------------------------------------------------------- the simulated session


@pytest.mark.parametrize("lang", ["en", "ru"])
def test_simulated_session_certificate(sim, outdir, lang):
    res, path = sim
    _pdf, text, n_img, figs = pdf_of("sim", lang, path, outdir)
    assert_in(res["serial"], text)
    assert_in(res["record_sha256"], text)
    for name in ("b1", "b2", "b1_0", "b2_0"):
        assert_in(f6(res["parameters"][name]["mean"]), text)
    for r in res["rounds"]:
        assert_in(f6(r["b1"]["mean"]), text)
        assert_in(f6(r["b2"]["mean"]), text)
    assert_in(f"{res['reduced_error_percent']:.3f} %", text)
    for s in ("b1", "b2"):
        assert_in(f"{res['instability_percent'][s]:+.3f} %", text)
        assert_in(f6(res["b_prior"][s]), text)
    rm = res["range_margin_gal"]
    gal = "Гал" if lang == "ru" else "Gal"
    assert_in(f"{rm['heavy']:.1f} {gal}", text)
    assert_in(f"{rm['light']:.1f} {gal}", text)
    # the classical 2·sd is Calibr.exe's repeatability, named so, never an expanded U
    b1 = res["parameters"]["b1"]
    u = float(f"{2 * b1['sd']:.1e}")
    nd = max(0, 1 - int(f"{u:e}".split("e")[1]))
    unit = "мГал/пикс" if lang == "ru" else "mGal/pix"
    word = "повторяемость" if lang == "ru" else "repeatability"
    assert_in(f"b₁ = {b1['mean']:.{nd}f} {unit}, 2s = {u:.{nd}f} {unit} ({word})", text)
    assert ", U = " not in text.split("д) " if lang == "ru" else "e) ")[0]
    # the verdict agrees with the JSON and the default tolerance 0.05 %: a criterion beyond
    # it is not passed; within it the classical method makes no statement of conformity
    ok = res["reduced_error_percent"] <= 0.05 and all(
        abs(v) <= 0.05 for v in res["instability_percent"].values()
    )
    word = {
        ("en", True): "NO STATEMENT OF CONFORMITY (tolerance 0.05 %)",
        ("en", False): "NOT PASSED (tolerance 0.05 %",
        ("ru", True): "СООТВЕТСТВИЕ НЕ УСТАНАВЛИВАЕТСЯ (допуск 0.05 %)",
        ("ru", False): "НЕ СООТВЕТСТВУЕТ (допуск 0.05 %",
    }[lang, ok]
    assert_in(word, text)
    assert "PASSED (tolerance" not in text.replace("NOT PASSED (tolerance", "")
    # figures: the record, the cosinusoid, the residuals — all drawn, all non-empty PNGs
    assert n_img == 3
    names = sorted(p.name for p in figs.glob("*.png"))
    assert names == ["fig1-record.png", "fig2-cosinusoid.png", "fig3-residuals.png"]
    for p in figs.glob("*.png"):
        assert p.read_bytes().startswith(PNG_MAGIC) and p.stat().st_size > 20_000


def test_tolerance_changes_the_verdict(sim):
    res, _ = sim
    worst = max([res["reduced_error_percent"], *map(abs, res["instability_percent"].values())])
    ok, line = verdict_of(res, worst * 1.01)  # classical: no U, so no pass
    assert ok is None and line.startswith("NO STATEMENT OF CONFORMITY")
    ok, line = verdict_of(res, worst * 0.99, lang="ru")
    assert ok is False and line.startswith("НЕ СООТВЕТСТВУЕТ")
    assert verdict_of({k: v for k, v in res.items() if k != "reduced_error_percent"})[0] is None
    rep = build_report(res, tolerance_percent=worst * 0.99, figures=False)
    assert rep.figures == [] and [b.kind for b in rep.blocks if getattr(b, "kind", "") == "fail"]


def test_record_moved_or_changed(sim, tmp_path):
    res, _ = sim
    moved = dict(res, record=str(tmp_path / "gone.csv"))
    rep = build_report(moved)
    assert [f.name for f in rep.figures] == ["residuals"]
    assert any("gone.csv is not available" in getattr(b, "text", "") for b in rep.blocks)
    changed = tmp_path / "changed.csv"
    changed.write_bytes(Path(res["record"]).read_bytes() + b"\n")
    rep = build_report(res, record_path=changed)
    assert [f.name for f in rep.figures] == ["residuals"]
    assert any("SHA-256 mismatch" in getattr(b, "text", "") for b in rep.blocks)


# --------------------------------------------------------------------------- Bayesian result


def test_bayes_certificate(bayes, outdir):
    res, path = bayes
    _pdf, text, n_img, figs = pdf_of("bayes", "en", path, outdir)
    # special characters of user text printed literally
    assert_in('B-7 #1 $x* "q"', text)
    assert_in('Lab #3 $1_000 *roof* \\ "north"', text)
    # the budget and the expanded uncertainty, metrology style
    assert_in("b₁ = 6.98041 mGal/pix, U = 0.00021 mGal/pix (k = 2)", text)
    assert_in("b₂ = 6.88213 mGal/pix, U = 0.00022 mGal/pix (k = 2)", text)
    assert_in("Uncertainty budget of b", text)
    for label in (
        "angle readout, random (Type A)",
        "reading noise",
        "drift",
        "quadratic coefficient a",
        "combined standard uncertainty u",
        "expanded U (k = 2)",
    ):
        assert_in(label, text)
    bud = res["uncertainty_budget"]["b1"]
    assert_in(f"angle readout, random (Type A) A {bud['angle_readout']:.6f}", text)
    assert_in("Source Type u(b₁)", text)
    assert_in("drift A", text)
    assert_in("quadratic coefficient a B", text)
    assert "angle sensor, systematic" not in text  # this result has no such line
    assert_in("expanded U (k = 2) 0.00021 30 0.00022 32", text)  # U and U/b in ppm
    # posterior summary with HDI, R-hat and ESS for every parameter
    assert_in("95 % HDI", text)
    assert_in("R-hat ESS", text)
    # τ's u is the fit's alone: the held-sample model biases it on a moving platform
    assert_in("τ is a parameter of the model, its u the fit's alone", text)
    assert_in("biases τ by many times u", text)
    for name, label in (
        ("dgamma_arcmin", "Δγ"),
        ("tau_s", "τ (time constant)"),
        ("drift1_pix_per_h", "drift of system 1"),
        ("eps1_arcmin", "ε₁"),
    ):
        e = res["parameters"][name]
        assert_in(f"{label} ", text)
        assert_in(f"{e['r_hat']:.3f} {e['ess_bulk']:.0f}", text)
    # diagnostics and problems, the verdict
    d = res["diagnostics"]
    assert_in(f"Largest R-hat (should be < 1.01) {d['r_hat_max']:.3f}", text)
    assert_in(f"Smallest bulk ESS (should be ≥ 400) {d['ess_bulk_min']:.0f}", text)
    # the fit's message as written, its parameter key by its name (issue 33 §6)
    assert_in(d["problems"][0].replace("tau_s", "τ (time constant)"), text)
    assert "tau_s" not in text
    assert_in("the sampler converged", text)
    # an archived result: the record is gone, the posterior is there
    assert_in("archive/missing_record.csv is not available", text)
    assert n_img == 3
    assert sorted(p.name for p in figs.glob("*.png")) == [
        "fig1-residuals.png",
        "fig2-pair.png",
        "fig3-drift.png",
    ]


@pytest.fixture(scope="module")
def bayes_systematic(bayes) -> tuple[dict, Path]:
    """The Bayesian result with a systematic angle-sensor line and ``angle_sensor``, as the
    estimator writes them (beside the posterior NetCDF)."""
    res, path = bayes
    res = json.loads(json.dumps(res))
    for name, sys_u in (("b1", 0.000120), ("b2", 0.000118)):
        b = res["uncertainty_budget"][name]
        b["angle_systematic"] = sys_u
        b["total"] = (b["total"] ** 2 + sys_u**2) ** 0.5
        b["expanded_k2"] = 2 * b["total"]
    res["angle_sensor"] = {
        "model": "systematic",
        "bound_arcsec": 3.0,
        "u_per_angle_arcsec": 1.2247,
        "u_scale_arcsec": 1.2247,
    }
    out = path.parent / "bayes_systematic.json"
    out.write_text(json.dumps(res), encoding="utf-8")
    return res, out


@pytest.mark.parametrize(
    ("lang", "labels"),
    [
        (
            "en",
            (
                "angle sensor, systematic (Type B, platform specification ±3″) B 0.00012",
                "angle readout, random (Type A) A 0.000091",
                "Platform angle sensor bound ±3″ read as rectangular (u = U/√3, GUM 4.3.7: "
                "only a bound is known), per-angle u = 1.22″, scale u = 1.22″ at the largest "
                "angle",
                "U includes the systematic error of the platform's angle sensor (Type B, "
                "platform specification ±3″).",
                "b₁ = 6.98041 mGal/pix, U = 0.00032 mGal/pix (k = 2)",
            ),
        ),
        (
            "ru",
            (
                "датчик угла, систематическая (тип В, паспорт платформы ±3″) В 0.00012",
                "отсчёт угла, случайная (тип А) А 0.000091",
                "Датчик угла платформы граница ±3″, равномерное распределение (u = U/√3, "
                "GUM 4.3.7: известна лишь граница)",
                "U включает систематическую погрешность датчика угла платформы (тип В, "
                "паспорт платформы ±3″).",
            ),
        ),
    ],
)
def test_budget_systematic_angle_line(bayes_systematic, outdir, lang, labels):
    _res, path = bayes_systematic
    _pdf, text, _n, _figs = pdf_of("bayes_sys", lang, path, outdir)
    for label in labels:
        assert_in(label, text)
    html = render_report(path, outdir / f"sys_{lang}.html", lang=lang).read_text(encoding="utf-8")
    assert labels[0].split(")")[0] in html


def test_budget_without_angle_sensor_has_no_bound(bayes):
    res, _ = bayes
    res = json.loads(json.dumps(res))
    res["uncertainty_budget"]["b1"]["angle_systematic"] = 0.0001
    rep = build_report(res, source=BAYES_JSON, figures=False)
    from chekan.report.document import Table

    texts = [c.text for b in rep.blocks if isinstance(b, Table) for row in b.rows for c in row]
    assert "angle sensor, systematic (Type B, platform specification)" in texts


def test_bayes_html_ru_self_contained(bayes, tmp_path):
    _, path = bayes
    out = render_report(path, tmp_path / "c.html", lang="ru")
    html = out.read_text(encoding="utf-8")
    assert "Бюджет неопределённости b" in html
    assert "b₁ = 6.98041 мГал/пикс, U = 0.00021 мГал/пикс (k = 2)" in html
    assert "B-7 #1 $x* &quot;q&quot;" in html  # escaped, not interpreted
    srcs = re.findall(r'\bsrc="([^"]*)"', html)
    assert len(srcs) == 3 and all(s.startswith("data:image/png;base64,") for s in srcs)
    for s in srcs:
        assert base64.b64decode(s.split(",", 1)[1]).startswith(PNG_MAGIC)
    assert "<link" not in html and "<script" not in html and "url(" not in html
    assert not re.search(r"(href|src)=\"(https?:|//)", html)


def test_bayes_without_netcdf_notes_it(bayes, tmp_path):
    res, _ = bayes
    rep = build_report(res, source=tmp_path / "elsewhere.json")
    assert [f.name for f in rep.figures] == ["residuals", "drift"]
    assert any("posterior.nc is not available" in getattr(b, "text", "") for b in rep.blocks)


def test_bayes_not_converged_fails(bayes):
    res, _ = bayes
    bad = json.loads(json.dumps(res))
    bad["diagnostics"]["converged"] = False
    rep = build_report(bad, tolerance_percent=1.0, source=BAYES_JSON, figures=False)
    fails = [b.text for b in rep.blocks if getattr(b, "kind", "") == "fail"]
    assert fails and "did NOT converge" in fails[0]


# --------------------------------------------------------------------------- HTML, CLI


def test_html_self_contained_sim(sim, tmp_path):
    res, path = sim
    out = render_report(res, tmp_path / "calibr.html", source=path)
    html = out.read_text(encoding="utf-8")
    assert html.startswith("<!DOCTYPE html>")
    srcs = re.findall(r'\bsrc="([^"]*)"', html)
    assert len(srcs) == 3 and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert "<link" not in html and "url(" not in html
    assert f6(res["rounds"][0]["b1"]["mean"]) in html
    assert res["record_sha256"] in html


def test_cli_report(paper, tmp_path, capsys):
    _, path = paper
    ap = argparse.ArgumentParser(prog="chekan")
    add_report_parser(ap.add_subparsers(dest="command"))
    out = tmp_path / "deep" / "c.htm"
    out.parent.mkdir()  # an output's folder must exist (none is created: test_outputs_kinds)
    args = ap.parse_args(
        ["report", str(path), "--lang", "ru", "--out", str(out), "--tolerance-percent", "0.01"]
    )
    assert args.func(args) == 0
    html = out.read_text(encoding="utf-8")
    assert "НЕ СООТВЕТСТВУЕТ (допуск 0.01 %)" in html  # 0.019 % > 0.01 %
    assert f"wrote {out}" in capsys.readouterr().out
    # default name: calibr_<serial>.<format> beside the result
    args = ap.parse_args(["report", str(path), "--format", "html"])
    assert args.func(args) == 0
    assert (path.parent / "calibr_46.html").is_file()
    with pytest.raises(SystemExit):
        ap.parse_args(["report", str(path), "--lang", "de"])


def test_calibrate_report_option(tmp_path, monkeypatch):
    """``chekan calibrate … --report`` (wired by the CLI) renders through render_report: a
    certificate with the lab file of ``$CHEKAN_LAB``, a draft without one."""
    from chekan.cli.commands import main

    out = tmp_path / "calibr_46.html"
    monkeypatch.setenv("CHEKAN_LAB", str(LAB_TOML))
    assert main(["calibrate", str(PAPER_CSV), "--quiet", "--report", str(out), "--lang", "ru"]) == 0
    html = out.read_text(encoding="utf-8")
    assert "Свидетельство о калибровке" in html and "ПРОЕКТ" not in html
    monkeypatch.delenv("CHEKAN_LAB")
    draft = tmp_path / "draft.html"
    assert main(["calibrate", str(PAPER_CSV), "-q", "--report", str(draft), "--lang", "ru"]) == 0
    assert "ПРОЕКТ — не является свидетельством о калибровке" in draft.read_text("utf-8")


# --------------------------------------------------------------------------- pdftotext cross-check


def test_pdftotext_reads_the_cyrillic(paper, outdir):
    exe = shutil.which("pdftotext")
    if exe is None:
        pytest.skip("pdftotext (poppler-utils) is not installed; the pypdf reader covers the rest")
    _, path = paper
    pdf, own_text, _, _ = pdf_of("paper", "ru", path, outdir)
    text = normalize(
        subprocess.run(
            [exe, "-layout", str(pdf), "-"], capture_output=True, text=True, check=True
        ).stdout
    )
    for s in (
        "Свидетельство о калибровке",
        "Заводской номер гравиметра",
        "СКП",
        "Приведённая погрешность δg = 0.019 %",
        "6.980339",
        "6.980343",
    ):
        assert s in text and s in own_text


# --------------------------------------------------------------------------- bad inputs


def _write(tmp_path: Path, obj) -> Path:
    p = tmp_path / "r.json"
    p.write_text(json.dumps(obj), encoding="utf-8")
    return p


def test_bad_inputs(paper, tmp_path):
    res, _ = paper
    out = tmp_path / "c.pdf"
    missing = {k: v for k, v in res.items() if k != "parameters"}
    with pytest.raises(FormatError, match=r"r\.json: missing key\(s\): parameters"):
        render_report(_write(tmp_path, missing), out)
    with pytest.raises(FormatError, match="unknown method 'magic'"):
        render_report(_write(tmp_path, dict(res, method="magic")), out)
    with pytest.raises(FormatError, match="not valid JSON"):
        (tmp_path / "bad.json").write_text("{", encoding="utf-8")
        render_report(tmp_path / "bad.json", out)
    with pytest.raises(FormatError, match="no such result file"):
        render_report(tmp_path / "none.json", out)
    with pytest.raises(ChekanError, match="unknown language 'de'"):
        render_report(res, out, lang="de")
    with pytest.raises(ChekanError, match="cannot tell the report format"):
        render_report(res, tmp_path / "c.docx")
    with pytest.raises(ChekanError, match="unknown report format"):
        render_report(res, out, fmt="docx")
    with pytest.raises(ChekanError, match="tolerance_percent must be a positive"):
        render_report(res, out, tolerance_percent=0)
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    with pytest.raises(ChekanError, match=r"file\.txt/c\.pdf: cannot write the certificate"):
        render_report(res, blocker / "c.pdf")
    with pytest.raises(ChekanError, match="is a folder"):
        render_report(res, tmp_path)
    broken = json.loads(json.dumps(res))
    del broken["residuals_mgal"]["dg_mgal"]["r2_s1"]
    with pytest.raises(
        FormatError, match=r"r\.json: residuals_mgal\.dg_mgal has no column 'r2_s1'"
    ):
        render_report(_write(tmp_path, broken), out)
    broken = json.loads(json.dumps(res))
    broken["rounds"][0]["b1"] = 6.98
    with pytest.raises(FormatError, match=r"rounds\[0\]\.b1\.mean is missing"):
        render_report(_write(tmp_path, broken), out)
    assert not out.exists()
    assert not list(tmp_path.glob(".c.pdf.*"))  # no temporary left behind


# --------------------------------------------------------------------------- rounds about X


@pytest.mark.parametrize("lang", ["en", "ru"])
def test_certificate_of_a_record_with_rounds_about_both_axes(tmp_path, lang):
    """Issue 30: the program as run (rounds with their axes, angles, dwell) in the header;
    the rounds about Y as the certificate's tables; the X rounds' own fit in its own
    labelled section; the figures drawn with each hold's axis."""
    from test_classical import _forward_record, _xy_program

    from chekan.pipeline import CalibrationOptions, calibrate_file
    from chekan.records import write_record
    from chekan.results.document import write_result

    rec, _ = _forward_record(_xy_program(round_axes=["y", "x", "x", "y"]))
    rec.meta["program"] = "xy-test"
    write_record(tmp_path / "xy.csv", rec)
    res = calibrate_file(tmp_path / "xy.csv", CalibrationOptions(progress=False))
    path = write_result(tmp_path / "xy.json", res)
    tp = res["tilt_program"]
    assert [(r["round"], r["axis"]) for r in tp["rounds"]] == [
        (1, "y"),
        (2, "x"),
        (3, "x"),
        (4, "y"),
    ]
    assert tp["dwell_s"] == 200.0 and tp["settle_s"] == 100.0 and len(tp["angles"]) == 4
    html = render_report(path, tmp_path / f"xy_{lang}.html", lang=lang).read_text(encoding="utf-8")
    text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html)).replace("&#x27;", "'")
    text = text.replace("&#39;", "'")
    want = {
        "en": [
            "xy-test — 4 rounds, each about its axis: 1 Y, 2 X, 3 X, 4 Y",
            "dwell 200 s (settling 100 s)",
            "Rounds about X: classical method, fitted apart",
            "— rounds about Y",
            "— rounds about X",
        ],
        "ru": [
            "xy-test — приёмов: 4, ось наклона каждого: 1 Y, 2 X, 3 X, 4 Y",
            "выдержка 200 с (успокоение 100 с)",
            "Приёмы с наклонами вокруг X",
        ],
    }[lang]
    for w in want:
        assert w in text, w
    assert "angles ±1°50'" in text or "углы ±1°50'" in text
    x = res["classical_by_axis"]["x"]
    for r in x["rounds"] + res["rounds"]:
        assert f6(r["b1"]["mean"]) in text and f6(r["b2"]["mean"]) in text
    assert len(re.findall(r'\bsrc="data:image/png;base64,', html)) == 3
    # a hand-edited per-axis part that cannot be right is an error naming it, not a traceback
    bad = json.loads(path.read_text(encoding="utf-8"))
    del bad["classical_by_axis"]["x"]["residuals_mgal"]["dg_mgal"]["r2_s1"]
    with pytest.raises(FormatError, match=r"classical_by_axis\.x\.residuals_mgal\.dg_mgal has no"):
        build_report(bad, figures=False)
    bad["classical_by_axis"] = {"z": {}}
    with pytest.raises(FormatError, match=r"classical_by_axis\.z: the axis must be"):
        build_report(bad, figures=False)


def _many_rounds(n_rounds: int) -> dict:
    """A classical residual table of ``n_rounds`` rounds (odd numbers, as the rounds about Y
    of an alternating program), 3 angles."""
    cols = [f"r{2 * r + 1}_s{s}" for r in range(n_rounds) for s in (1, 2)]
    val = {c: [0.1 * k + i for i in range(3)] for k, c in enumerate(cols)}
    return {
        "angle_label": ["±4°30'", "±4°51'", "±5°10'"],
        "columns": cols,
        "da_ref_mgal": [3026.9, 3515.8, 3989.6],
        "dg_mgal": val,
        "delta_g_mgal": val,
        "mean_delta_g_mgal": [1.0, 2.0, 3.0],
        "rms_mgal": {c: 0.5 for c in cols},
    }


def test_a_program_of_many_rounds_gets_its_round_tables_in_legible_parts():
    """The designer's 20-round program printed 42 numeric columns in one table (digits
    overlapping on the page): a table holds at most ROUNDS_PER_TABLE rounds, the parts
    captioned with their rounds, every column once, the mean Δg in the last part; a
    program of few rounds keeps its one table and caption."""
    from chekan.report.i18n import tr
    from chekan.report.rounds import ROUNDS_PER_TABLE, deviations_tables, increments_tables

    t = tr("en")
    rs = _many_rounds(10)
    inc = increments_tables(rs, t, "Table a")
    dev = deviations_tables(rs, t, "Table b")
    assert ROUNDS_PER_TABLE == 6 and len(inc) == len(dev) == 2
    assert [tb.caption for tb in inc] == ["Table a, rounds 1–11", "Table a, rounds 13–19"]
    assert [tb.caption for tb in dev] == ["Table b, rounds 1–11", "Table b, rounds 13–19"]
    assert [tb.ncols for tb in inc] == [2 + 12, 2 + 8]
    assert [tb.ncols for tb in dev] == [1 + 12, 1 + 8 + 1]  # the mean column once, last
    assert dev[-1].header[0][-1].text == "Mean Δg" and dev[0].header[0][-1].text != "Mean Δg"
    got = [c.text for tb in inc for c in tb.header[0][2:]]
    assert got == [f"Round {2 * r + 1}" for r in range(10)]
    assert [row[2].text for row in inc[1].rows] == ["1.20", "2.20", "3.20"]  # r13_s1's values
    few = _many_rounds(2)
    (one,) = increments_tables(few, t, "Table a")
    assert one.caption == "Table a" and one.ncols == 2 + 4
    (one,) = deviations_tables(few, t, "Table b")
    assert one.caption == "Table b" and one.ncols == 1 + 4 + 1


def test_a_figure_of_many_rounds_has_a_legend_that_leaves_room_for_its_axes():
    """Past the six round markers the legend names the rounds together, once per system
    (20 rounds gave 40 entries, collapsed the axes and a matplotlib warning on the
    terminal); up to six, one entry per round as before."""
    import warnings

    from chekan.report.figures import residual_figure, round_labels
    from chekan.report.i18n import tr

    t = tr("en")
    assert round_labels([0, 1, 2], t, 0) == {
        0: "level, system 1",
        1: "round 1, system 1",
        2: "round 2, system 1",
    }
    many = round_labels([0, *range(1, 21)], t, 1)
    assert many[0] == "level, system 2" and many[1] == "rounds 1–20, system 2"
    assert all(many[r] is None for r in range(2, 21))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # constrained_layout's "axes sizes collapsed"
        png = residual_figure(_many_rounds(10), t, tol_mgal=5.0)
    assert png.startswith(b"\x89PNG")


def test_the_cosinusoid_residuals_follow_the_sensors_lag_through_the_record():
    """A program whose settling time is short beside τ (the designer's: 120 s settle, τ
    60 s here) leaves part of each slew's transient in the hold means, several pixels: the
    figure's lower panel compares a hold mean with the model's mean over that hold with the
    lag followed (as the joint model fits it), not with the equilibrium alone. With the
    truth as the fitted model, the residuals are the noise; without the lag they were not."""
    import dataclasses

    import numpy as np

    from chekan.classical.settling import (
        fitted_model,
        lagged_hold_means,
        model_at_holds,
        unsettled_transient_pix,
    )
    from chekan.physics.program import build_program
    from chekan.records.holds import segment_record
    from chekan.records.simulate import Truth, simulate_session

    program = build_program(
        [4.5, 5 + 10 / 60], name="short-settle", axis="xy", order="alternate", rounds=2,
        dwell_s=188.0, settle_s=120.0,
    )  # fmt: skip
    truth = Truth(tau_s=60.0, angle_systematic_arcsec=0.0, drift_pix_per_h=(0.0, 0.0),
                  drift_pix_per_h2=(0.0, 0.0), hold_offset_sd_pix=0.0)  # fmt: skip
    rec, _ = simulate_session(program, truth, seed=4)
    holds = segment_record(rec, settle_s=120.0)
    g = truth.g_local_mgal
    a = g / (2.0 * truth.K_pix_per_rad**2)  # eq. 13: a = g/(2K²)
    mean = {"b1": truth.b_mgal_per_pix[0], "b2": truth.b_mgal_per_pix[1], "a": a,
            "eps1_arcmin": truth.eps_arcmin[0], "eps2_arcmin": truth.eps_arcmin[1],
            "dgamma_arcmin": truth.dgamma_arcmin, "tau_s": truth.tau_s}  # fmt: skip
    result = {
        "parameters": {k: {"mean": v} for k, v in mean.items()},
        "g_local_mgal": g,
        "level_reading_pix": {"m1": truth.m_level_pix[0], "m2": truth.m_level_pix[1]},
        "ccd_center_pix": truth.m0_pix,
    }
    params = fitted_model(result)
    m = np.asarray(holds.m_mean_pix)
    lagged = m - lagged_hold_means(params, holds, rec, truth.tau_s)
    held = m - model_at_holds(params, holds)
    assert np.nanmax(np.abs(held)) > 5.0  # the transient left in the hold means
    assert np.nanmax(np.abs(lagged)) < 0.5  # noise and angle jitter only
    gappy = dataclasses.replace(  # rows without angles, the first ones included
        rec, tilt_x_arcsec=np.where(np.arange(rec.n) % 500 < 3, np.nan, rec.tilt_x_arcsec)
    )
    again = m - lagged_hold_means(params, holds, gappy, truth.tau_s)
    assert np.all(np.isfinite(again)) and np.nanmax(np.abs(again - lagged)) < 0.01
    # the certificate warns that the classical items carry it; not where a hold settles
    from chekan.report.content import transient_note
    from chekan.report.i18n import tr

    (note,) = transient_note(result, holds, unsettled_transient_pix(result, holds, rec), tr("en"))
    assert note.kind == "warn" and "up to 48.2 pix of the slews' transients" in note.text
    assert "τ = 60.0 s" in note.text and "biased by them" in note.text
    # τ short beside the settling time: the two agree (a slow sensor is what differs)
    fast = dataclasses.replace(truth, tau_s=10.0)
    rec2, _ = simulate_session(program, fast, seed=4)
    holds2 = segment_record(rec2, settle_s=120.0)
    diff = lagged_hold_means(params, holds2, rec2, 10.0) - model_at_holds(params, holds2)
    assert np.nanmax(np.abs(diff)) < 0.05
    settled = {**result, "parameters": {**result["parameters"], "tau_s": {"mean": 10.0}}}
    assert (
        transient_note(settled, holds2, unsettled_transient_pix(settled, holds2, rec2), tr("en"))
        == []
    )
