"""From a ``chekan-result/1`` dict to the certificate's blocks (language-neutral model).

Sections follow the paper's protocol (Fig. 6, items а)–е)), then the uncertainty
budget and the diagnostics of the Bayesian method when present, and the verdict.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from chekan.classical.settling import UNSETTLED_PIX, unsettled_transient_pix
from chekan.errors import ChekanError, FormatError
from chekan.report import figures as figs
from chekan.report.checks import check_certificate_input, states_expanded_uncertainty
from chekan.report.document import Figure, Heading, KeyValue, Para, Report
from chekan.report.expanded import K_NORMAL, b_uncertainty, expanded_of
from chekan.report.i18n import (
    LABELS,
    Translator,
    param_name,
    source_name,
    tr,
    unit_name,
    value_name,
)
from chekan.report.numbers import (
    DASH,
    coverage_text,
    fixed,
    general,
    is_num,
    plain,
    sci,
    statement,
    unc,
    value_unc,
)
from chekan.report.rounds import deviations_tables, increments_tables, rounds_table
from chekan.report.tables import (  # PARAM_ORDER, BUDGET_ORDER: re-exported
    BUDGET_ORDER,  # noqa: F401
    PARAM_ORDER,  # noqa: F401
    angle_bound_text,
    budget_table,
    diagnostics_table,
    param_table,
)
from chekan.report.verdict import (  # verdict_of: re-exported
    verdict_of,  # noqa: F401
    verdict_paras,
)

FULL_RANGE_MGAL = 5000.0  # Δ₀ = 5 Gal


# --------------------------------------------------------------------------- helpers


def _a_value(result: Mapping[str, Any]) -> tuple[float | None, bool]:
    """``(a, fixed?)`` from the parameters or the fixed values."""
    p = result["parameters"]
    if "a" in p:
        return float(p["a"]["mean"]), False
    fx = (result.get("fixed") or {}).get("a")
    return (float(fx), True) if is_num(fx) else (None, False)


def _resolve(path: str | Path | None, source: str | Path | None) -> Path | None:
    """An existing file: ``path`` as given, else relative to the result file's folder."""
    if not path:
        return None
    p = Path(path)
    if p.is_file():
        return p
    if source is not None and not p.is_absolute():
        q = Path(source).resolve().parent / p
        if q.is_file():
            return q
    return None


# --------------------------------------------------------------------------- sections


