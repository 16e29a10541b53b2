"""The certificate's verdict in words: the outcome of :func:`chekan.report.checks.conformity`
(ILAC-G8:09/2019, guard band w = U where U is stated), each criterion with its value, U and
outcome, the problems that bar a pass, and the decision rule (ISO/IEC 17025 7.8.6)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from chekan.report.checks import Conformity, Criterion, conformity
from chekan.report.document import Para
from chekan.report.i18n import Translator, param_name, tr
from chekan.report.numbers import DASH, fixed, is_num, plain, unc

_KIND = {
    "pass": "pass",
    "conditional_pass": "warn",
    "conditional_fail": "fail",
    "fail": "fail",
    "undecided": "warn",
    "no_statement": "warn",
}


def _criterion_text(c: Criterion, t: Translator) -> str:
    """One criterion: its value against the tolerance, with U and outcome where U is stated."""
    tol = plain(c.tolerance_percent)
    v = abs(c.value_percent)
    op = "≤" if v <= c.tolerance_percent else ">"
    if c.key == "reduced_error":
        return t("crit_reduced", v=fixed(v, 3), op=op, tol=tol)
    name = param_name(c.key.removeprefix("instability_"), "en")
    if c.u_percent is None:
        return t("crit_instab", name=name, v=fixed(v, 3), op=op, tol=tol)
    return t(
        "crit_instab_u",
        name=name,
        v=fixed(v, 3),
        op=op,
        tol=tol,
        u=unc(c.u_percent),
        outcome=t(f"out_{c.outcome}"),
    )


def _problem_texts(result: Mapping[str, Any], conf: Conformity, t: Translator) -> list[str]:
    """The problems that bar a pass, in words: unsettled hold means (the classical method's
    precondition) in full, the diagnostics' problems by their number, no convergence."""
    out: list[str] = []
    un = result.get("unsettled_hold_means")
    rest = list(conf.problems)
    if isinstance(un, Mapping):
        shift = un.get("shift_percent") or []
        b1 = fixed(shift[0], 3, sign=True) + " %" if shift and is_num(shift[0]) else DASH
        out.append(t("crit_unsettled", pix=fixed(un.get("max_pix"), 2), b1=b1))
        rest = [p for p in rest if "transient" not in p and p != "unsettled hold means"]
    if "not converged" in rest:
        rest.remove("not converged")
        out.append(t("crit_noconv" if result.get("method") == "bayes" else "crit_noconv_fit"))
    if rest:
        bayes = result["method"] == "bayes" or "r_hat_max" in (result.get("diagnostics") or {})
        sec = t("sec_diag" if bayes else "sec_diag_classical")
        out.append(t("crit_problems", n=len(rest), sec=sec))
    return out


def verdict_paras(
    result: Mapping[str, Any], t: Translator, tol: float
) -> tuple[Conformity, list[Para]]:
    """The conformity of ``result`` and its paragraphs: the verdict line, the criteria, the
    decision rule (and a note where the instability was not assessed)."""
    conf = conformity(result, tol)
    if conf.outcome is None:
        return conf, [Para(t("verdict_none"), "warn")]
    crit = [_criterion_text(c, t) for c in conf.criteria]
    problems = _problem_texts(result, conf, t)
    is_bayes = result["method"] == "bayes"
    if is_bayes and (result.get("diagnostics") or {}).get("converged") is True:
        crit.append(t("crit_conv"))
    tol_s = plain(tol)
    if conf.outcome == "undecided":
        line = t("verdict_undecided", tol=tol_s, crit="; ".join(problems + crit))
    elif conf.outcome == "no_statement":
        line = t("verdict_no_statement", tol=tol_s, crit="; ".join(crit + problems))
    elif conf.outcome == "fail" and not conf.has_uncertainty:
        line = t("verdict_fail_classical", tol=tol_s, crit="; ".join(crit + problems))
    else:
        line = t(f"verdict_{conf.outcome}", tol=tol_s, crit="; ".join(crit + problems))
    paras = [Para(line, _KIND[conf.outcome])]  # type: ignore[arg-type]
    paras.append(
        Para(t("verdict_criteria", conv=t("verdict_conv_clause") if is_bayes else ""), "note")
    )
    paras.append(Para(t("decision_rule"), "note"))
    if len(conf.criteria) == 1:
        paras.append(Para(t("verdict_no_instab"), "note"))
    return conf, paras


def verdict_of(
    result: Mapping[str, Any], tolerance_percent: float = 0.05, lang: str = "en"
) -> tuple[bool | None, str]:
    """``(passed, verdict line)``: ``passed`` True for a pass, False where the line states
    anything else (not passed, conditional, no decision), None where no conformity is
    stated (nothing to judge; the classical method within the tolerance)."""
    conf, paras = verdict_paras(result, tr(lang), tolerance_percent)
    return conf.passed, paras[0].text
