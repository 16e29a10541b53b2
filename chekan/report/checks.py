"""What a certificate may state of a ``chekan-result/1`` dict, shared by the PDF/HTML
certificate and the DCC: its input check (each optional part refused with a
:class:`FormatError` naming it), the decision rule of its conformity statement
(:func:`conformity`, ILAC-G8:09/2019) and whether its results are metrologically
traceable (:func:`traceability`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from chekan.errors import FormatError
from chekan.report.expanded import expanded_of
from chekan.report.numbers import is_num


def _fail(src: str, problem: str) -> FormatError:
    return FormatError(src, None, problem)


def _need_list(obj: Any, where: str, src: str, n: int | None = None) -> list:
    if not isinstance(obj, list):
        raise _fail(src, f"{where} must be a list")
    if n is not None and len(obj) != n:
        raise _fail(src, f"{where} has {len(obj)} values, expected {n} (one per angle)")
    return obj


def _need_dict(obj: Any, where: str, src: str) -> dict:
    if not isinstance(obj, dict):
        raise _fail(src, f"{where} must be an object")
    return obj


def _check_classical_part(part: Mapping[str, Any], at: str, src: str) -> None:
    """The parameters, residual tables and rounds of a result (or of one axis's fit in
    ``classical_by_axis``, ``at`` its prefix)."""
    for name, e in _need_dict(part.get("parameters", {}), f"{at}parameters", src).items():
        if not isinstance(e, dict) or not is_num(e.get("mean")):
            raise _fail(src, f"{at}parameters.{name}.mean is not a number")
    rs = part.get("residuals_mgal")
    if rs is not None:
        _need_dict(rs, f"{at}residuals_mgal", src)
        for k in ("angle_label", "columns", "da_ref_mgal", "dg_mgal", "delta_g_mgal"):
            if k not in rs:
                raise _fail(src, f"{at}residuals_mgal.{k} is missing")
        n = len(_need_list(rs["angle_label"], f"{at}residuals_mgal.angle_label", src))
        _need_list(rs["da_ref_mgal"], f"{at}residuals_mgal.da_ref_mgal", src, n)
        if "mean_delta_g_mgal" in rs:
            _need_list(rs["mean_delta_g_mgal"], f"{at}residuals_mgal.mean_delta_g_mgal", src, n)
        for c in _need_list(rs["columns"], f"{at}residuals_mgal.columns", src):
            for k in ("dg_mgal", "delta_g_mgal"):
                d = _need_dict(rs[k], f"{at}residuals_mgal.{k}", src)
                if c not in d:
                    raise _fail(src, f"{at}residuals_mgal.{k} has no column {c!r}")
                _need_list(d[c], f"{at}residuals_mgal.{k}.{c}", src, n)
    for i, r in enumerate(_need_list(part.get("rounds", []), f"{at}rounds", src)):
        _need_dict(r, f"{at}rounds[{i}]", src)
        for s in ("b1", "b2"):
            if not isinstance(r.get(s), dict) or "mean" not in r[s]:
                raise _fail(src, f"{at}rounds[{i}].{s}.mean is missing")


def check_certificate_input(result: Mapping[str, Any], src: str) -> None:
    """Check the optional parts the certificate reads; raise :class:`FormatError` naming them."""
    _check_classical_part(result, "", src)
    by_axis = result.get("classical_by_axis")
    if by_axis is not None:
        for axis, entry in _need_dict(by_axis, "classical_by_axis", src).items():
            where = f"classical_by_axis.{axis}"
            if axis not in ("x", "y"):
                raise _fail(src, f"{where}: the axis must be 'x' or 'y'")
            _check_classical_part(_need_dict(entry, where, src), where + ".", src)
    bud = result.get("uncertainty_budget")
    if bud is not None:
        for s, comp in _need_dict(bud, "uncertainty_budget", src).items():
            for k, v in _need_dict(comp, f"uncertainty_budget.{s}", src).items():
                if v is not None and not is_num(v):
                    raise _fail(src, f"uncertainty_budget.{s}.{k} is not a number")
    dc = result.get("drift_curve")
    if dc is not None:
        _need_dict(dc, "drift_curve", src)
        if "t_h" not in dc:
            raise _fail(src, "drift_curve.t_h is missing")
        n = len(_need_list(dc["t_h"], "drift_curve.t_h", src))
        for k, v in dc.items():
            if len(_need_list(v, f"drift_curve.{k}", src)) != n:
                raise _fail(src, f"drift_curve.{k} has {len(v)} values, t_h has {n}")
    pp = result.get("posterior_predictive_mgal")
    if pp is not None:
        _need_dict(pp, "posterior_predictive_mgal", src)
        for k in ("delta_g_low", "delta_g_high"):
            _need_dict(pp.get(k), f"posterior_predictive_mgal.{k}", src)
    for key in (
        "range_margin_gal",
        "instability_percent",
        "diagnostics",
        "metadata",
        "angle_sensor",
    ):
        if result.get(key) is not None:
            _need_dict(result[key], key, src)


# ----------------------------------------------------------------------------- the decision rule

#: A criterion's or a result's conformity (ILAC-G8:09/2019, 4.2.3: a non-binary statement
#: with guard band w = U) and the two outcomes where no conformity is stated: ``undecided``
#: (the diagnostics raise a problem; nothing is beyond the tolerance) and ``no_statement``
#: (the method evaluates no measurement uncertainty; nothing is beyond the tolerance).
Outcome = Literal[
    "pass", "conditional_pass", "conditional_fail", "fail", "undecided", "no_statement"
]
_RANK = ("pass", "conditional_pass", "conditional_fail", "fail")


def guarded_outcome(value: float, big_u: float, tolerance: float) -> Outcome:
    """|value| against ``tolerance`` with guard band w = U (ILAC-G8:09/2019, 4.2.3): pass
    when |value| + U ≤ T, conditional pass when |value| ≤ T < |value| + U, conditional fail
    when |value| − U ≤ T < |value|, fail when |value| − U > T."""
    v = abs(value)
    if v - big_u > tolerance:
        return "fail"
    if v > tolerance:
        return "conditional_fail"
    if v + big_u > tolerance:
        return "conditional_pass"
    return "pass"


@dataclass(frozen=True)
class Criterion:
    """One criterion of the verdict: ``key`` ("reduced_error", "instability_b1", …), its
    measured value (%), its expanded uncertainty U (%, None where none is evaluated: judged
    by simple acceptance, ILAC-G8:09/2019 4.2.1), the tolerance and the outcome."""

    key: str
    value_percent: float
    u_percent: float | None
    k: float | None
    tolerance_percent: float
    outcome: Outcome


@dataclass(frozen=True)
class Conformity:
    """The verdict of a result: ``outcome`` (None: nothing to judge, the result has no
    reduced error), its criteria, the problems that bar a pass (the diagnostics' problems,
    a fit that did not converge, unsettled hold means of the classical method) and whether
    the method states an expanded uncertainty at all (the classical method does not)."""

    outcome: Outcome | None
    criteria: tuple[Criterion, ...]
    problems: tuple[str, ...]
    has_uncertainty: bool
    tolerance_percent: float

    @property
    def passed(self) -> bool | None:
        """True for a pass, None where no conformity is stated (nothing to judge, or the
        classical method within the tolerance), False otherwise (not passed, conditional,
        undecided)."""
        if self.outcome in (None, "no_statement"):
            return None
        return self.outcome == "pass"


def states_expanded_uncertainty(result: Mapping[str, Any]) -> bool:
    """Whether the result's uncertainties are expanded uncertainties: the joint model's
    (map, bayes: a budget of b). The classical method's 2s is Calibr.exe's repeatability of
    the least-squares fit only (no angle error, lag, drift or hold offsets), which covers
    the true b far less often than 95 % (README, «Validation»)."""
    return result.get("method") != "classical"


def verdict_problems(result: Mapping[str, Any]) -> tuple[str, ...]:
    """Every problem that bars a pass: the diagnostics' problems, a fit that did not
    converge, the classical method's unsettled hold means (its precondition)."""
    diag = result.get("diagnostics") or {}
    out = [str(p) for p in diag.get("problems") or []]
    if diag.get("converged") is False:
        out.append("not converged")
    if isinstance(result.get("unsettled_hold_means"), Mapping) and not any(
        "transient" in p for p in out
    ):
        out.append("unsettled hold means")
    return tuple(out)


