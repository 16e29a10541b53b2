"""DCC 3.3.0 in words and inside the PDF: validated offline (no network), results named in
words with their symbol, numbers at their meaning, the angle sensors and the program as
structured data, traceability and conformity decided from the inputs, --lang honoured;
the PDF certificate is PDF/A-3b carrying the DCC and the result, and reads back."""

from __future__ import annotations

import copy
import json
import re
import shutil
import socket
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

xmlschema = pytest.importorskip("xmlschema")

from chekan.cli.commands import main  # noqa: E402
from chekan.report.dcc import DCC_NS, SI_NS, build_dcc, dcc_bytes, load_lab  # noqa: E402
from chekan.report.dcc_read import read_dcc  # noqa: E402
from chekan.report.dcc_schema import SCHEMAS, dcc_schema, validate_dcc  # noqa: E402

DATA = Path(__file__).resolve().parent / "data" / "report"
D, S = f"{{{DCC_NS}}}", f"{{{SI_NS}}}"
LAB = """\
[lab]
name = "Gravimetry Lab"
code = "GL-01"
email = "lab@example.org"
street = "Malaya Posadskaya 30"
city = "Saint Petersburg"
post_code = "197046"
country_code = "RU"
accreditation = "RA.RU.000000"

[responsible]
name = "I. Ivanov"

[customer]
name = "Customer Ltd"
city = "Moscow"
"""
SURVEY = '\n[site]\ngravity_survey = "absolute point GL-1, FG5 survey 2024-05-01"\n'
SENSOR = {
    "model": "systematic",
    "reading": "tilt_y_arcsec",
    "source": "platform specification",
    "u_per_angle_arcsec": 1.5,
    "u_scale_arcsec": 0.9,
    "bound_arcsec": 3.0,
    "distribution": "rectangular",
}
CAL = {"id": "AC-17", "date": "2026-03-02", "laboratory": "Angle Lab", "sha256": "ab" * 32}


@pytest.fixture()
def res() -> dict:
    return json.loads((DATA / "bayes_result.json").read_text(encoding="utf-8"))


def _lab(tmp_path: Path, extra: str = "") -> dict:
    p = tmp_path / "lab.toml"
    p.write_text(LAB + extra, encoding="utf-8")
    return load_lab(p)


def _root(result: dict, lab: dict, **kw) -> ET.Element:
    xml = dcc_bytes(build_dcc(result, lab, **kw))
    validate_dcc(xml)
    return ET.fromstring(xml)


def _two_axes(result: dict, calibrated: bool) -> dict:
    out = copy.deepcopy(result)
    y = dict(SENSOR, axis="y")
    x = dict(SENSOR, axis="x", reading="tilt_x_arcsec", bound_arcsec=0.5)
    if calibrated:
        for s in (x, y):
            s.pop("bound_arcsec")
            s.update(distribution="normal", calibration=CAL)
        out["angle_calibration"] = CAL
    out["angle_sensor"], out["angle_sensors"] = y, {"y": y, "x": x}
    out["pendulum_horizontal"] = {"about": "ccd_center_pix", "u_pix": 0.5, "source": "--h"}
    return out


def test_validation_reads_only_the_vendored_files_and_never_the_network(monkeypatch, res, tmp_path):
    def no_network(*a, **k):
        raise AssertionError("the DCC validation tried to reach the network")

    monkeypatch.setattr(socket, "create_connection", no_network)
    monkeypatch.setattr(socket, "getaddrinfo", no_network)
    monkeypatch.setattr(socket.socket, "connect", no_network)
    dcc_schema.cache_clear()
    schema = dcc_schema()
    urls = {ns: [s.url for s in schemas] for ns, schemas in schema.maps.namespaces.items()}
    for ns in (DCC_NS, SI_NS, "http://www.w3.org/2000/09/xmldsig#", "http://qudt.org/vocab/"):
        assert urls[ns] and all(u.startswith(SCHEMAS.as_uri()) for u in urls[ns]), (ns, urls[ns])
    root = _root(res, _lab(tmp_path))
    assert root.get("schemaVersion") == "3.3.0"
    # the QUDT schema is a local stand-in: the element it types is never written
    assert not list(root.iter(S + "quantityTypeQUDT"))
    broken = copy.deepcopy(root)
    broken.set("schemaVersion", "3.1.2")
    with pytest.raises(xmlschema.XMLSchemaValidationError):
        schema.validate(ET.tostring(broken, encoding="unicode"))