def _header(rep: Report, result: Mapping[str, Any], t: Translator, lang: str) -> None:
    meta = result.get("metadata") or {}
    inst = value_name(str(meta.get("instrument", "Chekan-AM")), lang)
    rows: list[tuple[str, str, bool]] = []
    model = meta.get("model")
    rows.append(
        (
            t("instrument"),
            t("model_fmt", instrument=inst, model=value_name(str(model), lang)) if model else inst,
            False,
        )
    )
    rows.append((t("serial"), str(result["serial"]), False))
    if meta.get("platform_serial"):
        rows.append((t("platform_serial"), str(meta["platform_serial"]), False))
    if meta.get("site"):
        rows.append((t("site"), value_name(str(meta["site"]), lang), False))
    coords = []
    from chekan.physics.units import format_dms

    for key, lab in (("latitude_deg", "lat"), ("longitude_deg", "lon")):
        try:
            coords.append(f"{t(lab)} {format_dms(float(meta[key]), seconds=True, sign='always')}")
        except (KeyError, ValueError, TypeError):
            pass
    if meta.get("height_m"):
        coords.append(t("height", h=meta["height_m"]))
    if coords:
        rows.append((t("coords"), ", ".join(coords), False))
    rows.append((t("g_local"), f"{fixed(result['g_local_mgal'], 2)} {t('mgal')}", False))
    date = result.get("date") or meta.get("date") or str(meta.get("started", ""))[:10]
    if date:
        rows.append((t("date"), str(date), False))
    if meta.get("started"):
        rows.append((t("started"), str(meta["started"]), False))
    if meta.get("operator"):
        rows.append((t("operator"), str(meta["operator"]), False))
    prog = program_text(result, t)
    if prog:
        rows.append((t("program"), prog, False))
    method = result["method"]
    rows.append((t("method"), f"{t('method_' + method)} [{method}]", False))
    sensor = _angle_sensor_text(result, t, lang)
    if sensor:
        rows.append((t("angle_sensor"), sensor, False))
    cal = _angle_calibration_text(result, t)
    if cal:
        rows.append((t("angle_calibration"), cal, False))
    kind = result.get("input_kind")
    rec = str(result["record"])
    rows.append(
        (
            t("input"),
            rec + (f" — {t('input_' + kind)}" if kind in ("record", "protocol") else ""),
            False,
        )
    )
    if result.get("record_sha256"):
        rows.append((t("sha"), str(result["record_sha256"]), True))
    sw = result.get("software") or {}
    rows.append((t("software"), f"{sw.get('name', 'chekan')} {sw.get('version', '?')}", False))
    if result.get("created"):
        rows.append((t("created"), str(result["created"]), False))
    lv = result.get("level_reading_pix")
    if isinstance(lv, dict) and lv:
        rows.append(
            (
                t("level"),
                f"m₁ = {fixed(lv.get('m1'), 3)} {t('pix')}, m₂ = {fixed(lv.get('m2'), 3)} "
                f"{t('pix')}",
                False,
            )
        )
    if is_num(result.get("ccd_center_pix")):
        rows.append((t("ccd_center"), f"{plain(result['ccd_center_pix'])} {t('pix')}", False))
    if is_num(result.get("hdi_prob")):
        rows.append((t("interval_prob"), plain(result["hdi_prob"]), False))
    rep.add(Heading(t("sec_header")), KeyValue(rows))


def program_text(result: Mapping[str, Any], t: Translator) -> str | None:
    """The tilt program as run: name, rounds and the axis of each, angles, dwell (settle)."""
    meta = result.get("metadata") or {}
    tp = result.get("tilt_program")
    name = str(tp.get("name") or meta.get("program") or "") if isinstance(tp, dict) else ""
    if not isinstance(tp, dict) or not isinstance(tp.get("rounds"), list) or not tp["rounds"]:
        return str(meta["program"]) if meta.get("program") else None
    rounds = [r for r in tp["rounds"] if isinstance(r, dict)]
    axes = [str(r.get("axis", "y")).upper() for r in rounds]
    if len(set(axes)) == 1:
        parts = [t("prog_rounds", n=len(rounds), axis=axes[0])]
    else:
        each = ", ".join(f"{r.get('round', '')} {a}" for r, a in zip(rounds, axes, strict=True))
        parts = [t("prog_rounds_each", n=len(rounds), each=each)]
    by_axis: dict[str, list[str]] = {}
    for r, a in zip(rounds, axes, strict=True):
        for lab in r.get("angles") or []:
            if str(lab) not in by_axis.setdefault(a, []):
                by_axis[a].append(str(lab))
    if len({tuple(v) for v in by_axis.values()}) <= 1:
        angles = ", ".join(tp.get("angles") or next(iter(by_axis.values()), []))
        parts.append(t("prog_angles", angles=angles))
    else:
        for a, labs in by_axis.items():
            parts.append(t("prog_angles_axis", axis=a, angles=", ".join(labs)))
    if is_num(tp.get("dwell_s")):
        settle = tp.get("settle_s")
        parts.append(
            t("prog_dwell", dwell=plain(tp["dwell_s"]), settle=plain(settle))
            if is_num(settle)
            else t("prog_dwell_only", dwell=plain(tp["dwell_s"]))
        )
    return (f"{name} — " if name else "") + "; ".join(parts)


