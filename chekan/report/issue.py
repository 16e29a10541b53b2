"""What ISO/IEC 17025 7.8 asks of a certificate beyond the measurement: its identifier, the
issuing lab and the customer, the item's condition, the date of issue, the environmental
conditions, the authoriser, and that the results relate only to the item."""

from __future__ import annotations

import datetime as _dt
from collections.abc import Mapping
from typing import Any

from chekan.report.document import KeyValue, Para, Report
from chekan.report.i18n import Translator


def certificate_id(
    result: Mapping[str, Any], lab: Mapping[str, Any] | None, issued: _dt.date
) -> str:
    """Unique per lab, input (SHA-256), method, software version and date of issue."""
    code = str(((lab or {}).get("lab") or {}).get("code") or "LAB")
    sha = str(result.get("record_sha256") or "nohash")[:16]
    version = str((result.get("software") or {}).get("version") or "unknown")
    return f"{code}-{result['serial']}-{sha}-{result['method']}-{version}-{issued.isoformat()}"


def _address(c: Mapping[str, Any]) -> str:
    parts = [c.get(k) for k in ("street", "post_code", "city", "country_code")]
    return ", ".join([str(c["name"])] + [str(p) for p in parts if p])


def issue_rows(
    result: Mapping[str, Any],
    t: Translator,
    *,
    lab: Mapping[str, Any] | None,
    customer: str | None,
    issued: _dt.date,
    lang: str = "en",
) -> list[tuple[str, str, bool]]:
    """The key–value rows of the certificate's issue block ("not stated" agreeing with
    each row's noun in Russian)."""
    from chekan.report.checks import traceability

    meta = result.get("metadata") or {}
    rows = [
        (t("cert_id"), certificate_id(result, lab, issued), True),
        (t("issue_date"), issued.isoformat(), False),
    ]
    labt = (lab or {}).get("lab")
    rows.append((t("issuer"), _address(labt) if labt else t("not_stated_f"), False))
    if labt:
        rows.append((t("accreditation"), str(labt.get("accreditation")), False))
    cust = (lab or {}).get("customer")
    cust_text = customer or (_address(cust) if cust else t("not_stated_m"))
    rows.append((t("customer"), cust_text, False))
    condition = meta.get("item_condition") or t("not_stated")
    rows.append((t("item_condition"), str(condition), False))
    temp = temperature_text(result, meta)
    # the record's temp_c is the thermostatted sensor's, not the room's: no room is recorded
    rows.append((t("environment"), t("env_not_recorded") if temp else t("not_recorded_pl"), False))
    if temp:
        rows.append((t("sensor_temperature"), temp, False))
    rows.append((t("traceability"), traceability(result, lab).statement(lang), False))
    resp = (lab or {}).get("responsible")
    who = f"{resp['name']}" + (f", {resp['role']}" if resp.get("role") else "") if resp else None
    rows.append((t("authoriser"), who or t("not_stated_m"), False))
    return rows


def add_issue_block(
    rep: Report,
    result: Mapping[str, Any],
    t: Translator,
    *,
    lab: Mapping[str, Any] | None = None,
    customer: str | None = None,
    issued: _dt.date | None = None,
) -> None:
    """Set ``rep.certificate_id`` and add the issue rows and the item-only statement; a
    report without its laboratory (``lab`` None) is a draft: its identifier, printed on every
    page, says so, and a warning under the rows says why."""
    issued = issued or _dt.datetime.now(_dt.UTC).date()
    rows = issue_rows(result, t, lab=lab, customer=customer, issued=issued, lang=rep.lang)
    if rep.draft:
        rows[0] = (rows[0][0], t("draft_id", id=rows[0][1]), True)
    rep.certificate_id = rows[0][1]
    rep.add(KeyValue(rows))
    if rep.draft:
        rep.add(Para(t("draft_note"), "warn"))
    rep.add(Para(t("only_item"), "note"))


def add_end(rep: Report, t: Translator) -> None:
    """The certificate's (or draft's) clear end."""
    rep.add(Para(t("draft_end" if rep.draft else "cert_end", id=rep.certificate_id), "strong"))


def temperature_text(result: Mapping[str, Any], meta: Mapping[str, Any]) -> str | None:
    """The sensor temperature during the calibration: the record's ``temp_c`` column
    (``result["sensor_temperature_c"]``: mean, min, max), else the header's
    ``sensor_temperature_c``; None when neither says."""
    rec = result.get("sensor_temperature_c")
    if isinstance(rec, Mapping) and all(k in rec for k in ("mean", "min", "max")):
        return f"{rec['mean']:.2f} °C ({rec['min']:.2f}…{rec['max']:.2f} °C)"
    temp = meta.get("sensor_temperature_c")
    return f"{temp} °C" if temp is not None else None
