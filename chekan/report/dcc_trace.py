"""What the DCC states of traceability and conformity, decided from the result.

Traceable only when every input of the scale factors is: each angle sensor of the model
corrected by the platform's angle calibration, and the site gravity's survey named (the
lab file's ``[site] gravity_survey`` or the result's ``metadata.g_source``). Conformity
by ILAC-G8:09/2019: a criterion with an expanded uncertainty U is judged with guard band
w = U (4.2.3), one without on its measured value (4.2.1); a problem of the diagnostics
bars a pass.

The decisions are the certificate's own (:mod:`chekan.report.checks`); this module gives
them in the DCC's values and words.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from chekan.report.checks import Traceability, conformity
from chekan.report.dcc_words import words


def statement(t: Traceability) -> dict[str, str]:
    """The DCC's sentence for ``t`` (:func:`chekan.report.checks.traceability`), per
    language: traceable or not, and through what / why not."""
    if t.angle == "calibration":
        cal = t.calibration or {}
        lab = f" ({cal['laboratory']})" if cal.get("laboratory") else ""
        angle = words("trace_angle_cal", id=cal.get("id", "?"), date=cal.get("date", "?"), lab=lab)
    elif t.angle == "specification":
        angle = {
            "en": words("trace_angle_spec", axes=" and ".join(t.uncalibrated))["en"],
            "ru": words("trace_angle_spec", axes=" и ".join(t.uncalibrated))["ru"],
        }
    else:
        angle = words("trace_angle_unstated")
    g = words("trace_g", src=t.g_source) if t.g_source else words("trace_g_unnamed")
    head = words("trace_yes" if t.traceable else "trace_no")
    return {k: f"{head[k]}: {angle[k]}; {g[k]}." for k in head}


# ----------------------------------------------------------------------------- conformity


@dataclass(frozen=True)
class Criterion:
    key: str  # "reduced_error", "instability_b1", "instability_b2"
    value_percent: float
    u_percent: float | None
    outcome: str  # a DCC conformity value (_DCC_OUTCOME's)


@dataclass(frozen=True)
class Decision:
    """``outcome``: a DCC conformity value (``dcc:stringConformityStatementStatusType``), or
    None with ``why`` (no statement)."""

    outcome: str | None
    criteria: tuple[Criterion, ...]
    why: dict[str, str] | None


#: the certificate's outcomes (:class:`chekan.report.checks.Conformity`) in the DCC's values
#: (``dcc:stringConformityStatementStatusType``)
_DCC_OUTCOME = {
    "pass": "pass",
    "conditional_pass": "conditionalPass",
    "conditional_fail": "conditionalFail",
    "fail": "fail",
}


def decide(result: Mapping[str, Any], tolerance_percent: float) -> Decision:
    """The conformity of ``result`` with the tolerance: the certificate's own decision
    (:func:`chekan.report.checks.conformity`, the rule above), in the DCC's values; no
    statement, with why, where the certificate makes none."""
    conf = conformity(result, float(tolerance_percent))
    crits = tuple(
        Criterion(c.key, c.value_percent, c.u_percent, _DCC_OUTCOME[c.outcome])
        for c in conf.criteria
    )
    if conf.outcome in _DCC_OUTCOME:
        return Decision(_DCC_OUTCOME[conf.outcome], crits, None)
    if conf.outcome is None:
        return Decision(None, crits, words("why_nothing"))
    if conf.outcome == "no_statement":
        return Decision(None, crits, words("why_no_u"))
    from chekan.report.i18n import with_param_names

    why = {
        lang: text.format(p="; ".join(with_param_names(x, lang) for x in conf.problems))
        for lang, text in words("why_problems", p="{p}").items()
    }
    return Decision(None, crits, why)


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