def test_results_are_named_in_words_with_their_symbol_and_numbers_at_their_meaning(res, tmp_path):
    root = _root(res, _lab(tmp_path))
    names = {r.get("refType"): r.findtext(f"{D}name/{D}content") for r in root.iter(D + "result")}
    assert names["chekan_b1"] == "b₁, scale factor of quartz system 1 at the level reading"
    assert names["chekan_b2_0"].startswith("b₂₀, scale factor of quartz system 2")
    assert names["chekan_a"].startswith("a, quadratic coefficient")
    assert not [n for n in names.values() if re.search(r"\b(b1|b2|b1_0|eps1_arcmin)\b", n)]
    g = root.find(f".//{D}quantity[@refType='chekan_g_local']")
    assert [r.findtext(S + "value") for r in g.iter(S + "real")] == ["981922.05", "9.8192205"]
    values = [v.text or "" for v in root.iter(S + "value")]
    values += [v.text or "" for v in root.iter(S + "valueExpandedMU")]
    noisy = [v for v in values if re.search(r"(0000000|9999999)\d$", v)]
    assert not noisy, noisy
    b1 = root.find(f".//{D}quantity[@refType='chekan_b1']")
    si = b1.findall(f"{S}hybrid/{S}real")[1]
    assert si.findtext(S + "value") == "0.00006980412"
    assert si.findtext(f".//{S}valueExpandedMU") == "2.1e-9"
    # an optional element that is unknown is left out, never filled with "not stated"
    assert "not stated" not in ET.tostring(root, encoding="unicode")


def test_customer_without_email_has_no_email_element(res, tmp_path):
    root = _root(res, _lab(tmp_path))
    cust = root.find(f".//{D}customer")
    assert cust.find(D + "eMail") is None
    assert cust.findtext(f"{D}location/{D}city") == "Moscow"


def test_angle_sensors_and_program_are_structured(res, tmp_path):
    r = _two_axes(res, calibrated=False)
    r["tilt_program"] = {
        "name": "short",
        "source": "record",
        "rounds": [{"round": 1, "axis": "y", "angles": ["2°30'", "4°10'", "5°10'"]}],
        "angles": ["2°30'", "4°10'", "5°10'"],
        "dwell_s": 240.0,
        "settle_s": 150.0,
    }
    root = _root(r, _lab(tmp_path))
    ic = root.find(f".//{D}influenceCondition[@refType='chekan_angleSensors']")
    whole = ET.tostring(ic, encoding="unicode")
    assert "{" not in whole and '"bound_arcsec"' not in whole  # no raw JSON
    lists = {el.get("refType"): el for el in ic.iter(D + "list")}
    assert set(lists) == {"chekan_angleSensor_x", "chekan_angleSensor_y"}
    bound_x = lists["chekan_angleSensor_x"].find(
        f"{D}quantity[@refType='chekan_angleSensor_x_bound']"
    )
    reals = bound_x.findall(f"{S}hybrid/{S}real")
    assert reals[0].findtext(S + "value") == "0.5"
    assert [x.findtext(S + "unit") for x in reals] == ["|arcsecond", r"\radian"]
    assert float(reals[1].findtext(S + "value")) == pytest.approx(0.5 * 4.84813681109536e-6)
    assert "not calibrated" in "".join(lists["chekan_angleSensor_y"].itertext())
    hz = root.find(f".//{D}influenceCondition[@refType='chekan_pendulumHorizontal']")
    assert hz.findtext(f".//{D}quantity[@refType='chekan_horizontal_u_pix']//{S}value") == "0.5"
    um = root.find(f".//{D}usedMethod")
    rnd = um.find(f".//{D}usedMethodQuantity[@refType='chekan_round_1']")
    lists_xml = rnd.findall(f"{S}hybrid/{S}realListXMLList")
    assert lists_xml[0].findtext(S + "valueXMLList") == "150 250 310"
    assert lists_xml[0].findtext(S + "unitXMLList") == r"\arcminute"
    dwell = um.find(f".//{D}usedMethodQuantity[@refType='chekan_dwell_s']/{S}real")
    assert (dwell.findtext(S + "value"), dwell.findtext(S + "unit")) == ("240.0", r"\second")


