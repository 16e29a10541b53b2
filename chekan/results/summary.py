"""Readable plain-text summary of a ``chekan-result/1`` dict (what ``calibrate`` prints)."""

from __future__ import annotations

import math

ORDER = ("b1", "b2", "a", "b1_0", "b2_0", "eps1_arcmin", "eps2_arcmin", "dgamma_arcmin")
#: What the parameter table of each method holds.
ESTIMATES = {
    "classical": "classical method (Calibr.exe): least squares of eq. (21), all rounds",
    "map": "joint model, MAP with Laplace sds (hyperparameters at their EM values: no sd)",
    "bayes": "joint model, posterior ({sampler}): mean, sd and highest-density interval",
}
#: the sampler that drew the posterior, as the heading names it (``diagnostics.sampler``)
SAMPLER_NAMES = {"importance": "importance sampling", "emcee": "emcee"}


def _f(x, fmt: str) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return format(x, fmt)


def _param_fmt(name: str, value: object = None) -> str:
    if name == "a":
        return ".4e"
    if name.startswith("b"):
        return ".6f"
    if isinstance(value, int | float) and value and abs(value) < 0.01:
        return ".3e"  # a small quantity (κ ~ 1e-4) would print as 0.000
    return ".3f"


def _name(key: str) -> str:
    """A result parameter as a person reads it: the certificate's name (ε₁, b₁₀ (CCD
    centre), κ (slew error, relative)), never the key (eps1_arcmin, b1_0, slew_error)."""
    from chekan.report.i18n import param_name

    return param_name(key, "en")


def _unit(unit: str) -> str:
    """A parameter's unit for the console: mGal/pix², and "relative" for a ratio."""
    from chekan.report.i18n import unit_name

    return unit_name(unit, "en") if unit else "(relative)"