def _statements(result: Mapping[str, Any], t: Translator, lang: str) -> list[Para]:
    """The result lines "b₁ = … , U = … (k = 2)" for b1, b2, b1_0, b2_0 (k = t₉₅.₄₅(ν_eff)
    where the result states ν_eff: :mod:`chekan.report.expanded`); the classical method's
    "b₁ = …, 2s = …": Calibr.exe's repeatability, named so, not an expanded uncertainty."""
    if not states_expanded_uncertainty(result):
        return _repeatability_statements(result, t, lang)
    out: list[Para] = [Para(t("statement_title"), "strong")]
    params = result["parameters"]
    budget_used = False
    student = False
    for name in ("b1", "b2", "b1_0", "b2_0"):
        if name not in params:
            continue
        if name in ("b1", "b2"):
            budget_used |= b_uncertainty(result, name)[1]
        big_u, k = expanded_of(result, name)
        student |= k != K_NORMAL
        out.append(
            Para(
                statement(
                    param_name(name, lang),
                    params[name]["mean"],
                    big_u,
                    unit_name("mGal/pix", lang),
                    k=k,
                ),
                "strong",
            )
        )
    if budget_used:
        note = t("statement_budget_t") if student else t("statement_budget")
    else:
        note = t("statement_typeA")
    bud = result.get("uncertainty_budget") or {}
    if budget_used and any(
        is_num(v)
        for n in ("b1", "b2")
        for k, v in (bud.get(n) or {}).items()
        if k.startswith("angle_systematic")
    ):
        note += " " + t("statement_budget_systematic", bound=angle_bound_text(result))
    out.append(Para(note, "note"))
    return out


def _repeatability_statements(result: Mapping[str, Any], t: Translator, lang: str) -> list[Para]:
    """The classical b with 2s, the repeatability Calibr.exe prints (twice the least-squares
    standard error), and what it leaves out."""
    out: list[Para] = [Para(t("statement_title_repeat"), "strong")]
    params = result["parameters"]
    unit = unit_name("mGal/pix", lang)
    for name in ("b1", "b2", "b1_0", "b2_0"):
        if name not in params:
            continue
        sd = params[name].get("sd")
        xs, us = value_unc(params[name]["mean"], 2.0 * sd if is_num(sd) else None)
        out.append(
            Para(
                t("statement_repeat", name=param_name(name, lang), x=xs, u=us, unit=unit), "strong"
            )
        )
    out.append(Para(t("statement_typeA"), "warn"))
    return out


def _angle_sensor_text(result: Mapping[str, Any], t: Translator, lang: str) -> str | None:
    """The platform angle sensor's model from ``result["angle_sensor"]`` (None without it)."""
    a = result.get("angle_sensor")
    if not isinstance(a, Mapping):
        return None
    if a.get("model") == "independent":
        return t("angle_sensor_independent")
    src = source_name(str(a["source"]), lang) if a.get("source") else ""
    source = f"; {t('angle_source', src=src)}" if src else ""
    if isinstance(a.get("calibration"), Mapping):
        stated = a.get("axis") in (a["calibration"].get("scale_U_arcsec") or {})
        return t(
            "angle_sensor_calibrated_stated" if stated else "angle_sensor_calibrated",
            ua=fixed(a.get("u_per_angle_arcsec"), 2),
            us=fixed(a.get("u_scale_arcsec"), 2),
        )
    if not is_num(a.get("bound_arcsec")):
        return None
    dist = str(a.get("distribution", "rectangular"))
    key = f"dist_{dist}_gum" if f"dist_{dist}_gum" in LABELS else f"dist_{dist}"
    text = t(
        "angle_sensor_systematic",
        u=plain(a["bound_arcsec"]),
        dist=t(key),
        ua=fixed(a.get("u_per_angle_arcsec"), 2),
        us=fixed(a.get("u_scale_arcsec"), 2),
    )
    return text + source