def _trace(root: ET.Element) -> tuple[str, str]:
    st = root.find(f".//{D}statement[@refType='basic_traceability']")
    return st.findtext(D + "traceable"), st.findtext(f"{D}declaration/{D}content")


def test_traceable_only_when_every_input_is(res, tmp_path):
    """The angle on a specification bound, or no gravity survey named: false, with why."""
    spec = _trace(_root(_two_axes(res, calibrated=False), _lab(tmp_path, SURVEY)))
    assert spec[0] == "false" and "specification bound" in spec[1] and "X and Y" in spec[1]
    no_survey = _trace(_root(_two_axes(res, calibrated=True), _lab(tmp_path)))
    assert no_survey[0] == "false" and "no gravity survey is named" in no_survey[1]
    both = _root(_two_axes(res, calibrated=True), _lab(tmp_path, SURVEY))
    ok = _trace(both)
    assert ok[0] == "true" and "AC-17 of 2026-03-02 (Angle Lab)" in ok[1]
    assert "FG5 survey 2024-05-01" in ok[1]
    cert = both.find(f".//{D}influenceCondition[@refType='chekan_angleSensors']/{D}certificate")
    assert cert.findtext(D + "value") == "ab" * 32 and cert.findtext(D + "procedure") == "SHA-256"
    unstated = _trace(_root(res, _lab(tmp_path, SURVEY)))  # no angle model in the result
    assert unstated[0] == "false" and "no model of the tilt angles" in unstated[1]


@pytest.mark.parametrize(
    ("tolerance", "want"),
    [(0.05, "pass"), (0.033, "conditionalPass"), (0.03, "conditionalFail"), (0.02, "fail")],
)
def test_conformity_is_stated_with_the_guard_band(res, tmp_path, tolerance, want):
    """b₂'s instability 0.0319 % with U = 0.0032 %: against T the guard band w = U decides."""
    r = copy.deepcopy(res)
    r["diagnostics"]["problems"] = []
    root = _root(r, _lab(tmp_path), tolerance_percent=tolerance)
    st = root.find(f".//{D}statement[@refType='basic_conformity']")
    assert st.findtext(D + "conformity") == want
    assert "guard band w = U" in st.findtext(f"{D}declaration/{D}content")


def test_problems_of_the_diagnostics_bar_a_conformity_statement(res, tmp_path):
    st = _root(res, _lab(tmp_path)).find(f".//{D}statement[@refType='basic_conformity']")
    assert st.find(D + "conformity") is None
    assert "No statement of conformity: the diagnostics report problems (τ (time constant)" in (
        st.findtext(f"{D}declaration/{D}content")
    )


def test_lang_ru_writes_russian_first_and_english_beside(res, tmp_path):
    src = tmp_path / "r.json"
    shutil.copy(DATA / "bayes_result.json", src)
    (tmp_path / "lab.toml").write_text(LAB, encoding="utf-8")
    out = tmp_path / "ru.xml"
    assert main(["report", str(src), "--lab", str(tmp_path / "lab.toml"), "-o", str(out),
                 "--lang", "ru", "-q"]) == 0  # fmt: skip
    validate_dcc(out)
    root = ET.parse(out).getroot()
    core = root.find(f"{D}administrativeData/{D}coreData")
    assert [e.text for e in core.findall(D + "usedLangCodeISO639_1")] == ["ru", "en"]
    assert core.findtext(D + "mandatoryLangCodeISO639_1") == "ru"
    b1 = root.find(f".//{D}result[@refType='chekan_b1']/{D}name")
    assert [(c.get("lang"), c.text[:40]) for c in b1] == [
        ("ru", "b₁, масштабный коэффициент кварцевой сис"),
        ("en", "b₁, scale factor of quartz system 1 at t"),
    ]
    for el in root.iter():  # every text in words has its Russian form
        langs = [c.get("lang") for c in el.findall(D + "content") if c.get("lang")]
        assert not langs or langs[0] == "ru", (el.tag, langs)
    assert read_dcc(out) == json.loads(src.read_text(encoding="utf-8"))


