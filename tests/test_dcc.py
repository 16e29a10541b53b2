"""The Digital Calibration Certificate (PTB DCC 3.3.0): valid against the vendored XSDs
(offline), the numbers equal the result JSON's, it reads back into the same archive row,
and a certificate without a lab file is refused."""

from __future__ import annotations

import json
import shutil
import sqlite3
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

xmlschema = pytest.importorskip("xmlschema")

from chekan.cli.commands import main  # noqa: E402
from chekan.report.dcc import DCC_NS, SI_NS, dcc_schema, validate_dcc  # noqa: E402
from chekan.report.dcc_read import is_dcc, read_dcc  # noqa: E402

DATA = Path(__file__).resolve().parent / "data" / "report"
# where an si:real states its expanded uncertainty (D-SI 2.2.1: si:expandedMU)
_MU = f"{{{SI_NS}}}measurementUncertaintyUnivariate/{{{SI_NS}}}expandedMU/{{{SI_NS}}}"
UNC, UNC_K, UNC_DIST = _MU + "valueExpandedMU", _MU + "coverageFactor", _MU + "distribution"
LAB = """\
[lab]
name = "Gravimetry Lab <A&B> \\"north\\""
code = "GL-01"
email = "lab@example.org"
street = "Malaya Posadskaya 30"
city = "Saint Petersburg"
post_code = "197046"
country_code = "RU"
accreditation = "RA.RU.000000"

[responsible]
name = "I. Ivanov"
role = "head of the laboratory"

[customer]
name = "Customer & Co <x>"
city = "Moscow"
country_code = "RU"
"""


@pytest.fixture()
def lab(tmp_path) -> Path:
    p = tmp_path / "lab.toml"
    p.write_text(LAB, encoding="utf-8")
    return p


@pytest.fixture()
def bayes_json(tmp_path) -> Path:
    """The hand-made Bayesian result of the report tests (with an uncertainty budget)."""
    p = tmp_path / "bayes_result.json"
    shutil.copy(DATA / "bayes_result.json", p)
    return p


@pytest.fixture(scope="module")
def sim_bayes_json(tmp_path_factory) -> Path:
    """A bayes result (--quick) of the short simulated session (seed 7)."""
    pytest.importorskip("chekan.joint")
    from chekan.demo import demo_program
    from chekan.pipeline import CalibrationOptions, calibrate_file
    from chekan.records import write_record
    from chekan.records.simulate import Truth, simulate_session
    from chekan.results.document import write_result

    d = tmp_path_factory.mktemp("simbayes")
    rec, _ = simulate_session(demo_program(quick=True), Truth(serial="T-1"), seed=7)
    write_record(d / "rec.csv", rec)
    opts = CalibrationOptions(method="bayes", settle_s=200, quick=True, progress=False, seed=2)
    return write_result(d / "bayes.json", calibrate_file(d / "rec.csv", opts))


@pytest.fixture(scope="module")
def sim_map_json(tmp_path_factory) -> Path:
    """A MAP result of the short simulated session (seed 7): its U has k = t₉₅.₄₅(ν_eff)."""
    from chekan.demo import demo_program
    from chekan.pipeline import CalibrationOptions, calibrate_file
    from chekan.records import write_record
    from chekan.records.simulate import Truth, simulate_session
    from chekan.results.document import write_result

    d = tmp_path_factory.mktemp("simmap")
    rec, _ = simulate_session(demo_program(quick=True), Truth(serial="T-1"), seed=7)
    write_record(d / "rec.csv", rec)
    opts = CalibrationOptions(method="map", settle_s=200, progress=False)
    return write_result(d / "map.json", calibrate_file(d / "rec.csv", opts))


def _dcc(result_json: Path, lab: Path, out: Path, *extra: str) -> Path:
    rc = main(["report", str(result_json), "--lab", str(lab), "-o", str(out), *extra])
    assert rc == 0
    return out


def _reals(xml: Path) -> dict[str, ET.Element]:
    """The first (own-unit) si:real of each result quantity, by parameter name."""
    root = ET.parse(xml).getroot()
    out = {}
    for q in root.iter(f"{{{DCC_NS}}}quantity"):
        real = q.find(f"{{{SI_NS}}}hybrid/{{{SI_NS}}}real")
        out[(q.get("refType") or "").removeprefix("chekan_")] = real
    return out