def _angle_calibration_text(result: Mapping[str, Any], t: Translator) -> str | None:
    """The platform's angle calibration the result used (traceability of the angle)."""
    c = result.get("angle_calibration")
    if not isinstance(c, Mapping) or not c.get("id"):
        return None
    lab = f", {c['laboratory']}" if c.get("laboratory") else ""
    return t("angle_calibration_text", id=c["id"], date=c.get("date", "?"), lab=lab)


def _items(
    rep: Report,
    result: Mapping[str, Any],
    t: Translator,
    lang: str,
    tol: float,
    cos_fig: Figure | None,
    figures: bool = True,
) -> None:
    rs = result.get("residuals_mgal")
    pp = result.get("posterior_predictive_mgal")
    # а) increments
    rep.add(Heading(t("sec_a")), Para(t("sec_a_text")))
    if cos_fig is not None:
        rep.add(cos_fig)
    by_axis = result.get("classical_by_axis") or {}
    about = t("cap_about", axis="Y") if by_axis else ""  # the certificate's rounds
    if rs:
        rep.add(*increments_tables(rs, t, t("cap_a") + about))
        # б) deviations
        rep.add(Heading(t("sec_b")), Para(t("sec_b_text")))
        rep.add(*deviations_tables(rs, t, t("cap_b") + about))
        tol_mgal = tol / 100.0 * FULL_RANGE_MGAL
        cap = t("fig_resid", tol=plain(tol)) + (t("fig_resid_pp") if pp else "")
        if figures:
            png = figs.residual_figure(rs, t, tol_mgal=tol_mgal, band=pp)
            rep.add(Figure("residuals", png, cap))
    # в) reduced error
    rerr = result.get("reduced_error_percent")
    if is_num(rerr):
        rep.add(Heading(t("sec_c")), Para(t("sec_c_text")))
        m_s, ang = DASH, DASH
        if rs and rs.get("mean_delta_g_mgal"):
            vals = [abs(v) if is_num(v) else -1.0 for v in rs["mean_delta_g_mgal"]]
            k = max(range(len(vals)), key=vals.__getitem__)
            m_s, ang = fixed(vals[k], 2), str(rs["angle_label"][k])  # |mean δg|: unsigned
        rep.add(Para(t("reduced_error", v=fixed(rerr, 3), m=m_s, angle=ang), "strong"))
    # г) a, b1, b2
    rep.add(Heading(t("sec_d")), Para(t("sec_d_text")))
    rounds = result.get("rounds") or []
    if rounds:
        rep.add(rounds_table(rounds, t, t("cap_rounds") + about))
    param_table(rep, result, t, lang)
    if is_num(result.get("mean_b_mgal_per_pix")):
        rep.add(Para(t("mean_b", v=fixed(result["mean_b_mgal_per_pix"], 6))))
    if is_num(result.get("discrepancy_between_rounds_percent")):
        rep.add(Para(t("discrepancy", v=fixed(result["discrepancy_between_rounds_percent"], 3))))
    a, _ = _a_value(result)
    if a is not None:
        rep.add(Para(t("a_convention", v=sci(-a, 4) if a else "0"), "note"))
    cert_axis = certified_axis(result)
    for axis, entry in by_axis.items():
        if axis != cert_axis:  # the certificate's own rounds are items a)–d) above
            _other_axis(rep, axis, entry, t)
    _rest_of_items(rep, result, t, lang, tol, figures)


def certified_axis(result: Mapping[str, Any]) -> str | None:
    """The axis ("y", "x") of ``classical_by_axis`` whose rounds the certificate's items are:
    the entry marked ``used_by_certificate``, else the result's ``classical_axis`` (a result
    whose marks were lost: a classical fit flagged with unsettled hold means)."""
    by_axis = result.get("classical_by_axis") or {}
    marked = [
        a for a, e in by_axis.items() if isinstance(e, Mapping) and e.get("used_by_certificate")
    ]
    if marked:
        return marked[0]
    axis = str(result.get("classical_axis") or "").lower()
    return axis if axis in by_axis else None


