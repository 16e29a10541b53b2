"""The Digital Calibration Certificate (PTB DCC 3.3.0, D-SI 2.2.1) of a chekan-result/1.

Built with :mod:`xml.etree.ElementTree` (escaping by the library), in the certificate's
language (``en``; ``ru`` writes every text in Russian and English, Russian mandatory).
Each result is named in words with its symbol and carries its value, its expanded
uncertainty (U = k·u as the PDF states it, :func:`chekan.report.expanded.expanded_of`)
and its SI value beside it (:mod:`chekan.report.dcc_xml` writes numbers at their
meaning). The result JSON is embedded, so that :mod:`chekan.report.dcc_read` reads it back
and checks every value against it. Unknown optional elements are left out.
"""

from __future__ import annotations

import base64
import datetime as _dt
import json
import os
import tomllib
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from chekan.errors import ChekanError
from chekan.report.checks import Traceability, traceability
from chekan.report.dcc_conditions import influence_conditions, used_methods
from chekan.report.dcc_schema import SCHEMA_VERSION, SCHEMAS, dcc_schema, validate_dcc
from chekan.report.dcc_trace import criteria_text, decide, statement
from chekan.report.dcc_words import RESULT_NAMES, words
from chekan.report.dcc_xml import (
    DCC_NS,
    K_COVERAGE,
    P_COVERAGE,
    RAD_PER_ARCMIN,
    SI_NS,
    d,
    hybrid_real,
    quantity,
    sub,
    text,
)
from chekan.report.issue import certificate_id

__all__ = [
    "DCC_NS",
    "EMBEDDED_NAME",
    "SCHEMAS",
    "SCHEMA_VERSION",
    "SI_NS",
    "build_dcc",
    "dcc_bytes",
    "dcc_schema",
    "load_lab",
    "validate_dcc",
    "write_dcc",
]

MGAL_TO_SI = 1e-5  # 1 mGal = 1e-5 m s^-2
LAB_ENV = "CHEKAN_LAB"
EMBEDDED_NAME = "chekan-result.json"
# parameter unit → (the unit of its own si:real, the SI real's unit, the SI factor)
UNITS = {
    "mGal/pix": (r"|mGal\per|pixel", r"\metre\second\tothe{-2}\per|pixel", MGAL_TO_SI),
    "mGal/pix^2": (
        r"|mGal\per|pixel\tothe{2}",
        r"\metre\second\tothe{-2}\per|pixel\tothe{2}",
        MGAL_TO_SI,
    ),
    "arcmin": (r"|arcminute", r"\radian", RAD_PER_ARCMIN),
}
RESULT_PARAMS = ("b1", "b2", "a", "b1_0", "b2_0")
LAB_REQUIRED = ("name", "email", "street", "city", "post_code", "country_code", "accreditation")
__all__ += ["K_COVERAGE", "P_COVERAGE", "UNITS"]


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
    site = data.get("site")
    if site is not None and (
        not isinstance(site, dict)
        or ("gravity_survey" in site and not _nonempty(site["gravity_survey"]))
    ):
        raise ChekanError(f"{p}: [site] gravity_survey must be a non-empty text")
    return data


def _nonempty(v: Any) -> bool:
    return isinstance(v, str | int) and str(v).strip() != ""


# ----------------------------------------------------------------------------- numbers