def _instability_u_percent(result: Mapping[str, Any], name: str) -> tuple[float | None, float]:
    """U (%) of the instability of ``name`` against its prior, and k (U None without one)."""
    u, k = expanded_of(result, name)
    prior = (result.get("b_prior") or {}).get(name)
    if u is None or not is_num(prior) or not prior:
        return None, k
    return 100.0 * u / abs(float(prior)), k


def conformity(result: Mapping[str, Any], tolerance_percent: float = 0.05) -> Conformity:
    """The verdict of ``result`` against ``tolerance_percent`` by the certificate's decision
    rule (ILAC-G8:09/2019; ISO/IEC 17025 7.8.6):

    * a criterion with a stated expanded uncertainty U (the joint model's instability of b₁,
      b₂) is judged with guard band w = U (:func:`guarded_outcome`, 4.2.3); one without (the
      reduced error, whose uncertainty is not evaluated) on its measured value (simple
      acceptance, 4.2.1);
    * the result's outcome is its worst criterion's; a fit that did not converge is ``fail``;
      another problem of the diagnostics (unsettled hold means among them) bars every pass:
      ``undecided`` unless a criterion is beyond the tolerance;
    * the classical method states no expanded uncertainty: a criterion beyond the tolerance
      is ``fail`` (on the measured value), otherwise ``no_statement``.
    """
    tol = float(tolerance_percent)
    has_u = states_expanded_uncertainty(result)
    problems = verdict_problems(result)
    rerr = result.get("reduced_error_percent")
    if not is_num(rerr):
        return Conformity(None, (), problems, has_u, tol)
    crits = [
        Criterion("reduced_error", float(rerr), None, None, tol, "pass" if rerr <= tol else "fail")
    ]
    inst = result.get("instability_percent") or {}
    for name in ("b1", "b2"):
        v = inst.get(name)
        if not is_num(v):
            continue
        big_u, k = _instability_u_percent(result, name) if has_u else (None, None)
        if big_u is None:
            outcome: Outcome = "pass" if abs(v) <= tol else "fail"
        else:
            outcome = guarded_outcome(float(v), big_u, tol)
        crits.append(Criterion(f"instability_{name}", float(v), big_u, k, tol, outcome))
    worst = max((c.outcome for c in crits), key=_RANK.index)
    if "not converged" in problems:  # no estimate: what the criteria say is not shown
        worst = "fail"
    if not has_u:
        overall: Outcome = "fail" if worst == "fail" else "no_statement"
    elif problems and worst in ("pass", "conditional_pass"):
        overall = "undecided"
    else:
        overall = worst
    return Conformity(overall, tuple(crits), problems, has_u, tol)


