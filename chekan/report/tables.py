"""Tables of the certificate: the parameters, the uncertainty budget, the diagnostics."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from chekan.physics.parameters import PHYSICAL
from chekan.report.document import Cell, Heading, KeyValue, Para, Report, Table
from chekan.report.i18n import Translator, param_name, unit_name, with_param_names
from chekan.report.numbers import (
    DASH,
    coverage_text,
    fixed,
    general,
    is_num,
    plain,
    sci,
    unc,
    value_unc,
)

PARAM_ORDER = (*PHYSICAL, "sigma_theta_arcsec", "sigma_hold_pix")
BUDGET_ORDER = (
    "angle_systematic",
    "angle_systematic_y",
    "angle_systematic_x",
    "angle_systematic_xy",
    "angle_readout",
    "x_response",
    "noise",
    "drift",
    "a",
)
# GUM evaluation type of each budget line: A from the scatter of the data, B from other
# information (the platform's specification, priors)
BUDGET_TYPE = {
    "angle_systematic": "B",
    "angle_systematic_y": "B",
    "angle_systematic_x": "B",
    "angle_systematic_xy": "B",
    "x_response": "B",
    "angle_readout": "A",
    "noise": "A",
    "drift": "A",
    "hold_offsets": "A",
    "level_offset": "A",
    "a": "B",
    "other_priors": "B",
    "hyperparameters": "A",
}
# the budget's last rows, in this order: u, then (map) ν_eff and k, then U
FOOTER = ("total", "nu_eff", "coverage_factor", "expanded", "expanded_k2")
_NOT_UNCERTAINTIES = ("nu_eff", "coverage_factor")


def param_cells(name: str, e: Mapping[str, Any]) -> tuple[str, str, str, str]:
    """(estimate, u, low, high) with matched decimals."""
    mean, sd = e.get("mean"), e.get("sd")
    lo, hi = e.get("hdi_low"), e.get("hdi_high")
    if re.fullmatch(r"b\d(_0)?", name):
        return fixed(mean, 6), unc(sd), fixed(lo, 6), fixed(hi, 6)
    ms, us = value_unc(mean, sd)
    if "·10" in ms:
        exp = int(ms.split("·10")[1].translate(str.maketrans("⁰¹²³⁴⁵⁶⁷⁸⁹⁻", "0123456789-")))
        nd = len(ms.split("·")[0].split(".")[1]) if "." in ms.split("·")[0] else 0
        return ms, us, sci(lo, nd + 1, exp=exp), sci(hi, nd + 1, exp=exp)
    nd = len(ms.split(".")[1]) if "." in ms else 0
    return ms, us, fixed(lo, nd), fixed(hi, nd)


def param_table(rep: Report, result: Mapping[str, Any], t: Translator, lang: str) -> None:
    """The parameter table: estimate, sd, interval, unit (R-hat and ESS when present)."""
    params = result["parameters"]
    names = [n for n in PARAM_ORDER if n in params] + sorted(
        n for n in params if n not in PARAM_ORDER
    )
    diag = any("r_hat" in params[n] or "ess_bulk" in params[n] for n in names)
    p = plain(round(100 * float(result.get("hdi_prob", 0.95)), 6))
    bayes = result["method"] == "bayes"
    head = [t("param"), t("mean"), t("sd"), t("hdi" if bayes else "interval", p=p), t("unit")]
    if diag:
        head += [t("rhat"), t("ess")]
    rows = []
    for n in names:
        e = params[n]
        m, u, lo, hi = param_cells(n, e)
        row = [
            Cell(param_name(n, lang)),
            Cell(m, bold=n in ("b1", "b2")),
            Cell(u),
            Cell(f"{lo} … {hi}" if lo != DASH else DASH),
            Cell(unit_name(str(e.get("unit", "")), lang)),
        ]
        if diag:
            row += [Cell(fixed(e.get("r_hat"), 3)), Cell(fixed(e.get("ess_bulk"), 0))]
        rows.append(row)
    for n, v in (result.get("fixed") or {}).items():
        if n in params or not is_num(v):
            continue
        unit = "mGal/pix^2" if n == "a" else ""
        row = [
            Cell(param_name(n, lang)),
            Cell(sci(v, 4) if abs(v) < 1e-3 else general(v)),
            Cell(t("fixed")),
            Cell(DASH),
            Cell(unit_name(unit, lang)),
        ]
        if diag:
            row += [Cell(""), Cell("")]
        rows.append(row)
    cap = t("cap_params_bayes", p=p) if bayes else t("cap_params")
    if "tau_s" in params:  # its sd is statistical only (README: "Angles up to a second late")
        cap = f"{cap}. {t('cap_params_tau')}"
    rep.add(
        Table([[Cell(h, bold=True) for h in head]], rows, "lrrcl" + ("rr" if diag else ""), cap)
    )


def budget_table(rep: Report, result: Mapping[str, Any], t: Translator, lang: str) -> None:
    """The uncertainty budget section (nothing when the result has none)."""
    bud = result.get("uncertainty_budget")
    if not bud:
        return
    systems = [s for s in ("b1", "b2") if s in bud] + sorted(
        s for s in bud if s not in ("b1", "b2")
    )
    keys: list[str] = []
    for s in systems:
        for k in bud[s]:
            if k not in keys:
                keys.append(k)
    if not any(is_num(bud[s].get("nu_eff")) for s in systems):
        keys = [k for k in keys if k != "nu_eff"]  # not evaluated (bayes): no row
    order = [k for k in BUDGET_ORDER if k in keys]
    order += [k for k in keys if k not in BUDGET_ORDER and k not in FOOTER]
    order += [k for k in FOOTER if k in keys]
    head = [Cell(t("source"), bold=True), Cell(t("src_type"), bold=True)]
    for s in systems:
        head += [Cell(f"u({param_name(s, lang)})", bold=True), Cell(t("ppm"), bold=True)]
    rows = []
    for k in order:
        if k == "angle_systematic" and isinstance(result.get("angle_calibration"), Mapping):
            label = t("src_angle_systematic_cal", id=result["angle_calibration"].get("id", "?"))
        elif k == "angle_systematic":
            label = t("src_angle_systematic", bound=angle_bound_text(result))
        elif k in ("angle_systematic_y", "angle_systematic_x"):
            axis = k[-1]
            label = t("src_angle_systematic_axis", axis=axis.upper()) + (
                t("src_angle_cal_of", id=result["angle_calibration"].get("id", "?"))
                if _calibrated(result, axis)
                else t("src_angle_spec_of", bound=angle_bound_text(result, axis))
            )
        elif k == "x_response":
            label = t("src_x_response", u=horizontal_u_text(result, lang))
        else:
            label = t(f"src_{k}") if f"src_{k}" in _known_sources() else k
        typ = BUDGET_TYPE.get(k)
        row = [
            Cell(label, bold=k in ("total", "expanded", "expanded_k2")),
            Cell(t(f"type_{typ}") if typ else ""),
        ]
        for s in systems:
            v = bud[s].get(k)
            if k in _NOT_UNCERTAINTIES:
                text = coverage_text(v) if k == "coverage_factor" else _nu_text(v)
                row += [Cell(text), Cell(DASH)]
                continue
            b = result["parameters"].get(s, {}).get("mean")
            ppm = 1e6 * v / b if is_num(v) and is_num(b) and b else None
            row += [
                Cell(unc(v), bold=k in ("expanded", "expanded_k2")),
                Cell(unc(ppm) if ppm is not None else DASH),
            ]
        rows.append(row)
    foot = sum(k in FOOTER for k in order)
    rep.add(
        Heading(t("sec_budget")),
        Para(t("budget_text")),
        Table([head], rows, "lc" + "rr" * len(systems), t("cap_budget"), footer_rows=foot),
    )


def _nu_text(v: object) -> str:
    """ν_eff as a whole number (GUM G.4.1 truncates it), ∞ beyond 10⁵ (k = 2.00), "< 1"
    below one (no degree of freedom left: no k)."""
    if not is_num(v):
        return DASH
    nu = float(v)  # type: ignore[arg-type]
    return "∞" if nu >= 1e5 else "< 1" if nu < 1.0 else str(int(nu))


def angle_bound_text(result: Mapping[str, Any], axis: str | None = None) -> str:
    """ " ±3″" from the result's ``angle_sensor.bound_arcsec`` (or that of the ``axis``
    sensor in ``angle_sensors``); "" when it has none."""
    a = result.get("angle_sensor")
    sensors = result.get("angle_sensors")
    if axis is not None and isinstance(sensors, Mapping):
        a = sensors.get(axis)
    bound = a.get("bound_arcsec") if isinstance(a, Mapping) else None
    return f" ±{plain(bound)}″" if is_num(bound) else ""


def horizontal_u_text(result: Mapping[str, Any], lang: str = "en") -> str:
    """The pendulums' horizontal's standard uncertainty (pix) that the result states
    (``pendulum_horizontal.u_pix``; a result of an older version: the then fixed 100)."""
    h = result.get("pendulum_horizontal")
    u = h.get("u_pix") if isinstance(h, Mapping) else None
    text = plain(u) if is_num(u) else "100"
    return text.replace(".", ",") if lang == "ru" else text


def _calibrated(result: Mapping[str, Any], axis: str) -> bool:
    """The ``axis`` sensor's prior comes from the platform's angle calibration."""
    sensors = result.get("angle_sensors")
    a = sensors.get(axis) if isinstance(sensors, Mapping) else None
    return isinstance(a, Mapping) and isinstance(a.get("calibration"), Mapping)


def _known_sources() -> set[str]:
    """The uncertainty sources that have a translated label."""
    from chekan.report.i18n import LABELS

    return {k for k in LABELS if k.startswith("src_")}


def _sampler(d: Mapping[str, Any], t: Translator) -> str:
    """Which sampler drew the posterior, with the importance sampling's figures where it was
    tried."""
    imp = d.get("importance") or {}
    k = fixed(imp["pareto_k"], 2) if is_num(imp.get("pareto_k")) else "—"
    ess = fixed(imp["ess_min"], 0) if is_num(imp.get("ess_min")) else "—"
    if d["sampler"] == "importance":
        return t("sampler_importance", k=k, ess=ess)
    return t("sampler_refused", k=k, ess=ess) if imp else t("sampler_emcee")


def diagnostics_table(
    rep: Report, result: Mapping[str, Any], t: Translator, lang: str = "en"
) -> None:
    """The diagnostics section: convergence, R-hat, ESS, problems and notes."""
    d = result.get("diagnostics") or {}
    if not d:
        return
    bayes = result["method"] in ("bayes",) or "r_hat_max" in d
    rows: list[tuple[str, str, bool]] = []
    if "converged" in d:
        rows.append((t("converged"), t("yes") if d["converged"] else t("no"), False))
    if is_num(d.get("r_hat_max")):
        rows.append((t("rhat_max"), fixed(d["r_hat_max"], 3), False))
    if is_num(d.get("ess_bulk_min")):
        rows.append((t("ess_min"), fixed(d["ess_bulk_min"], 0), False))
    if d.get("sampler"):
        rows.append((t("sampler"), _sampler(d, t), False))
    if is_num(d.get("n_draws")):
        rows.append((t("n_draws"), fixed(d["n_draws"], 0), False))
    if is_num(d.get("seconds")):
        rows.append((t("seconds"), fixed(d["seconds"], 1), False))
    if is_num(d.get("sigma_mgal")):
        rows.append((t("sigma_fit"), fixed(d["sigma_mgal"], 3), False))
    rep.add(Heading(t("sec_diag" if bayes else "sec_diag_classical")), KeyValue(rows))
    if lang != "en" and (d.get("problems") or d.get("notes")):  # the estimator writes English
        rep.add(Para(t("messages_in_english"), "note"))
    for msg in d.get("problems") or []:
        rep.add(Para(f"{t('problem')}: {with_param_names(str(msg), lang)}", "warn"))
    for msg in d.get("notes") or []:
        rep.add(Para(f"{t('note')}: {with_param_names(str(msg), lang)}", "note"))