def expanded_uncertainties(result: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
    """(U, k) of each result parameter, as the PDF certificate states it
    (:func:`chekan.report.expanded.expanded_of`); none for a result whose sds are no
    expanded uncertainty (the classical method's repeatability:
    :func:`chekan.report.checks.states_expanded_uncertainty`)."""
    from chekan.report.checks import states_expanded_uncertainty
    from chekan.report.expanded import expanded_of

    params = result["parameters"]
    out: dict[str, tuple[float, float]] = {}
    if not states_expanded_uncertainty(result):
        return out
    for name in RESULT_PARAMS:
        if name not in params:
            continue
        big_u, k = expanded_of(result, name)
        if big_u is not None:
            out[name] = (float(big_u), float(k))
    return out


def dcc_langs(lang: str) -> tuple[str, ...]:
    """The languages of a DCC issued in ``lang``: the language itself first (mandatory),
    English beside any other."""
    from chekan.report.i18n import check_lang

    check_lang(lang)
    return (lang,) if lang == "en" else (lang, "en")


# ----------------------------------------------------------------------------- the document


def build_dcc(
    result: Mapping[str, Any],
    lab: Mapping[str, Any],
    *,
    customer: str | None = None,
    issued: _dt.date | None = None,
    decision_rule: str | None = None,
    lang: str = "en",
    tolerance_percent: float = 0.05,
) -> ET.ElementTree:
    """The DCC element tree of ``result`` issued by ``lab`` (a :func:`load_lab` dict) in
    ``lang``; conformity judged against ``tolerance_percent``. ``decision_rule``: the
    lab's own words of its rule, added to the statement of conformity."""
    from chekan import __version__

    langs = dcc_langs(lang)
    issued = issued or _dt.datetime.now(_dt.UTC).date()
    tr = traceability(result, lab)
    root = ET.Element(d("digitalCalibrationCertificate"), schemaVersion=SCHEMA_VERSION)
    adm = sub(root, d("administrativeData"))
    sw = sub(sub(adm, d("dccSoftware")), d("software"))
    text(sw, "name", "chekan", langs)
    sub(sw, d("release"), __version__)
    sub(sw, d("type"), "application")
    _core_data(adm, result, lab, issued, langs)
    _items(adm, result, langs)
    _laboratory(adm, lab["lab"], langs)
    rp = sub(sub(adm, d("respPersons")), d("respPerson"))
    text(sub(rp, d("person")), "name", str(lab["responsible"]["name"]), langs)
    if _nonempty(lab["responsible"].get("role")):
        sub(rp, d("role"), str(lab["responsible"]["role"]))
    sub(rp, d("mainSigner"), "true")
    cust = {"name": customer} if customer else dict(lab.get("customer") or {})
    if cust:
        _contact(sub(adm, d("customer")), cust, langs)
    else:  # the schema requires a customer: its absence is stated, not invented
        el = sub(adm, d("customer"))
        text(el, "name", words("no_customer"), langs)
        text(sub(el, d("location")), "further", words("no_customer"), langs)
    _statements(adm, result, lab, tr, decision_rule, float(tolerance_percent), langs)
    mrs = sub(root, d("measurementResults"))
    mr = sub(mrs, d("measurementResult"))
    text(mr, "name", words("results"), langs)
    used_methods(mr, result, langs)
    sws = sub(mr, d("usedSoftware"))
    sw = sub(sws, d("software"))
    text(sw, "name", "chekan", langs)
    sub(sw, d("release"), str((result.get("software") or {}).get("version") or __version__))
    sub(sw, d("type"), "application")
    influence_conditions(mr, result, tr, langs)
    _results(mr, result, langs)
    return ET.ElementTree(root)


def _session_date(result: Mapping[str, Any], issued: _dt.date) -> str:
    v = result.get("date")
    if isinstance(v, str) and len(v) >= 10:
        return v[:10]
    started = (result.get("metadata") or {}).get("started")
    if isinstance(started, str) and len(started) >= 10:
        return started[:10]
    return issued.isoformat()


def _core_data(adm, result, lab, issued: _dt.date, langs: Sequence[str]) -> None:
    core = sub(adm, d("coreData"))
    sub(core, d("countryCodeISO3166_1"), str(lab["lab"]["country_code"]).upper())
    for lang in langs:
        sub(core, d("usedLangCodeISO639_1"), lang)
    sub(core, d("mandatoryLangCodeISO639_1"), langs[0])
    sub(core, d("uniqueIdentifier"), certificate_id(result, lab, issued))
    ident = sub(sub(core, d("identifications")), d("identification"))
    sub(ident, d("issuer"), "calibrationLaboratory")
    sub(ident, d("value"), issued.isoformat())
    text(ident, "name", words("date_of_issue"), langs)
    day = _session_date(result, issued)
    sub(core, d("beginPerformanceDate"), day)
    sub(core, d("endPerformanceDate"), day)
    sub(core, d("performanceLocation"), "laboratory")
    sub(core, d("issueDate"), issued.isoformat())


def _items(adm: ET.Element, result: Mapping[str, Any], langs: Sequence[str]) -> None:
    from chekan.report.i18n import value_name

    meta = result.get("metadata") or {}
    items = sub(adm, d("items"))
    instrument = str(meta.get("instrument") or "Chekan-AM")
    gravimeter = {k: v.format(model=value_name(instrument, k)) for k, v in
                  words("gravimeter", model="{model}").items()}  # fmt: skip
    for name, model, serial in (
        (gravimeter, str(meta.get("model") or instrument), result["serial"]),
        (words("platform"), None, meta.get("platform_serial")),
    ):
        if serial is None:
            continue
        it = sub(items, d("item"))
        text(it, "name", name, langs)
        if model is not None:
            text(sub(it, d("manufacturer")), "name", "CSRI Elektropribor", langs)
            sub(it, d("model"), model)
        ident = sub(sub(it, d("identifications")), d("identification"))
        sub(ident, d("issuer"), "manufacturer")
        sub(ident, d("value"), str(serial))
        text(ident, "name", words("serial"), langs)


def _contact(
    el: ET.Element, c: Mapping[str, Any], langs: Sequence[str], further: dict | None = None
) -> None:
    """A dcc:contactType: name, e-mail and address where stated (the schema requires a
    location: without any address, ``further`` repeats the name)."""
    text(el, "name", str(c["name"]), langs)
    if _nonempty(c.get("email")):
        sub(el, d("eMail"), str(c["email"]))
    loc = sub(el, d("location"))
    for key, tag in (
        ("city", "city"),
        ("country_code", "countryCode"),
        ("post_code", "postCode"),
        ("street", "street"),
    ):
        if _nonempty(c.get(key)):
            sub(loc, d(tag), str(c[key]).upper() if key == "country_code" else str(c[key]))
    if further is not None:
        text(loc, "further", further, langs)
    elif len(loc) == 0:
        text(loc, "further", str(c["name"]), langs)


def _laboratory(adm: ET.Element, lab: Mapping[str, Any], langs: Sequence[str]) -> None:
    el = sub(adm, d("calibrationLaboratory"))
    if _nonempty(lab.get("code")):
        sub(el, d("calibrationLaboratoryCode"), str(lab["code"]))
    _contact(sub(el, d("contact")), lab, langs, words("accreditation", a=lab["accreditation"]))


def _statements(
    adm: ET.Element,
    result: Mapping[str, Any],
    lab: Mapping[str, Any],
    tr: Traceability,
    rule: str | None,
    tolerance_percent: float,
    langs: Sequence[str],
) -> None:
    sts = sub(adm, d("statements"))
    st = sub(sts, d("statement"), refType="basic_traceability")
    sub(st, d("traceable"), "true" if tr.traceable else "false")
    decl = text(st, "declaration", statement(tr), langs)
    if _nonempty(lab["lab"].get("traceability")):  # the lab's own words, after the facts
        sub(decl, d("content"), str(lab["lab"]["traceability"]))
    st = sub(sts, d("statement"), refType="basic_itemOnly")
    text(st, "declaration", words("item_only"), langs)
    _conformity(sts, result, rule, tolerance_percent, langs)
    st = sub(sts, d("statement"), refType="basic_uncertainty")
    text(st, "declaration", words("uncertainty"), langs)


def _conformity(sts, result, rule: str | None, tolerance_percent: float, langs) -> None:
    """The statement of conformity: the decision rule with each criterion's outcome, and
    dcc:conformity where one is stated (else the reason why not)."""
    dec = decide(result, tolerance_percent)
    if not dec.criteria and dec.why is None:
        return
    st = sub(sts, d("statement"), refType="basic_conformity")
    tol = f"{tolerance_percent:g}"
    crit = criteria_text(dec)
    decl = words("rule", tol=tol, criteria="{criteria}")
    decl = {k: v.replace("{criteria}", crit[k]) for k, v in decl.items()}
    if decl and "ru" in decl:
        decl["ru"] = decl["ru"].replace(f"{tol} %", f"{tol.replace('.', ',')} %")
    if dec.why is not None:
        why = words("conformity_none", why="{why}")
        decl = {k: f"{decl[k]} {why[k].replace('{why}', dec.why[k])}" for k in decl}
    el = text(st, "declaration", decl, langs)
    if rule:
        sub(el, d("content"), rule)
    if dec.outcome is not None:
        sub(st, d("conformity"), dec.outcome)


def _results(mr: ET.Element, result: Mapping[str, Any], langs: Sequence[str]) -> None:
    """Each parameter with a unit of :data:`UNITS`, named in words, and the result JSON."""
    from chekan.report.i18n import param_name

    big_u = expanded_uncertainties(result)
    res = sub(mr, d("results"))
    for name, p in result["parameters"].items():
        unit = p.get("unit") or ""
        if unit not in UNITS:
            continue
        label = RESULT_NAMES.get(name) or {lang: param_name(name, lang) for lang in ("en", "ru")}
        r = sub(res, d("result"), refType=f"chekan_{name}")
        text(r, "name", label, langs)
        q = quantity(sub(r, d("data")), f"chekan_{name}", label, langs)
        own, si_unit, factor = UNITS[unit]
        hybrid_real(q, name, float(p["mean"]), own, si_unit, factor, big_u.get(name))
    r = sub(res, d("result"), refType="chekan_resultJson")
    text(r, "name", words("result_json"), langs)
    bd = sub(sub(r, d("data")), d("byteData"))
    sub(bd, d("fileName"), EMBEDDED_NAME)
    sub(bd, d("mimeType"), "application/json")
    sub(bd, d("dataBase64"), base64.b64encode(result_json_bytes(result)).decode("ascii"))


def result_json_bytes(result: Mapping[str, Any]) -> bytes:
    """The result as the DCC and the PDF embed it (UTF-8 JSON, key order kept)."""
    return json.dumps(result, ensure_ascii=False, allow_nan=False).encode("utf-8")


def dcc_bytes(tree: ET.ElementTree) -> bytes:
    """The document as UTF-8 bytes with an XML declaration, indented."""
    root = tree.getroot()
    assert root is not None
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


def write_dcc(
    result: Mapping[str, Any],
    out: Path,
    lab_path: str | os.PathLike | None,
    *,
    customer: str | None = None,
    tolerance_percent: float = 0.05,
    lang: str = "en",
) -> Path:
    """The DCC of ``result`` at ``out``; the lab file is read before anything is written."""
    from chekan.files.durable import atomic_output
    from chekan.files.outputs import SYSTEM_ERRNOS

    lab = load_lab(lab_path)
    data = dcc_bytes(
        build_dcc(result, lab, customer=customer, lang=lang, tolerance_percent=tolerance_percent)
    )
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(out, "wb") as f:
            f.write(data)
    except OSError as e:
        if e.errno in SYSTEM_ERRNOS:  # a full disk: exit 1, the file named (atomic_output)
            raise
        raise ChekanError(f"{out}: cannot write the certificate: {e.strerror or e}") from None
    return out