# ----------------------------------------------------------------------------- traceability


@dataclass(frozen=True)
class Traceability:
    """Whether the results are metrologically traceable to the SI (ISO/IEC 17025 6.5,
    7.8.4.1) as the result says, and why: ``angle`` is "calibration" (every angle sensor
    corrected by the platform's angle calibration ``calibration``), "specification" (the
    sensors ``uncalibrated`` rest on a specification bound) or "unstated" (no angle model:
    a classical result); ``g_source`` names the site gravity's source (None: not stated)."""

    angle: Literal["calibration", "specification", "unstated"]
    calibration: Mapping[str, Any] | None
    uncalibrated: tuple[str, ...]
    g_source: str | None

    @property
    def traceable(self) -> bool:
        """Both inputs of the scale factors, the tilt angle and the site gravity, traced."""
        return self.angle == "calibration" and self.g_source is not None

    def missing(self, lang: str = "en") -> list[str]:
        """What breaks the chain, in words (empty when :attr:`traceable`)."""
        from chekan.report.i18n import tr

        t = tr(lang)
        out = []
        if self.angle == "specification":
            out.append(t("trace_miss_angle_axes", axes=", ".join(self.uncalibrated)))
        elif self.angle == "unstated":
            out.append(t("trace_miss_angle"))
        if self.g_source is None:
            out.append(t("trace_miss_g"))
        return out

    def statement(self, lang: str = "en") -> str:
        """One sentence for a certificate: traceable through what, or what is missing."""
        from chekan.report.i18n import tr

        t = tr(lang)
        if self.angle == "calibration":
            cal = self.calibration or {}
            lab = f" ({cal['laboratory']})" if cal.get("laboratory") else ""
            angle = t("trace_angle_cal", id=cal.get("id", "?"), date=cal.get("date", "?"), lab=lab)
        elif self.angle == "specification":
            angle = t("trace_angle_spec")
        else:
            angle = t("trace_angle_unstated")
        gravity = t("trace_g", src=self.g_source) if self.g_source else t("trace_g_unstated")
        head = t("trace_yes" if self.traceable else "trace_no")
        return f"{head}: {angle}; {gravity}."


