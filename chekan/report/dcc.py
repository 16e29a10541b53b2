"""The Digital Calibration Certificate (PTB DCC 3.1.2, D-SI 2.1.0) of a chekan-result/1.

Built with :mod:`xml.etree.ElementTree` (escaping by the library). Numbers are written
with ``repr`` precision, so that :mod:`chekan.report.dcc_read` reads them back exactly.
The expanded uncertainty is the certificate's: U = k·u with k = 2 (u from the uncertainty
budget for b₁, b₂ when present, else the standard deviation), p = 0.9545 (normal).
"""

from __future__ import annotations

import base64
import datetime as _dt
import json
import math
import os
import tomllib
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from chekan.errors import ChekanError
from chekan.report.issue import certificate_id, temperature_text

DCC_NS = "https://ptb.de/dcc"
SI_NS = "https://ptb.de/si"
SCHEMA_VERSION = "3.1.2"
SCHEMAS = Path(__file__).resolve().parent / "schemas"
SI_LOCATION = "https://ptb.de/si/v2.1.0/SI_Format.xsd"
K_COVERAGE = 2.0
P_COVERAGE = 0.9545
MGAL_TO_SI = 1e-5  # 1 mGal = 1e-5 m s^-2
LAB_ENV = "CHEKAN_LAB"
EMBEDDED_NAME = "chekan-result.json"
# parameter → (unit in the hybrid's mGal real, the SI real's unit, the SI factor)
UNITS = {
    "mGal/pix": (r"|mGal\per|pixel", r"\metre\second\tothe{-2}\per|pixel", MGAL_TO_SI),
    "mGal/pix^2": (
        r"|mGal\per|pixel\tothe{2}",
        r"\metre\second\tothe{-2}\per|pixel\tothe{2}",
        1e-5,
    ),
    "arcmin": (r"|arcminute", r"\radian", math.pi / 10800.0),
}
RESULT_PARAMS = ("b1", "b2", "a", "b1_0", "b2_0")

ET.register_namespace("dcc", DCC_NS)
ET.register_namespace("si", SI_NS)

LAB_REQUIRED = ("name", "email", "street", "city", "post_code", "country_code", "accreditation")


def _d(tag: str) -> str:
    return f"{{{DCC_NS}}}{tag}"


def _s(tag: str) -> str:
    return f"{{{SI_NS}}}{tag}"


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    el = ET.SubElement(parent, tag, attrib)
    if text is not None:
        el.text = text
    return el


def _text(parent: ET.Element, tag: str, content: str, lang: str = "en") -> ET.Element:
    """A dcc:textType element with one ``dcc:content``."""
    el = _sub(parent, _d(tag))
    _sub(el, _d("content"), content, lang=lang)
    return el


# ----------------------------------------------------------------------------- lab file