def test_dcc_of_a_simulated_bayes_session_validates_and_carries_b1_and_u(
    sim_bayes_json, lab, tmp_path
):
    res = json.loads(sim_bayes_json.read_text(encoding="utf-8"))
    assert res["method"] == "bayes"
    out = _dcc(sim_bayes_json, lab, tmp_path / "c.xml")
    validate_dcc(out)
    reals = _reals(out)
    b1 = reals["b1"]
    assert float(b1.findtext(f"{{{SI_NS}}}value")) == res["parameters"]["b1"]["mean"]
    u = float(b1.findtext(UNC))
    assert u == res["uncertainty_budget"]["b1"]["expanded"]
    assert float(b1.findtext(UNC_K)) == 2.0
    for name in ("b2", "a", "b1_0", "b2_0"):
        assert float(reals[name].findtext(f"{{{SI_NS}}}value")) == res["parameters"][name]["mean"]
    assert read_dcc(out) == res
    # the sensor temperature comes from the record's temp_c column (the simulator's 45 °C)
    temp = res["sensor_temperature_c"]
    assert 44.9 < temp["min"] <= temp["mean"] <= temp["max"] < 45.1
    assert f"{temp['mean']:.2f} °C" in out.read_text(encoding="utf-8")


def test_dcc_of_a_map_result_states_its_coverage_factor(sim_map_json, lab, tmp_path):
    """A MAP's U rests on variances estimated from the record: the DCC carries its k
    (Student's t at ν_eff, not 2) and U = k·u, and reads back into the same result."""
    from inference.dof import coverage_factor

    res = json.loads(sim_map_json.read_text(encoding="utf-8"))
    out = _dcc(sim_map_json, lab, tmp_path / "m.xml")
    validate_dcc(out)
    reals = _reals(out)
    for name in ("b1", "b2"):
        bud = res["uncertainty_budget"][name]
        k = float(reals[name].findtext(UNC_K))
        assert k == bud["coverage_factor"] == coverage_factor(bud["nu_eff"]) > 2.0
        u = float(reals[name].findtext(UNC))
        assert u == bud["expanded"] == pytest.approx(k * bud["total"], rel=1e-12)
        assert reals[name].findtext(UNC_DIST) == "t"
    a = reals["a"].findtext(UNC_K)
    assert float(a) == coverage_factor(res["parameters"]["a"]["nu_eff"])
    assert read_dcc(out)["parameters"]["b1"] == res["parameters"]["b1"]


def test_dcc_header_is_escaped_and_complete(bayes_json, lab, tmp_path):
    res = json.loads(bayes_json.read_text(encoding="utf-8"))
    out = _dcc(bayes_json, lab, tmp_path / "c.xml")
    validate_dcc(out)
    text = out.read_text(encoding="utf-8")
    assert "Gravimetry Lab &lt;A&amp;B&gt;" in text and "Customer &amp; Co &lt;x&gt;" in text
    root = ET.parse(out).getroot()
    d = f"{{{DCC_NS}}}"
    assert root.get("schemaVersion") == "3.3.0"
    ids = [el.text for el in root.iter(d + "value")]
    assert res["serial"] in ids and res["metadata"]["platform_serial"] in ids
    assert root.findtext(f".//{d}respPerson/{d}person/{d}name/{d}content") == "I. Ivanov"
    assert root.findtext(f".//{d}coreData/{d}beginPerformanceDate") == res["date"]
    uid = root.findtext(f".//{d}coreData/{d}uniqueIdentifier")
    assert uid.startswith("GL-01-") and res["record_sha256"][:16] in uid
    refs = {st.get("refType") for st in root.iter(d + "statement")}
    assert {"basic_traceability", "basic_itemOnly", "basic_conformity"} <= refs
    conf = [st for st in root.iter(d + "statement") if st.get("refType") == "basic_conformity"]
    assert "simple acceptance" in ET.tostring(conf[0], encoding="unicode")
    # the budget's U (not 2·sd of something else) and the SI value beside the mGal one
    b1 = root.find(f".//{d}quantity[@refType='chekan_b1']")
    reals = b1.findall(f"{{{SI_NS}}}hybrid/{{{SI_NS}}}real")
    assert float(reals[0].findtext(UNC)) == 0.00021
    assert float(reals[1].findtext(f"{{{SI_NS}}}value")) == pytest.approx(6.980412e-5, rel=1e-15)
    assert reals[1].findtext(f"{{{SI_NS}}}unit").startswith(r"\metre\second\tothe{-2}")