def _sensors(result: Mapping[str, Any]) -> dict[str, Mapping[str, Any]]:
    """The platform angle sensors the result's model used, by axis."""
    both = result.get("angle_sensors")
    if isinstance(both, Mapping) and both:
        return {str(a): s for a, s in both.items() if isinstance(s, Mapping)}
    one = result.get("angle_sensor")
    if isinstance(one, Mapping) and one.get("model") != "independent":
        return {str(one.get("axis", "y")): one}
    return {}


def g_source_of(result: Mapping[str, Any], lab: Mapping[str, Any] | None = None) -> str | None:
    """The named source of the site gravity: the lab file's ``[site] gravity_survey``, else
    the result's ``metadata.g_source``; None when neither names one."""
    site = (lab or {}).get("site")
    for v in (
        site.get("gravity_survey") if isinstance(site, Mapping) else None,
        (result.get("metadata") or {}).get("g_source"),
    ):
        if isinstance(v, str) and v.strip():
            return v.strip()
    return None


def traceability(result: Mapping[str, Any], lab: Mapping[str, Any] | None = None) -> Traceability:
    """Whether the tilt angles and the site gravity, the inputs the scale factors are
    realised from, are traceable as the result says: every angle sensor of the model
    corrected by the platform's angle calibration (``angle_calibration``), and the source of
    ``g_local`` named (:func:`g_source_of`: the lab file's survey or ``metadata.g_source``).
    A specification bound, a result that states nothing of its angles (classical; angle
    errors modelled as independent) or an unnamed gravity break the chain."""
    cal = result.get("angle_calibration")
    sensors = _sensors(result)
    uncal = tuple(
        sorted(
            a.upper() for a, s in sensors.items() if not isinstance(s.get("calibration"), Mapping)
        )
    )
    if not sensors:
        angle: Literal["calibration", "specification", "unstated"] = "unstated"
    elif uncal or not (isinstance(cal, Mapping) and cal.get("id")):
        angle = "specification"
        uncal = uncal or tuple(sorted(a.upper() for a in sensors))
    else:
        angle = "calibration"
    calib = cal if angle == "calibration" and isinstance(cal, Mapping) else None
    return Traceability(angle, calib, uncal, g_source_of(result, lab))
