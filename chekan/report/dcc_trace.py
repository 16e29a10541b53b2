"""What the DCC states of traceability and conformity, decided from the result.

Traceable only when every input of the scale factors is: each angle sensor of the model
corrected by the platform's angle calibration, and the site gravity's survey named (the
lab file's ``[site] gravity_survey`` or the result's ``metadata.g_source``). Conformity
by ILAC-G8:09/2019: a criterion with an expanded uncertainty U is judged with guard band
w = U (4.2.3), one without on its measured value (4.2.1); a problem of the diagnostics
bars a pass.

A stand-in for the certificate's own decision (``chekan.report.checks``), to be joined
with it: same rules, DCC words.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from chekan.report.dcc_words import words
from chekan.report.expanded import expanded_of
from chekan.report.numbers import is_num

#: the DCC's conformity values (dcc:stringConformityStatementStatusType), worst last
RANK = ("pass", "conditionalPass", "conditionalFail", "fail")


@dataclass(frozen=True)
class Trace:
    """``angle``: "calibration", "specification" (``uncalibrated`` axes) or "unstated";
    ``g_source``: the site gravity's survey (None: not named)."""

    angle: str
    calibration: Mapping[str, Any] | None
    uncalibrated: tuple[str, ...]
    g_source: str | None

    @property
    def traceable(self) -> bool:
        return self.angle == "calibration" and self.g_source is not None

    def statement(self) -> dict[str, str]:
        """The sentence, per language: traceable or not, and through what / why not."""
        if self.angle == "calibration":
            cal = self.calibration or {}
            lab = f" ({cal['laboratory']})" if cal.get("laboratory") else ""
            angle = words(
                "trace_angle_cal", id=cal.get("id", "?"), date=cal.get("date", "?"), lab=lab
            )
        elif self.angle == "specification":
            angle = {
                "en": words("trace_angle_spec", axes=" and ".join(self.uncalibrated))["en"],
                "ru": words("trace_angle_spec", axes=" и ".join(self.uncalibrated))["ru"],
            }
        else:
            angle = words("trace_angle_unstated")
        g = words("trace_g", src=self.g_source) if self.g_source else words("trace_g_unnamed")
        head = words("trace_yes" if self.traceable else "trace_no")
        return {k: f"{head[k]}: {angle[k]}; {g[k]}." for k in head}


def _sensors(result: Mapping[str, Any]) -> dict[str, Mapping[str, Any]]:
    """The platform angle sensors of the result's model, by axis."""
    both = result.get("angle_sensors")
    if isinstance(both, Mapping) and both:
        return {str(a): v for a, v in both.items() if isinstance(v, Mapping)}
    one = result.get("angle_sensor")
    if isinstance(one, Mapping) and one.get("model") != "independent":
        return {str(one.get("axis", "y")): one}
    return {}


def g_source_of(result: Mapping[str, Any], lab: Mapping[str, Any] | None) -> str | None:
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


def trace(result: Mapping[str, Any], lab: Mapping[str, Any] | None = None) -> Trace:
    """The traceability of ``result`` (issued with ``lab``)."""
    cal = result.get("angle_calibration")
    sensors = _sensors(result)
    uncal = tuple(
        sorted(
            a.upper() for a, v in sensors.items() if not isinstance(v.get("calibration"), Mapping)
        )
    )
    if not sensors:
        angle = "unstated"
    elif uncal or not (isinstance(cal, Mapping) and cal.get("id")):
        angle = "specification"
        uncal = uncal or tuple(sorted(a.upper() for a in sensors))
    else:
        angle = "calibration"
    calib = cal if angle == "calibration" and isinstance(cal, Mapping) else None
    return Trace(angle, calib, uncal, g_source_of(result, lab))


# ----------------------------------------------------------------------------- conformity


@dataclass(frozen=True)
class Criterion:
    key: str  # "reduced_error", "instability_b1", "instability_b2"
    value_percent: float
    u_percent: float | None
    outcome: str  # one of RANK


@dataclass(frozen=True)
class Decision:
    """``outcome``: one of :data:`RANK`, or None with ``why`` (no statement)."""

    outcome: str | None
    criteria: tuple[Criterion, ...]
    why: dict[str, str] | None


def guarded(value: float, big_u: float, tol: float) -> str:
    """|value| against ``tol`` with guard band w = U (ILAC-G8:09/2019, 4.2.3)."""
    v = abs(value)
    if v - big_u > tol:
        return "fail"
    if v > tol:
        return "conditionalFail"
    if v + big_u > tol:
        return "conditionalPass"
    return "pass"


def decide(result: Mapping[str, Any], tolerance_percent: float) -> Decision:
    """The conformity of ``result`` with the tolerance, by the rule above."""
    tol = float(tolerance_percent)
    rerr = result.get("reduced_error_percent")
    if not is_num(rerr):
        return Decision(None, (), words("why_nothing"))
    has_u = result.get("method") != "classical"
    crits = [Criterion("reduced_error", float(rerr), None, "pass" if rerr <= tol else "fail")]
    inst = result.get("instability_percent") or {}
    for name in ("b1", "b2"):
        v = inst.get(name)
        if not is_num(v):
            continue
        big_u = None
        prior = (result.get("b_prior") or {}).get(name)
        u, _k = expanded_of(result, name)
        if has_u and u is not None and is_num(prior) and prior:
            big_u = 100.0 * float(u) / abs(float(prior))
        out = (
            guarded(float(v), big_u, tol)
            if big_u is not None
            else ("pass" if abs(v) <= tol else "fail")
        )
        crits.append(Criterion(f"instability_{name}", float(v), big_u, out))
    worst = max((c.outcome for c in crits), key=RANK.index)
    diag = result.get("diagnostics") or {}
    problems = [str(p) for p in diag.get("problems") or []]
    if diag.get("converged") is False:
        problems.append("not converged")
    if worst == "fail":
        return Decision("fail", tuple(crits), None)
    if not has_u:
        return Decision(None, tuple(crits), words("why_no_u"))
    if problems and worst in ("pass", "conditionalPass"):
        from chekan.report.i18n import with_param_names

        why = {
            lang: text.format(p="; ".join(with_param_names(x, lang) for x in problems))
            for lang, text in words("why_problems", p="{p}").items()
        }
        return Decision(None, tuple(crits), why)
    return Decision(worst, tuple(crits), None)


def criteria_text(decision: Decision) -> dict[str, str]:
    """Each criterion with its value, U and outcome, per language."""
    out: dict[str, list[str]] = {"en": [], "ru": []}
    for c in decision.criteria:
        name, verdict = words(f"crit_{c.key}"), words(c.outcome)
        for lang in out:
            u = f" (U = {c.u_percent:.3g} %)" if c.u_percent is not None else ""
            v = f"{c.value_percent:.3g}"
            if lang == "ru":
                v, u = v.replace(".", ","), u.replace(".", ",")
            out[lang].append(f"{name[lang]} {v} %{u}: {verdict[lang]}")
    return {k: "; ".join(v) for k, v in out.items()}