def test_schema_rejects_a_broken_dcc(bayes_json, lab, tmp_path):
    """The validator is real: a DCC without its coreData fails."""
    out = _dcc(bayes_json, lab, tmp_path / "c.xml")
    root = ET.parse(out).getroot()
    adm = root.find(f"{{{DCC_NS}}}administrativeData")
    adm.remove(adm.find(f"{{{DCC_NS}}}coreData"))
    with pytest.raises(xmlschema.XMLSchemaValidationError):
        dcc_schema().validate(ET.tostring(root, encoding="unicode"))


def test_missing_lab_file_is_refused(bayes_json, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("CHEKAN_LAB", raising=False)
    out = tmp_path / "c.xml"
    assert main(["report", str(bayes_json), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--lab" in err and "CHEKAN_LAB" in err and "[responsible] name" in err
    assert not out.exists()


def test_lab_file_from_env_and_malformed_lab_file(bayes_json, lab, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("CHEKAN_LAB", str(lab))
    assert main(["report", str(bayes_json), "--format", "dcc", "-o", str(tmp_path / "a")]) == 0
    validate_dcc(tmp_path / "a")
    bad = tmp_path / "bad.toml"
    bad.write_text(LAB.replace('email = "lab@example.org"\n', "").replace("[responsible]", "[x]"))
    assert main(["report", str(bayes_json), "--lab", str(bad), "-o", str(tmp_path / "b.xml")]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "[lab] email" in err and "[responsible] name" in err
    bad.write_text("[lab\nname = 1\n")
    assert main(["report", str(bayes_json), "--lab", str(bad), "-o", str(tmp_path / "b.xml")]) == 2
    assert "not valid TOML" in capsys.readouterr().err


def test_customer_option_overrides_the_lab_file(bayes_json, lab, tmp_path):
    out = _dcc(bayes_json, lab, tmp_path / "c.xml", "--customer", "Other Ltd")
    root = ET.parse(out).getroot()
    d = f"{{{DCC_NS}}}"
    assert root.findtext(f".//{d}customer/{d}name/{d}content") == "Other Ltd"


def _rows(db: Path) -> tuple[list, list]:
    con = sqlite3.connect(db)
    s = con.execute(
        "SELECT instrument_id, input_path, input_sha256, input_kind, calibrated_on,"
        " metadata_json, method, software_version, created, result_json FROM sessions"
    ).fetchall()
    p = con.execute(
        "SELECT name, mean, sd, hdi_low, hdi_high, unit, r_hat, ess_bulk, fixed FROM parameters"
        " ORDER BY name"
    ).fetchall()
    con.close()
    return s, p


def test_archive_add_of_the_dcc_gives_the_json_row(bayes_json, lab, tmp_path, capsys):
    out = _dcc(bayes_json, lab, tmp_path / "c.xml")
    assert is_dcc(out) and not is_dcc(bayes_json)
    (tmp_path / "posterior.nc").write_bytes(b"")  # archive add copies the NetCDF it names
    assert main(["archive", "add", str(bayes_json), "--db", str(tmp_path / "j.db")]) == 0
    assert main(["archive", "add", str(out), "--db", str(tmp_path / "d.db")]) == 0
    sj, pj = _rows(tmp_path / "j.db")
    sd, pd = _rows(tmp_path / "d.db")
    assert len(sj) == 1 and sj == sd
    assert len(pj) >= 5 and pj == pd


def test_tampered_dcc_is_refused(bayes_json, lab, tmp_path, capsys):
    out = _dcc(bayes_json, lab, tmp_path / "c.xml")
    text = out.read_text(encoding="utf-8").replace(
        "<si:value>6.980412</si:value>", "<si:value>6.980413</si:value>", 1
    )
    out.write_text(text, encoding="utf-8")
    assert main(["archive", "add", str(out), "--db", str(tmp_path / "d.db")]) == 1
    assert "b1: the DCC's value differs" in capsys.readouterr().err


@pytest.mark.parametrize("lang", ["en", "ru"])
def test_pdf_states_what_iso_17025_7_8_asks(bayes_json, lab, tmp_path, lang):
    """Identifier and page on every page, a clear end, lab, customer, authoriser, date of
    issue, item condition, environment, item-only statement and the decision rule."""
    pypdf = pytest.importorskip("pypdf")
    pytest.importorskip("typst")
    from chekan.report.i18n import tr

    out = tmp_path / "c.pdf"
    assert main(["report", str(bayes_json), "--lab", str(lab), "-o", str(out), "--lang", lang]) == 0
    pages = [" ".join(p.extract_text().split()) for p in pypdf.PdfReader(out).pages]
    t = tr(lang)
    uid = pages[0].split(t("cert_id"), 1)[1].split()[0]
    assert uid.startswith("GL-01-B-7")
    for i, text in enumerate(pages, start=1):
        assert f"— {i} / {len(pages)}" in text and "GL-01-B-7 #1" in text
    assert " ".join(t("cert_end", id="").split()).rstrip(".") in pages[-1]
    whole = " ".join(pages)
    for key in ("issue_date", "issuer", "customer", "authoriser", "item_condition", "environment"):
        assert t(key) in whole, key
    for needle in ("Gravimetry Lab <A&B>", "Customer & Co <x>", "I. Ivanov", "RA.RU.000000"):
        assert needle in whole
    assert " ".join(t("only_item").split()) in whole
    assert " ".join(t("decision_rule").split())[:60] in whole


def test_dcc_states_that_the_classical_items_come_from_settled_hold_means(
    bayes_json, lab, tmp_path
):
    """A joint result whose hold means were unsettled (chekan.results.document.settled_items): the
    DCC's method description says so with Calibr.exe's raw figures, as the PDF does, and
    the result it embeds keeps them."""
    res = json.loads(bayes_json.read_text(encoding="utf-8"))
    raw_b = {k: {**res["parameters"][k], "mean": res["parameters"][k]["mean"] * 1.003}
             for k in ("b1", "b2")}  # fmt: skip
    res["hold_transient"] = {
        "max_pix": 3.91,
        "tau_s": 30.0,
        "settle_s": 120.0,
        "calibr_exe": {**raw_b, "reduced_error_percent": 0.0957},
    }
    src = tmp_path / "settled.json"
    src.write_text(json.dumps(res), encoding="utf-8")
    out = _dcc(src, lab, tmp_path / "s.xml")
    validate_dcc(out)
    root = ET.parse(out).getroot()
    method = root.find(f".//{{{DCC_NS}}}usedMethod/{{{DCC_NS}}}description")
    assert method is not None
    texts = [c.text or "" for c in method.iter(f"{{{DCC_NS}}}content")]
    (note,) = [x for x in texts if "hold means carried up to 3.91 pix" in x]
    assert "τ = 30.0 s" in note and "reduced error 0.096 %" in note
    assert f"b₁ = {raw_b['b1']['mean']:.6f}" in note
    assert read_dcc(out)["hold_transient"] == res["hold_transient"]


def test_a_classical_dcc_states_no_expanded_uncertainty(lab, tmp_path, paper_protocol):
    """Calibr.exe's 2s is a repeatability, not an expanded uncertainty: the classical DCC
    gives b₁, b₂ without one (before, it wrote 2·sd as si:expandedMU), and it reads back."""
    res, out = tmp_path / "r.json", tmp_path / "c.xml"
    assert main(["calibrate", str(paper_protocol), "-q", "-o", str(res)]) == 0
    assert main(["report", str(res), "--lab", str(lab), "-q", "--out", str(out)]) == 0
    validate_dcc(out.read_bytes())
    reals = ET.parse(out).getroot().iter(f"{{{SI_NS}}}real")
    labels = {r.findtext(f"{{{SI_NS}}}label") for r in reals}
    assert {"b1", "b2"} <= labels
    assert not list(ET.parse(out).getroot().iter(f"{{{SI_NS}}}expandedMU"))
    assert read_dcc(out)["method"] == "classical"