def load_lab(path: str | os.PathLike | None) -> dict[str, Any]:
    """The lab configuration (TOML) at ``path`` or ``$CHEKAN_LAB``; ChekanError naming
    what is missing or wrong."""
    where = path if path is not None else os.environ.get(LAB_ENV)
    if not where:
        raise ChekanError(
            "a DCC needs the calibration laboratory's identity: give the lab file "
            f"(--lab lab.toml) or set ${LAB_ENV}; missing: [lab] {', '.join(LAB_REQUIRED)} "
            "and [responsible] name"
        )
    p = Path(where)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ChekanError(f"{p}: no such lab file") from None
    except tomllib.TOMLDecodeError as e:
        raise ChekanError(f"{p}: not valid TOML: {e}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ChekanError(f"{p}: cannot read the lab file: {e}") from None
    lab = data.get("lab")
    resp = data.get("responsible")
    missing = []
    if not isinstance(lab, dict):
        missing += [f"[lab] {k}" for k in LAB_REQUIRED]
        lab = {}
    else:
        missing += [f"[lab] {k}" for k in LAB_REQUIRED if not _nonempty(lab.get(k))]
    if not isinstance(resp, dict) or not _nonempty(resp.get("name")):
        missing.append("[responsible] name")
    if missing:
        raise ChekanError(f"{p}: lab file lacks {', '.join(missing)}")
    cust = data.get("customer")
    if cust is not None and (not isinstance(cust, dict) or not _nonempty(cust.get("name"))):
        raise ChekanError(f"{p}: [customer] must be a table with a name")
    if not (isinstance(lab["country_code"], str) and len(lab["country_code"]) == 2):
        raise ChekanError(f"{p}: [lab] country_code must be two letters (ISO 3166-1)")
    return data


def _nonempty(v: Any) -> bool:
    return isinstance(v, str | int) and str(v).strip() != ""


# ----------------------------------------------------------------------------- numbers


def expanded_uncertainties(result: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
    """(U, k) of each result parameter, as the PDF certificate states it
    (:func:`chekan.report.expanded.expanded_of`)."""
    from chekan.report.expanded import expanded_of

    params = result["parameters"]
    out: dict[str, tuple[float, float]] = {}
    for name in RESULT_PARAMS:
        if name not in params:
            continue
        big_u, k = expanded_of(result, name)
        if big_u is not None:
            out[name] = (float(big_u), float(k))
    return out


def _real(
    parent: ET.Element,
    label: str,
    value: float,
    unit: str,
    big_u: float | None,
    k: float = K_COVERAGE,
) -> None:
    r = _sub(parent, _s("real"))
    _sub(r, _s("label"), label)
    _sub(r, _s("value"), repr(float(value)))
    _sub(r, _s("unit"), unit)
    if big_u is not None:
        e = _sub(r, _s("expandedUnc"))
        _sub(e, _s("uncertainty"), repr(float(big_u)))
        _sub(e, _s("coverageFactor"), repr(float(k)))
        _sub(e, _s("coverageProbability"), repr(P_COVERAGE))
        _sub(e, _s("distribution"), "normal" if k == K_COVERAGE else "t")


def _hybrid_quantity(
    parent: ET.Element,
    name: str,
    label: str,
    value: float,
    unit: str,
    expanded: tuple[float, float] | None,
) -> None:
    """A dcc:quantity with an si:hybrid: the value in ``unit`` and in SI beside it, with
    ``expanded`` = (U, k) when it has one."""
    q = _sub(parent, _d("quantity"), refType=f"chekan_{name}")
    _text(q, "name", label)
    h = _sub(q, _s("hybrid"))
    own, si_unit, factor = UNITS[unit]
    big_u, k = expanded if expanded is not None else (None, K_COVERAGE)
    _real(h, name, value, own, big_u, k)
    _real(h, name, value * factor, si_unit, None if big_u is None else big_u * factor, k)


# ----------------------------------------------------------------------------- the document


def build_dcc(
    result: Mapping[str, Any],
    lab: Mapping[str, Any],
    *,
    customer: str | None = None,
    issued: _dt.date | None = None,
    decision_rule: str | None = None,
) -> ET.ElementTree:
    """The DCC element tree of ``result`` issued by ``lab`` (a :func:`load_lab` dict)."""
    from chekan import __version__

    issued = issued or _dt.datetime.now(_dt.UTC).date()
    root = ET.Element(_d("digitalCalibrationCertificate"), schemaVersion=SCHEMA_VERSION)
    adm = _sub(root, _d("administrativeData"))
    sw = _sub(_sub(adm, _d("dccSoftware")), _d("software"))
    _text(sw, "name", "chekan")
    _sub(sw, _d("release"), __version__)
    _core_data(adm, result, lab, issued)
    _items(adm, result)
    _laboratory(adm, lab["lab"])
    rp = _sub(_sub(adm, _d("respPersons")), _d("respPerson"))
    _text(_sub(rp, _d("person")), "name", str(lab["responsible"]["name"]))
    if _nonempty(lab["responsible"].get("role")):
        _sub(rp, _d("role"), str(lab["responsible"]["role"]))
    _sub(rp, _d("mainSigner"), "true")
    cust = dict(lab.get("customer") or {})
    if customer:
        cust = {"name": customer}
    _contact(_sub(adm, _d("customer")), cust or {"name": "not stated"})
    _statements(adm, result, lab, decision_rule)
    _measurement_results(root, result)
    return ET.ElementTree(root)


def _session_date(result: Mapping[str, Any], issued: _dt.date) -> str:
    for key in ("date",):
        v = result.get(key)
        if isinstance(v, str) and len(v) >= 10:
            return v[:10]
    started = (result.get("metadata") or {}).get("started")
    if isinstance(started, str) and len(started) >= 10:
        return started[:10]
    return issued.isoformat()


def _core_data(
    adm: ET.Element, result: Mapping[str, Any], lab: Mapping[str, Any], issued: _dt.date
) -> None:
    core = _sub(adm, _d("coreData"))
    _sub(core, _d("countryCodeISO3166_1"), str(lab["lab"]["country_code"]).upper())
    _sub(core, _d("usedLangCodeISO639_1"), "en")
    _sub(core, _d("mandatoryLangCodeISO639_1"), "en")
    _sub(core, _d("uniqueIdentifier"), certificate_id(result, lab, issued))
    ids = _sub(core, _d("identifications"))
    ident = _sub(ids, _d("identification"))
    _sub(ident, _d("issuer"), "calibrationLaboratory")
    _sub(ident, _d("value"), issued.isoformat())
    _text(ident, "name", "date of issue")
    day = _session_date(result, issued)
    _sub(core, _d("beginPerformanceDate"), day)
    _sub(core, _d("endPerformanceDate"), day)
    _sub(core, _d("performanceLocation"), "laboratory")


def _items(adm: ET.Element, result: Mapping[str, Any]) -> None:
    meta = result.get("metadata") or {}
    items = _sub(adm, _d("items"))
    for label, model, serial in (
        ("gravimeter", str(meta.get("instrument") or "Chekan-AM"), str(result["serial"])),
        ("tilting platform", "platform", meta.get("platform_serial")),
    ):
        if serial is None:
            continue
        it = _sub(items, _d("item"))
        _text(it, "name", f"{label} {model}")
        _contact(_sub(it, _d("manufacturer")), {"name": "CSRI Elektropribor"})
        _sub(it, _d("model"), str(meta.get("model") or model) if label == "gravimeter" else model)
        ident = _sub(_sub(it, _d("identifications")), _d("identification"))
        _sub(ident, _d("issuer"), "manufacturer")
        _sub(ident, _d("value"), str(serial))
        _text(ident, "name", "serial number")


def _contact(el: ET.Element, c: Mapping[str, Any], further: str | None = None) -> None:
    _text(el, "name", str(c["name"]))
    _sub(el, _d("eMail"), str(c["email"]) if _nonempty(c.get("email")) else "not stated")
    loc = _sub(el, _d("location"))
    for key, tag in (
        ("city", "city"),
        ("country_code", "countryCode"),
        ("post_code", "postCode"),
        ("street", "street"),
    ):
        if _nonempty(c.get(key)):
            _sub(loc, _d(tag), str(c[key]))
    if further is not None or len(loc) == 0:
        _sub(loc, _d("further")).append(_content(further or "not stated"))


def _content(text: str) -> ET.Element:
    el = ET.Element(_d("content"), lang="en")
    el.text = text
    return el


def _laboratory(adm: ET.Element, lab: Mapping[str, Any]) -> None:
    el = _sub(adm, _d("calibrationLaboratory"))
    if _nonempty(lab.get("code")):
        _sub(el, _d("calibrationLaboratoryCode"), str(lab["code"]))
    _contact(_sub(el, _d("contact")), lab, further=f"accreditation: {lab['accreditation']}")


def _statement(parent: ET.Element, text: str, ref: str, **extra: str) -> ET.Element:
    st = _sub(parent, _d("statement"), refType=ref)
    _text(st, "declaration", text)
    for tag, value in extra.items():
        _sub(st, _d(tag), value)
    return st


def _default_traceability(result: Mapping[str, Any]) -> str:
    """What the angle and the gravity are traceable through, as the result says."""
    cal = result.get("angle_calibration")
    if isinstance(cal, Mapping) and cal.get("id"):
        lab = f" ({cal['laboratory']})" if cal.get("laboratory") else ""
        angle = (
            f"The tilt angles are traceable to the SI through the platform's angle "
            f"calibration {cal['id']} of {cal.get('date', '?')}{lab}"
        )
    else:
        angle = (
            "The tilt angles rest on the platform's specification of its angle sensors "
            "(a bound, no calibration of the platform was given)"
        )
    return (
        angle + "; the site gravity through the gravity survey named in the influence conditions."
    )


def _statements(
    adm: ET.Element, result: Mapping[str, Any], lab: Mapping[str, Any], rule: str | None
) -> None:
    sts = _sub(adm, _d("statements"))
    trace = str(lab["lab"].get("traceability") or _default_traceability(result))
    st = _sub(sts, _d("statement"), refType="basic_traceability")
    _sub(st, _d("traceable"), "true")
    _text(st, "declaration", trace)
    _statement(sts, "The results relate only to the calibrated item.", "basic_itemOnly")
    if rule:
        _statement(sts, rule, "basic_conformity")
    _statement(
        sts,
        f"Expanded uncertainty U = k·u, coverage probability about {P_COVERAGE:.2%}: "
        f"k = {K_COVERAGE:g} for a normal distribution, Student's t at the effective degrees "
        "of freedom where the standard uncertainty rests on variances estimated from the "
        "record (GUM G.4, G.6.4); k is stated with each value.",
        "basic_uncertainty",
    )


def _measurement_results(root: ET.Element, result: Mapping[str, Any]) -> None:
    mr = _sub(_sub(root, _d("measurementResults")), _d("measurementResult"))
    _text(mr, "name", "Tilt calibration of the scale factors")
    um = _sub(_sub(mr, _d("usedMethods")), _d("usedMethod"), refType="chekan_tiltCalibration")
    _text(um, "name", f"tilt calibration, estimator: {result['method']}")
    desc = _sub(um, _d("description"))
    from chekan.report.content import program_text, settled_note  # the certificate's words
    from chekan.report.i18n import tr

    prog = program_text(result, tr("en"))
    _sub(desc, _d("content"), f"tilt program: {prog or 'not stated'}", lang="en")
    for para in settled_note(result, tr("en")):  # the classical items from settled hold means
        _sub(desc, _d("content"), para.text, lang="en")
    sw = _sub(_sub(mr, _d("usedSoftware")), _d("software"))
    _text(sw, "name", "chekan")
    _sub(sw, _d("release"), str((result.get("software") or {}).get("version") or "unknown"))
    _influence(mr, result)
    _results(mr, result)


def _influence(mr: ET.Element, result: Mapping[str, Any]) -> None:
    ics = _sub(mr, _d("influenceConditions"))
    ic = _sub(ics, _d("influenceCondition"), refType="chekan_siteGravity")
    _text(ic, "name", "site gravity")
    meta = result.get("metadata") or {}
    src = meta.get("g_source") or "as given to chekan calibrate"
    _sub(_sub(ic, _d("description")), _d("content"), f"source: {src}", lang="en")
    data = _sub(ic, _d("data"))
    q = _sub(data, _d("quantity"), refType="chekan_g_local")
    _text(q, "name", "g_local")
    h = _sub(q, _s("hybrid"))
    g = float(result["g_local_mgal"])
    _real(h, "g_local", g, "|mGal", None)
    _real(h, "g_local", g * MGAL_TO_SI, r"\metre\second\tothe{-2}", None)
    ic = _sub(ics, _d("influenceCondition"), refType="chekan_sensorTemperature")
    _text(ic, "name", "sensor temperature")
    text = temperature_text(result, meta) or "not recorded in the result"
    _sub(_sub(_sub(ic, _d("data")), _d("text")), _d("content"), text, lang="en")
    ic = _sub(ics, _d("influenceCondition"), refType="chekan_angleSensors")
    _text(ic, "name", "platform angle sensors")
    a = result.get("angle_sensors") or result.get("angle_sensor")  # both, where both tilt
    text = json.dumps(a, ensure_ascii=False, sort_keys=True) if a else "not stated in the result"
    _sub(_sub(_sub(ic, _d("data")), _d("text")), _d("content"), text, lang="en")
    horizontal = result.get("pendulum_horizontal")  # rounds about X: a Type B input
    if horizontal:
        ic = _sub(ics, _d("influenceCondition"), refType="chekan_pendulumHorizontal")
        _text(ic, "name", "the pendulums' horizontal about the CCD centre")
        text = json.dumps(horizontal, ensure_ascii=False, sort_keys=True)
        _sub(_sub(_sub(ic, _d("data")), _d("text")), _d("content"), text, lang="en")


def _results(mr: ET.Element, result: Mapping[str, Any]) -> None:
    params = result["parameters"]
    big_u = expanded_uncertainties(result)
    res = _sub(mr, _d("results"))
    for name, p in params.items():
        unit = p.get("unit") or ""
        if unit not in UNITS:
            continue
        r = _sub(res, _d("result"), refType=f"chekan_{name}")
        _text(r, "name", name)
        _hybrid_quantity(_sub(r, _d("data")), name, name, float(p["mean"]), unit, big_u.get(name))
    r = _sub(res, _d("result"), refType="chekan_resultJson")
    _text(r, "name", "the chekan-result/1 this certificate was written from")
    bd = _sub(_sub(r, _d("data")), _d("byteData"))
    _sub(bd, _d("fileName"), EMBEDDED_NAME)
    _sub(bd, _d("mimeType"), "application/json")
    blob = json.dumps(result, ensure_ascii=False, allow_nan=False)  # key order kept
    _sub(bd, _d("dataBase64"), base64.b64encode(blob.encode("utf-8")).decode("ascii"))


def dcc_bytes(tree: ET.ElementTree) -> bytes:
    """The document as UTF-8 bytes with an XML declaration, indented."""
    root = tree.getroot()
    assert root is not None
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


def dcc_schema():  # type: ignore[no-untyped-def]
    """The vendored DCC 3.1.2 schema, its D-SI import mapped to the local copy (offline)."""
    import xmlschema

    local = (SCHEMAS / "SI_Format.xsd").as_uri()
    return xmlschema.XMLSchema(str(SCHEMAS / "dcc.xsd"), uri_mapper={SI_LOCATION: local})


def validate_dcc(source: str | os.PathLike | bytes) -> None:
    """Raise ``xmlschema.XMLSchemaValidationError`` if ``source`` is not a valid DCC."""
    data = Path(source).read_bytes() if not isinstance(source, bytes) else source
    dcc_schema().validate(data.decode("utf-8"))


def decision_rule_text(result: Mapping[str, Any], tolerance_percent: float) -> str | None:
    """The conformity statement with its decision rule (None when there is nothing to judge)."""
    from chekan.report.content import verdict_of
    from chekan.report.i18n import tr

    passed, line = verdict_of(result, tolerance_percent, "en")
    if passed is None:
        return None
    return f"{line} {tr('en')('decision_rule')}"
