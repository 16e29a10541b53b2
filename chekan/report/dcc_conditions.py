"""The DCC's used method (the estimator and the tilt program as run) and influence
conditions (site gravity, sensor temperature, the platform's angle sensors, the pendulums'
horizontal), each a structured D-SI quantity where it is a number, words where it is not.
What the result does not say is left out, never filled with "not stated"."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from typing import Any

from chekan.report.checks import Traceability
from chekan.report.dcc_words import W, words
from chekan.report.dcc_xml import (
    RAD_PER_ARCMIN,
    RAD_PER_ARCSEC,
    contents,
    d,
    hybrid_real,
    no_quantity,
    num,
    quantity,
    real,
    s,
    scaled,
    sub,
    text,
)
from chekan.report.numbers import is_num

MGAL_TO_SI = 1e-5  # 1 mGal = 1e-5 m s^-2


def _tr_lang(lang: str):  # type: ignore[no-untyped-def]
    from chekan.report.i18n import tr

    return tr(lang)


def used_methods(mr: ET.Element, result: Mapping[str, Any], langs: Sequence[str]) -> None:
    """The tilt calibration: its estimator in words, the program as text (the certificate's
    words) and as quantities (each round's axis and angles, the dwell, the settling)."""
    from chekan.report.content import program_text, settled_note

    method = str(result["method"])
    um = sub(sub(mr, d("usedMethods")), d("usedMethod"), refType="chekan_tiltCalibration")
    text(um, "name", words("method", m=method), langs)
    desc = sub(um, d("description"))
    key = f"method_{method}"
    if key in W:
        contents(desc, words(key), langs)
    for lang in langs:
        prog = program_text(result, _tr_lang(lang))
        if prog:
            sub(desc, d("content"), f"{W['program'][lang]}: {prog}", lang=lang)
        for para in settled_note(result, _tr_lang(lang)):  # items from settled hold means
            sub(desc, d("content"), para.text, lang=lang)
    quantities = _program_quantities(result, langs)
    if len(quantities):
        um.append(quantities)


def _program_quantities(result: Mapping[str, Any], langs: Sequence[str]) -> ET.Element:
    """``dcc:usedMethodQuantities`` of the tilt program (empty when the result has none)."""
    from chekan.physics.units import parse_angle_deg

    el = ET.Element(d("usedMethodQuantities"))
    tp = result.get("tilt_program")
    if not isinstance(tp, Mapping):
        return el
    for r in tp.get("rounds") or []:
        if not isinstance(r, Mapping):
            continue
        try:
            arcmin = [parse_angle_deg(str(a)) * 60.0 for a in r.get("angles") or []]
        except (ValueError, TypeError):
            continue  # a label this version cannot read stays in the program's words
        if not arcmin:
            continue
        axis = str(r.get("axis", "y")).upper()
        q = sub(el, d("usedMethodQuantity"), refType=f"chekan_round_{r.get('round', '')}")
        text(q, "name", words("round", n=r.get("round", ""), axis=axis), langs)
        h = sub(q, s("hybrid"))
        for unit, values in (
            (r"\arcminute", [f"{a:.12g}" for a in arcmin]),
            (r"\radian", [scaled(a, RAD_PER_ARCMIN) for a in arcmin]),
        ):
            lst = sub(h, s("realListXMLList"))
            sub(lst, s("valueXMLList"), " ".join(values))
            sub(lst, s("unitXMLList"), unit)
    for key, ref in (("dwell_s", "dwell"), ("settle_s", "settle")):
        if is_num(tp.get(key)):
            q = sub(el, d("usedMethodQuantity"), refType=f"chekan_{key}")
            text(q, "name", words(ref), langs)
            real(q, key, num(tp[key]), r"\second")
    return el


# ----------------------------------------------------------------------------- conditions


def influence_conditions(
    mr: ET.Element, result: Mapping[str, Any], tr: Traceability, langs: Sequence[str]
) -> None:
    """The influence conditions the result states."""
    ics = sub(mr, d("influenceConditions"))
    _site_gravity(ics, result, tr, langs)
    _temperature(ics, result, langs)
    _angle_sensors(ics, result, tr, langs)
    _horizontal(ics, result, langs)


def _site_gravity(ics: ET.Element, result: Mapping[str, Any], tr: Traceability, langs) -> None:
    ic = sub(ics, d("influenceCondition"), refType="chekan_siteGravity")
    text(ic, "name", words("site_gravity"), langs)
    src = words("g_source", src=tr.g_source) if tr.g_source else words("g_unnamed")
    text(ic, "description", src, langs)
    q = quantity(sub(ic, d("data")), "chekan_g_local", words("g_local"), langs)
    hybrid_real(
        q, "g_local", float(result["g_local_mgal"]), "|mGal", r"\metre\second\tothe{-2}", 1e-5
    )


def _temperature(ics: ET.Element, result: Mapping[str, Any], langs) -> None:
    from chekan.report.issue import temperature_text

    meta = result.get("metadata") or {}
    line = temperature_text(result, meta)
    if line is None:
        return
    ic = sub(ics, d("influenceCondition"), refType="chekan_sensorTemperature")
    text(ic, "name", words("temperature"), langs)
    text(ic, "description", line, langs)
    data = sub(ic, d("data"))
    rec = result.get("sensor_temperature_c")
    if isinstance(rec, Mapping) and all(is_num(rec.get(k)) for k in ("mean", "min", "max")):
        values = [(k, rec[k]) for k in ("mean", "min", "max")]
    elif is_num(meta.get("sensor_temperature_c")):
        values = [("mean", meta["sensor_temperature_c"])]
    else:
        values = []
    for k, v in values:
        q = quantity(data, f"chekan_temperature_{k}", words(f"t_{k}"), langs)
        real(q, f"t_{k}", num(v), r"\degreecelsius")
    if not values:
        sub(data, d("text")).append(_plain_content(line))


def _plain_content(line: str) -> ET.Element:
    el = ET.Element(d("content"))
    el.text = line
    return el


def _arcsec(data: ET.Element, ref: str, key: str, value: float, langs) -> None:
    q = quantity(data, ref, words(key), langs)
    hybrid_real(q, key, float(value), "|arcsecond", r"\radian", RAD_PER_ARCSEC)


def _angle_sensors(ics: ET.Element, result: Mapping[str, Any], tr: Traceability, langs) -> None:
    """One condition for the platform's angle sensors: their traceability in words, the
    calibration's file hash where there is one, and per axis the error model's numbers."""
    both = result.get("angle_sensors")
    one = result.get("angle_sensor")
    if isinstance(both, Mapping) and both:
        sensors = {str(a): v for a, v in both.items() if isinstance(v, Mapping)}
    elif isinstance(one, Mapping):
        sensors = {str(one.get("axis", "y")): one}
    else:
        return
    ic = sub(ics, d("influenceCondition"), refType="chekan_angleSensors")
    text(ic, "name", words("sensors"), langs)
    cal = result.get("angle_calibration")
    if isinstance(cal, Mapping) and cal.get("sha256") and tr.angle == "calibration":
        cert = sub(ic, d("certificate"))
        text(cert, "referral", words("cal_referral"), langs)
        sub(cert, d("referralID"), str(cal.get("id") or cal.get("file")))
        sub(cert, d("procedure"), "SHA-256")
        sub(cert, d("value"), str(cal["sha256"]))
        sub(cert, d("traceable"), "true")
    data = sub(ic, d("data"))
    for axis, v in sorted(sensors.items()):
        _sensor_list(data, axis, v, result, langs)


def _sensor_list(
    data: ET.Element, axis: str, v: Mapping[str, Any], result: Mapping[str, Any], langs
) -> None:
    """A ``dcc:list`` of one sensor: its model, status, bound and uncertainties."""
    lst = sub(data, d("list"), refType=f"chekan_angleSensor_{axis.lower()}")
    text(lst, "name", words("sensor", axis=axis.upper()), langs)
    ref = f"chekan_angleSensor_{axis.lower()}"
    model = "model_independent" if v.get("model") == "independent" else "model_systematic"
    no_quantity(lst, f"{ref}_model", words("model"), words(model), langs)
    if v.get("model") != "independent":
        cal = v.get("calibration")
        if isinstance(cal, Mapping):
            lab = f" ({cal['laboratory']})" if cal.get("laboratory") else ""
            status = words("calibrated", id=cal.get("id", "?"), date=cal.get("date", "?"), lab=lab)
        else:
            status = words("uncalibrated")
        no_quantity(lst, f"{ref}_status", words("sensor_source"), status, langs)
    if is_num(v.get("bound_arcsec")):
        _arcsec(lst, f"{ref}_bound", "bound", v["bound_arcsec"], langs)
    for key, field in (("u_angle", "u_per_angle_arcsec"), ("u_scale", "u_scale_arcsec")):
        if is_num(v.get(field)):
            _arcsec(lst, f"{ref}_{field}", key, v[field], langs)
    for key, field in (("distribution", "distribution"), ("reading", "reading")):
        if v.get(field):
            no_quantity(lst, f"{ref}_{field}", words(key), str(v[field]), langs)
    if v.get("source"):
        no_quantity(lst, f"{ref}_source", words("source"), str(v["source"]), langs)


def _horizontal(ics: ET.Element, result: Mapping[str, Any], langs) -> None:
    """The pendulums' horizontal about the CCD centre, a Type B input of rounds about X."""
    h = result.get("pendulum_horizontal")
    if not isinstance(h, Mapping):
        return
    ic = sub(ics, d("influenceCondition"), refType="chekan_pendulumHorizontal")
    text(ic, "name", words("horizontal"), langs)
    data = sub(ic, d("data"))
    if is_num(h.get("u_pix")):
        q = quantity(data, "chekan_horizontal_u_pix", words("u_horizontal"), langs)
        real(q, "u_pix", num(h["u_pix"]), "|pixel")
    if h.get("source"):
        no_quantity(data, "chekan_horizontal_source", words("source"), str(h["source"]), langs)
    if not len(data):
        ics.remove(ic)