def _other_axis(rep: Report, axis: str, entry: Mapping[str, Any], t: Translator) -> None:
    """The classical fit of the rounds about another axis than the certificate's, in full,
    with what it is (not used by the certificate, and why)."""
    rounds = entry.get("rounds") or []
    nums = ", ".join(str(r.get("round", "")) for r in rounds)
    rep.add(Heading(t("sec_axis", axis=axis.upper())), Para(t("sec_axis_text", rounds=nums)))
    about = t("cap_about", axis=axis.upper())
    rs = entry.get("residuals_mgal")
    if rs:
        rep.add(*increments_tables(rs, t, t("cap_a") + about))
        rep.add(*deviations_tables(rs, t, t("cap_b") + about))
    if rounds:
        rep.add(rounds_table(rounds, t, t("cap_rounds") + about))
    p = entry.get("parameters") or {}
    parts = [
        f"{param_name(n, 'en')} = {fixed(p[n]['mean'], 6)} ± {unc(p[n].get('sd'))}"
        for n in ("b1", "b2")
        if n in p
    ]
    if "a" in p:
        parts.append(f"a = {sci(p['a']['mean'], 4)} ± {sci(p['a'].get('sd'), 1)}")
    if parts:
        rep.add(Para(t("axis_fit", axis=axis.upper(), fit="; ".join(parts))))


def _rest_of_items(
    rep: Report,
    result: Mapping[str, Any],
    t: Translator,
    lang: str,
    tol: float,
    figures: bool,
) -> None:
    # д) instability
    rep.add(Heading(t("sec_e")))
    inst = result.get("instability_percent") or {}
    prior = result.get("b_prior") or {}
    any_inst = False
    for name in ("b1", "b2"):
        v = inst.get(name)
        if not is_num(v):
            continue
        any_inst = True
        u, k = expanded_of(result, name)
        p = prior.get(name)
        big_u = 100.0 * u / p if u is not None and is_num(p) and p else None
        repeat = not states_expanded_uncertainty(result)  # 2s: Calibr.exe's repeatability
        rep.add(
            Para(
                t(
                    "instability_repeat" if repeat else "instability",
                    name=param_name(name, lang),
                    v=fixed(v, 3, sign=True),
                    u=unc(big_u) if big_u is not None else DASH,
                    k=coverage_text(k),
                    prior=fixed(p, 6) if is_num(p) else DASH,
                )
            )
        )
    if not any_inst:
        rep.add(Para(t("no_prior"), "note"))
    # е) range margin
    rep.add(Heading(t("sec_f")))
    rm = result.get("range_margin_gal")
    if rm and is_num(rm.get("heavy")) and is_num(rm.get("light")):
        meta = result.get("metadata") or {}
        try:
            from chekan.physics.units import format_dms

            lat = format_dms(float(meta["latitude_deg"]), seconds=True, sign="always")
            rep.add(Para(t("margin_at", lat=lat)))
        except (KeyError, ValueError, TypeError):
            rep.add(Para(t("margin_plain")))
        rep.add(
            Para(t("margin_heavy", v=fixed(rm["heavy"], 1)), "strong"),
            Para(t("margin_light", v=fixed(rm["light"], 1)), "strong"),
        )
        rng = result.get("ccd_range_pix")
        if isinstance(rng, list) and len(rng) == 2:
            rep.add(Para(t("margin_ccd", lo=plain(rng[0]), hi=plain(rng[1])), "note"))
    else:
        rep.add(Para(t("no_margin"), "note"))


# --------------------------------------------------------------------------- record, posterior


