"""The expanded uncertainty U = k·u that a certificate states for each result value.

A ``map`` result carries each value's effective degrees of freedom ν_eff (GUM G.4; the
hyperparameters are estimated from the record: :mod:`chekan.fit.typea`), and its budget
of b the coverage factor k = t₉₅.₄₅(ν_eff) and U (``coverage_factor``, ``expanded``).
Results without them (``bayes``, classical, results written before 0.3.9 with the budget's
``expanded_k2``) state k = 2.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from chekan.report.numbers import is_num

K_NORMAL = 2.0


def b_uncertainty(result: Mapping[str, Any], name: str) -> tuple[float | None, bool]:
    """Standard uncertainty of b1/b2: the budget's total when present (True), else the sd."""
    bud = (result.get("uncertainty_budget") or {}).get(name) or {}
    if is_num(bud.get("total")):
        return float(bud["total"]), True
    sd = result["parameters"].get(name, {}).get("sd")
    return (float(sd), False) if is_num(sd) else (None, False)


def expanded_of(result: Mapping[str, Any], name: str) -> tuple[float | None, float]:
    """``(U, k)`` of result value ``name``: b1/b2 from their budget when it has one (its U and
    k, or ``expanded_k2`` with k = 2), otherwise k·sd with k from the value's ``nu_eff``
    (:func:`inference.dof.coverage_factor`) or 2. U is None without an uncertainty, and
    where ν_eff < 1 leaves no finite k (k is then ``inf``)."""
    if name in ("b1", "b2"):
        u, from_budget = b_uncertainty(result, name)
        bud = (result.get("uncertainty_budget") or {}).get(name) or {}
        if from_budget and is_num(bud.get("expanded")) and is_num(bud.get("coverage_factor")):
            return float(bud["expanded"]), float(bud["coverage_factor"])
        if from_budget and is_num(bud.get("expanded_k2")):
            return float(bud["expanded_k2"]), K_NORMAL
    else:
        e = result["parameters"].get(name) or {}
        u = float(e["sd"]) if is_num(e.get("sd")) else None
    k = coverage_factor_of(result, name)
    return (k * u if u is not None and math.isfinite(k) else None), k


def coverage_factor_of(result: Mapping[str, Any], name: str) -> float:
    """k of result value ``name`` from its ``nu_eff`` (2 without one)."""
    nu = (result["parameters"].get(name) or {}).get("nu_eff")
    if not is_num(nu):
        return K_NORMAL
    from inference.dof import coverage_factor

    return coverage_factor(float(nu))