def format_summary(res: dict) -> str:
    lines: list[str] = []
    meta = res.get("metadata", {})
    inst = meta.get("instrument", "Chekan-AM")
    lines.append(
        f"{inst} no. {res['serial']} — method {res['method']} — {res.get('input_kind', 'input')} "
        f"{res['record']}"
    )
    lines.append(
        f"g_local = {res['g_local_mgal']:.2f} mGal;  interval probability {res['hdi_prob']:g}"
    )
    if "level_reading_pix" in res:
        lv = res["level_reading_pix"]
        lines.append(f"level readings m_h: m1 = {lv['m1']:.3f} pix, m2 = {lv['m2']:.3f} pix")
    lines.append("")
    method = res.get("method", "classical")
    scope = ESTIMATES.get(method, method)
    if method == "bayes":
        ran = res.get("diagnostics", {}).get("sampler", "emcee")
        scope = scope.format(sampler=SAMPLER_NAMES.get(ran, ran))
    if res.get("classical_by_axis") and method == "classical":
        scope = scope.replace("all rounds", "the rounds about Y")
    lines.append(f"estimates — {scope}:")
    p = res["parameters"]
    hp = round(res["hdi_prob"] * 100)
    names = [n for n in ORDER if n in p] + sorted(n for n in p if n not in ORDER)
    width = max([15, *(len(_name(n)) + 2 for n in [*names, *res.get("fixed", {})])])
    head = f"{'parameter':<{width}}{'mean':>14}{'sd':>12}{f'{hp}% low':>14}{f'{hp}% high':>14}"
    has_diag = any("r_hat" in e for e in p.values())
    if has_diag:
        head += f"{'R-hat':>8}{'ESS':>8}"
    lines.append(head + "  unit")
    for n in names:
        e = p[n]
        fmt = _param_fmt(n, e.get("mean"))
        row = (
            f"{_name(n):<{width}}{_f(e.get('mean'), fmt):>14}{_f(e.get('sd'), '.2e'):>12}"
            f"{_f(e.get('hdi_low'), fmt):>14}{_f(e.get('hdi_high'), fmt):>14}"
        )
        if has_diag:
            row += f"{_f(e.get('r_hat'), '.3f'):>8}{_f(e.get('ess_bulk'), '.0f'):>8}"
        lines.append(row + f"  {_unit(str(e.get('unit', '')))}")
    for k, v in res.get("fixed", {}).items():
        lines.append(f"{_name(k):<{width}}{_f(v, _param_fmt(k, v)):>14}  (fixed)")
    if "a" in p or "a" in res.get("fixed", {}):
        lines.append(
            "(a in the record's convention, Δg = b(m − m_h) + a(m − m_h)² with readings growing "
            "with gravity; a legacy protocol prints it with the opposite sign)"
        )
    by_axis = res.get("classical_by_axis")
    if by_axis:
        lines.append("")
        lines.append(
            "classical method per axis: rounds about Y and about X fitted apart, each with "
            "its own a; the classical b and a above are those of the rounds about Y (eq. 14: "
            "the response to tilts about Y)"
        )
        for axis, entry in by_axis.items():
            lines.append("")
            use = "the certificate's" if entry.get("used_by_certificate") else "not certified"
            rounds = ", ".join(str(r["round"]) for r in entry.get("rounds", []))
            lines.append(f"rounds about {axis.upper()} (round(s) {rounds}; {use}):")
            if not entry.get("used_by_certificate"):
                lines.extend(_axis_parameters(entry))
            lines.extend(_classical_tables(entry, method, res_level=False))
    else:
        lines.extend(_classical_tables(res, method, res_level=True))
    lines.append("")
    if "mean_b_mgal_per_pix" in res:
        which = "rounds about Y" if by_axis else "rounds"
        lines.append(
            f"mean b over systems and {which} («Среднее»): "
            f"{res['mean_b_mgal_per_pix']:.6f} mGal/pix"
        )
    if "reduced_error_percent" in res:
        lines.append(f"reduced error of the characteristic: {res['reduced_error_percent']:.3f} %")
    if res.get("discrepancy_between_rounds_percent") is not None:
        lines.append(
            f"discrepancy between rounds: {res['discrepancy_between_rounds_percent']:.3f} %"
        )
    for k, v in (res.get("instability_percent") or {}).items():
        if v is not None:
            lines.append(f"instability of {k} against the prior: {v:+.3f} %")
    ht = res.get("hold_transient")
    if ht:  # chekan.results.document.settled_items
        raw = ht.get("calibr_exe") or {}
        parts = [f"{k} = {raw[k]['mean']:.6f} mGal/pix" for k in ("b1", "b2") if k in raw]
        if raw.get("reduced_error_percent") is not None:
            parts.append(f"reduced error {raw['reduced_error_percent']:.3f} %")
        lines.append(
            f"the classical items above are from the hold means less the lag's transient "
            f"(up to {ht['max_pix']:.2g} pix: settling {ht['settle_s']:g} s against "
            f"τ = {ht['tau_s']:.1f} s); from the raw hold means, as Calibr.exe: " + ", ".join(parts)
        )
    if "range_margin_gal" in res:
        rm = res["range_margin_gal"]
        lines.append(
            f"range margin: {rm['heavy']:.1f} Gal heavy side, {rm['light']:.1f} Gal light side"
        )
    d = res.get("diagnostics", {})
    if d:
        conv = d.get("converged")
        lines.append(
            f"converged: {'yes' if conv else 'NO'}"
            + "".join(
                f"; {k} = {v:.4g}"
                for k, v in d.items()
                if isinstance(v, int | float) and k != "converged"
            )
        )
        if d.get("sampler"):
            lines.append(f"posterior drawn by: {sampler_words(d)}")
        from chekan.report.i18n import with_param_names  # ε₁ for eps1_arcmin, as printed above

        for msg in d.get("problems", []):
            lines.append(f"WARNING: {with_param_names(str(msg), 'en')}")
        for msg in d.get("notes", []):
            lines.append(f"note: {with_param_names(str(msg), 'en')}")
    return "\n".join(lines)