def _record_figures(
    result: Mapping[str, Any],
    record_path: str | Path | None,
    source: str | Path | None,
    t: Translator,
) -> tuple[list[Figure], Figure | None, list[Para]]:
    """(figures of the record, the cosinusoid figure, notes) — figures omitted with a note."""
    if result.get("input_kind") == "protocol" and record_path is None:
        return [], None, [Para(t("no_record_protocol"), "note")]
    given = record_path if record_path is not None else result.get("record")
    path = _resolve(given, source)
    if path is None:
        return [], None, [Para(t("no_record_file", path=str(given)), "note")]
    want = result.get("record_sha256")
    if want:
        from chekan.results.document import sha256_file

        if sha256_file(path) != want:
            return [], None, [Para(t("record_changed", path=str(path)), "warn")]
    try:
        from chekan.records.holds import segment_record, settle_of
        from chekan.records.inputs import read_input

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = read_input(path)
            if hasattr(rec, "dg_mgal"):  # a protocol: no raw readings
                return [], None, [Para(t("no_record_protocol"), "note")]
            holds = segment_record(rec, settle_s=settle_of(rec))
    except (ChekanError, OSError, ValueError) as e:
        return [], None, [Para(t("record_unreadable", path=str(path), err=str(e)), "warn")]
    fig_rec = Figure("record", figs.record_figure(rec, holds, t), t("fig_record"))
    transient = unsettled_transient_pix(result, holds, rec)  # once: figure and note
    png = figs.cosinusoid_figure(holds, result, t, transient)
    if png is None:
        a, _ = _a_value(result)
        return [fig_rec], None, [Para(t("no_cos_model", a=general(a)), "note")]
    gamma = t("fig_cos_gamma") if "dgamma_arcmin" in result["parameters"] else ""
    band = t("fig_cos_band_model" if figs.has_noise_model(result) else "fig_cos_band_rms")
    cap = t("fig_cos", gamma=gamma, band=band)
    if transient is not None:
        cap += " " + t(
            "fig_cos_lag"
        )  # the residuals of chekan.classical.settling.lagged_hold_means
    return [fig_rec], Figure("cosinusoid", png, cap), transient_note(result, holds, transient, t)


def transient_note(
    result: Mapping[str, Any], holds: Any, transient: np.ndarray | None, t: Translator
) -> list[Para]:
    """A warning where the hold means still carry the slews' transients (``transient``,
    :func:`chekan.classical.settling.unsettled_transient_pix`; a settling time short beside τ)
    and the result's classical items were computed from them (a result written before
    :func:`chekan.results.document.settled_items` existed): they and the verdict's reduced
    error are biased by them, the joint model is not. A result whose items were settled states it in
    :func:`settled_note` instead."""
    if "hold_transient" in result or transient is None:
        return []
    if not np.any(np.abs(transient) > UNSETTLED_PIX):
        return []
    tau = float(result["parameters"]["tau_s"]["mean"])
    worst = float(np.nanmax(np.abs(transient)))
    text = t("transient_note", pix=fixed(worst, 1), settle=plain(holds.settle_s), tau=fixed(tau, 1))
    return [Para(text, "warn")]


def settled_note(result: Mapping[str, Any], t: Translator) -> list[Para]:
    """Where the joint model removed the lag's transient from the hold means before the
    classical items (``hold_transient``, :func:`chekan.results.document.settled_items`): how much,
    and Calibr.exe's figures from the raw hold means, which the items no longer show."""
    ht = result.get("hold_transient")
    if not isinstance(ht, Mapping):
        return []
    raw = ht.get("calibr_exe") or {}

    def b(name: str) -> str:
        v = (raw.get(name) or {}).get("mean")
        return fixed(v, 6) if is_num(v) else DASH

    rerr = raw.get("reduced_error_percent")
    text = t(
        "settled_note",
        pix=fixed(ht["max_pix"], 2),
        settle=plain(ht["settle_s"]),
        tau=fixed(ht["tau_s"], 1),
        b1=b("b1"),
        b2=b("b2"),
        rerr=fixed(rerr, 3) if is_num(rerr) else DASH,
    )
    return [Para(text, "note")]