# ----------------------------------------------------------------------------- the PDF


def _attachments(pdf: Path) -> tuple[dict[str, bytes], dict[str, str], str]:
    pypdf = pytest.importorskip("pypdf")
    reader = pypdf.PdfReader(pdf)
    files = {k: v[0] for k, v in reader.attachments.items()}
    catalog = reader.trailer["/Root"]
    rel = {str(fs.get_object()["/F"]): str(fs.get_object()["/AFRelationship"])
           for fs in catalog["/AF"]}  # fmt: skip
    xmp = catalog["/Metadata"].get_object().get_data().decode("utf-8")
    return files, rel, xmp


def test_pdf_certificate_is_pdf_a3_with_the_dcc_and_the_result(res, tmp_path):
    pytest.importorskip("typst")
    src = tmp_path / "r.json"
    shutil.copy(DATA / "bayes_result.json", src)
    (tmp_path / "lab.toml").write_text(LAB, encoding="utf-8")
    pdf = tmp_path / "cert.pdf"
    assert main(["report", str(src), "--lab", str(tmp_path / "lab.toml"), "-o", str(pdf),
                 "-q"]) == 0  # fmt: skip
    files, rel, xmp = _attachments(pdf)
    assert set(files) == {"dcc.xml", "chekan-result.json"}
    assert rel == {"dcc.xml": "/Alternative", "chekan-result.json": "/Source"}
    assert re.search(r"pdfaid:part>3<", xmp) and re.search(r"pdfaid:conformance>B<", xmp)
    validate_dcc(files["dcc.xml"])
    assert json.loads(files["chekan-result.json"]) == res
    (tmp_path / "inner.xml").write_bytes(files["dcc.xml"])
    assert read_dcc(tmp_path / "inner.xml") == res
    # chekan report reads the result back out of the PDF: into a DCC, and a new PDF
    back = tmp_path / "back.xml"
    assert main(["report", str(pdf), "--lab", str(tmp_path / "lab.toml"), "-o", str(back),
                 "-q"]) == 0  # fmt: skip
    assert read_dcc(back) == res
    again = tmp_path / "again.pdf"
    assert main(["report", str(pdf), "-o", str(again), "-q", "--lang", "ru"]) == 0
    files2, _, _ = _attachments(again)
    assert json.loads(files2["chekan-result.json"]) == res
    assert "dcc.xml" not in files2  # no lab file: no DCC (it needs the issuer), the result only


def test_pdf_whose_dcc_and_result_disagree_is_refused(res, tmp_path, capsys):
    pytest.importorskip("typst")
    from chekan.report.document import Para, Report
    from chekan.report.pdf_certificate import certificate_attachments
    from chekan.report.typst_pdf import Attachment, render_pdf

    lab = _lab(tmp_path)
    other = copy.deepcopy(res)
    other["parameters"]["b1"]["mean"] = 6.9
    atts = certificate_attachments(res, lab, None, 0.05, "en")
    wrong = [a if a.name == "dcc.xml" else Attachment(a.name, json.dumps(other).encode(),
             a.mime_type, a.relationship, a.description) for a in atts]  # fmt: skip
    rep = Report("en", "T", "S", "H", [Para("x")])
    pdf = tmp_path / "bad.pdf"
    pdf.write_bytes(render_pdf(rep, attachments=wrong))
    assert main(["report", str(pdf), "-o", str(tmp_path / "x.xml"), "--lab",
                 str(tmp_path / "lab.toml")]) == 2  # fmt: skip
    assert "dcc.xml and chekan-result.json disagree" in capsys.readouterr().err
    plain = tmp_path / "plain.pdf"
    plain.write_bytes(render_pdf(rep))
    assert main(["report", str(plain), "-o", str(tmp_path / "y.xml")]) == 2
    assert "carries no chekan-result.json" in capsys.readouterr().err