def sampler_words(diag: dict) -> str:
    """Which sampler drew the posterior, with its figures (the console's and the
    certificate's line)."""
    imp = diag.get("importance") or {}
    k, ess = imp.get("pareto_k"), imp.get("ess_min")
    figures = (
        f"Pareto k = {_f(k, '.2f')}, smallest ESS {_f(ess, '.0f')} of {imp.get('n_points')} draws"
    )
    refits = int(imp.get("proposal_refits") or 0)
    if refits:
        figures += f", the proposal refitted to weighted draws {refits}×"
    if diag.get("sampler") == "importance":
        return f"importance sampling from the fitted proposal ({figures})"
    if imp:
        return f"emcee ({imp.get('message') or 'importance sampling refused: ' + figures})"
    return "emcee"


def _axis_parameters(entry: dict) -> list[str]:
    """b₁, b₂ and a of one axis's fit, one line."""
    p = entry.get("parameters", {})
    parts = [
        f"{n} = {_f(p[n]['mean'], _param_fmt(n))} ± {_f(p[n].get('sd'), '.1e')}"
        for n in ("b1", "b2", "a")
        if n in p
    ]
    return ["  " + ", ".join(parts)] if parts else []


def _classical_tables(res: dict, method: str, *, res_level: bool) -> list[str]:
    """The classical increments, deviations and СКП table, and b per round."""
    lines: list[str] = []
    rs = res.get("residuals_mgal")
    if rs and "columns" in rs:
        cols = rs["columns"]
        lines.append("")
        if method != "classical" and res_level:
            lines.append(
                "classical method (Calibr.exe), shown beside the joint estimate (the tables "
                "below, to the mean b and the range margin)"
            )
        lines.append("increments dg and deviations δg = da_ref − dg, mGal")
        lines.append(
            f"{'angle':<9}{'da_ref':>9}"
            + "".join(f"{'dg ' + c:>12}" for c in cols)
            + "".join(f"{'δg ' + c:>11}" for c in cols)
            + f"{'mean δg':>9}"
        )
        for i, lab in enumerate(rs["angle_label"]):
            row = f"{lab:<9}{_f(rs['da_ref_mgal'][i], '.2f'):>9}"
            row += "".join(f"{_f(rs['dg_mgal'][c][i], '.2f'):>12}" for c in cols)
            row += "".join(f"{_f(rs['delta_g_mgal'][c][i], '.2f'):>11}" for c in cols)
            row += f"{_f(rs['mean_delta_g_mgal'][i], '.2f'):>9}"
            lines.append(row)
        lines.append(
            f"{'СКП/RMS':<18}"
            + " " * (12 * len(cols))
            + "".join(f"{_f(rs['rms_mgal'][c], '.2f'):>11}" for c in cols)
        )
    if res.get("rounds"):
        lines.append("")
        lines.append("scale factors per round (classical, eq. 21):")
        for r in res["rounds"]:
            b1, b2 = r["b1"], r["b2"]
            lines.append(
                f"round {r['round']}: b1 = {_f(b1['mean'], '.6f')} ± {_f(b1.get('sd'), '.1e')}, "
                f"b2 = {_f(b2['mean'], '.6f')} ± {_f(b2.get('sd'), '.1e')} mGal/pix"
            )
    if not res_level:
        if "mean_b_mgal_per_pix" in res:
            lines.append(
                f"mean b over systems and rounds: {res['mean_b_mgal_per_pix']:.6f} mGal/pix"
            )
        if "reduced_error_percent" in res:
            lines.append(
                f"reduced error of the characteristic: {res['reduced_error_percent']:.3f} %"
            )
        if res.get("discrepancy_between_rounds_percent") is not None:
            d = res["discrepancy_between_rounds_percent"]
            lines.append(f"discrepancy between rounds: {d:.3f} %")
    return lines