def _posterior_figures(
    rep: Report,
    result: Mapping[str, Any],
    netcdf_path: str | Path | None,
    source: str | Path | None,
    t: Translator,
    lang: str,
) -> None:
    given = netcdf_path if netcdf_path is not None else result.get("posterior_netcdf")
    if given:
        path = _resolve(given, source)
        if path is None:
            rep.add(Para(t("no_netcdf", path=str(given)), "note"))
        else:
            try:
                draws = figs.read_posterior(path)
            except Exception as e:  # h5py/xarray raise many kinds; the certificate goes on
                rep.add(
                    Para(t("bad_netcdf", path=str(path), err=f"{type(e).__name__}: {e}"), "warn")
                )
            else:
                draws = {k: v for k, v in draws.items() if v.size and math.isfinite(float(v.std()))}
                if len(draws) >= 2:
                    rep.add(Figure("pair", figs.pair_figure(draws, lang), t("fig_pair"), width=0.9))
    dc = result.get("drift_curve")
    if dc and dc.get("t_h"):
        rep.add(Figure("drift", figs.drift_figure(dc, t), t("fig_drift")))


# --------------------------------------------------------------------------- entry


def build_report(
    result: Mapping[str, Any],
    *,
    lang: str = "en",
    tolerance_percent: float = 0.05,
    record_path: str | Path | None = None,
    netcdf_path: str | Path | None = None,
    source: str | Path | None = None,
    figures: bool = True,
    lab: Mapping[str, Any] | None = None,
    customer: str | None = None,
) -> Report:
    """The certificate of ``result`` as blocks (figures as PNG unless ``figures=False``);
    ``lab``: a :func:`chekan.report.dcc.load_lab` dict (issuer, authoriser, customer)."""
    from chekan.report.issue import add_end, add_issue_block

    t = tr(lang)
    src = str(source) if source is not None else "<result>"
    check_certificate_input(result, src)
    meta = result.get("metadata") or {}
    inst = value_name(str(meta.get("instrument", "Chekan-AM")), lang)
    serial = str(result["serial"])
    draft = not (lab and lab.get("lab"))  # no issuing laboratory: a draft on every page
    rep = Report(
        lang=lang,
        title=t("title_draft" if draft else "title"),
        subtitle=t("subtitle", instrument=inst, serial=serial),
        running_head=t(
            "running_head_draft" if draft else "running_head", instrument=inst, serial=serial
        ),
        draft=draft,
    )
    try:
        _header(rep, result, t, lang)
        add_issue_block(rep, result, t, lab=lab, customer=customer)
        rec_figs, cos_fig, notes = (
            _record_figures(result, record_path, source, t) if figures else ([], None, [])
        )
        rep.add(*rec_figs, *notes, *settled_note(result, t))
        conf, verdict = verdict_paras(result, t, tolerance_percent)
        rep.add(Heading(t("sec_summary")), *_statements(result, t, lang), verdict[0])
        if conf.outcome is not None:  # a verdict said here states its decision rule (7.8.6)
            rep.add(Para(t("decision_rule_ref"), "note"))
        _items(rep, result, t, lang, tolerance_percent, cos_fig, figures)
        budget_table(rep, result, t, lang)
        if figures and (
            result["method"] == "bayes"
            or result.get("posterior_netcdf")
            or result.get("drift_curve")
        ):
            _posterior_figures(rep, result, netcdf_path, source, t, lang)
        diagnostics_table(rep, result, t, lang)
        rep.add(Heading(t("sec_verdict")), *verdict)
        sw = result.get("software") or {}
        rep.add(
            Para(
                t(
                    "footer_note",
                    version=sw.get("version", "?"),
                    created=result.get("created", "?"),
                ),
                "note",
            )
        )
        add_end(rep, t)
    except (KeyError, TypeError, IndexError, AttributeError) as e:
        raise FormatError(src, None, f"malformed result ({type(e).__name__}: {e})") from e
    return rep
