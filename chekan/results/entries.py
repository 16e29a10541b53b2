"""The entries and the words of a joint result that its fits' values imply: the budget's
entries (each group scaled to the reported sd, ν_eff, k and U), the angle sensor's entry,
the prior-dominated parameters, and the problems that the hyperparameters' EM leaves
(a hyperparameter at its clip bound, a misfit, an implausible angle error, a pass at its
cap), and which sampler drew the posterior. Nothing here estimates;
:mod:`chekan.results.joint` writes them into the result."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from chekan.fit.budget import PRIOR_SD
from chekan.joint.angles import DEFAULT_BOUND_ARCSEC, AngleSensorSpec
from chekan.joint.em import (
    AT_BOUND_LOG,
    HYPER_MAX_UPDATES,
    NOISE_LOWER,
    NOISE_UPPER,
    SIGMA_HOLD_BOUNDS_PIX,
    SIGMA_THETA_BOUNDS_ARCSEC,
)
from chekan.joint.problem import Hyper
from inference.dof import coverage_factor

if TYPE_CHECKING:
    from inference.sampling import SamplingResult


def hyper_at_bounds(h: Hyper) -> list[str]:
    """The hyperparameters that the EM left at one of its clip bounds, in words: there the
    data did not determine them, and the uncertainty that rests on them may be wrong."""
    s = np.asarray(h["noise_scale"], dtype=float).reshape(-1)
    values = [
        ("noise scale s₁", float(s[0]), np.exp(NOISE_LOWER[0]), np.exp(NOISE_UPPER[0]), ""),
        ("noise scale s₂", float(s[1]), np.exp(NOISE_LOWER[1]), np.exp(NOISE_UPPER[1]), ""),
        (
            "slew error κ",
            float(h["slew_error"]),
            np.exp(NOISE_LOWER[2]),
            np.exp(NOISE_UPPER[2]),
            "",
        ),
        ("σ_θ", float(h["sigma_theta_arcsec"]), *SIGMA_THETA_BOUNDS_ARCSEC, "″"),
        ("σ_o", float(h["sigma_hold_pix"]), *SIGMA_HOLD_BOUNDS_PIX, " pix"),
    ]
    out = []
    for name, v, low, high, unit in values:
        for edge, which in ((low, "lower"), (high, "upper")):
            if abs(np.log(v) - np.log(edge)) < AT_BOUND_LOG:
                out.append(f"hyperparameter {name} = {v:.4g}{unit} ended at its {which} bound")
    return out


MISFIT_SCALE = 2.0  # residuals this many times the samples' own scatter: a misfit
# a random angle error of the holds this many times the platform's specified accuracy
# (its bound, 3″ unless the user states a larger one): no platform within its specification
IMPLAUSIBLE_ANGLE_FACTOR = 2.0


def residual_misfit(h: Hyper) -> list[str]:
    """The systems whose residuals the model does not describe, in words: the bin means
    scatter about the fit sⱼ times more than the record's own sample-to-sample noise says
    (sⱼ > ``MISFIT_SCALE``): an effect the model leaves out (a jump, a drift the polynomial
    cannot follow), and the sd that rests on the fit may be too small."""
    s = np.asarray(h["noise_scale"], dtype=float).reshape(-1)
    return [
        f"residuals of system {j + 1} are {v:.3g}× the scatter of its own samples: the model "
        "does not describe this record (an unmodelled effect); its uncertainty may be too small"
        for j, v in enumerate(s[:2])
        if v > MISFIT_SCALE
    ]


def implausible_angle_error(h: Hyper, bound_arcsec: float) -> list[str]:
    """The holds' random angle error, in words, where the EM put it beyond what a platform
    within its specification can have (σ_θ > ``IMPLAUSIBLE_ANGLE_FACTOR`` × the bound):
    there the fit explains a misfit of the slews by the holds' angles, which frees b to
    follow the transients (σ_θ 15–30″ came with b off by up to 9 sd on simulated records
    whose slew paths the model misreads: README, "Angles up to a second late")."""
    v = float(h["sigma_theta_arcsec"])
    if v <= IMPLAUSIBLE_ANGLE_FACTOR * bound_arcsec:
        return []
    return [
        f"the holds' random angle error σ_θ = {v:.3g}″ is {v / bound_arcsec:.2g}× the "
        f"platform's {bound_arcsec:g}″ specification: the model does not describe this "
        "record's slews (the recorded angles may lag the readings); b may be biased and its "
        "uncertainty too small"
    ]


def capped_problem(passes: list[int]) -> list[str]:
    """The problem of EM passes that stopped at ``HYPER_MAX_UPDATES`` still moving: the
    hyperparameters (and so the weights of the MAP after them) are not at their fixed point."""
    if not passes:
        return []
    return [
        f"the EM of the hyperparameters stopped at its cap of {HYPER_MAX_UPDATES} updates without"
        f" converging (after MAP pass {', '.join(map(str, passes))}): the noise and angle-error"
        " variances, and so b's weights and uncertainty, are not at their estimate"
    ]


def angle_sensor_entry(spec: AngleSensorSpec | None) -> dict:
    """The result's ``angle_sensor``: how the platform's angle errors were modelled."""
    if spec is None:
        return {"model": "independent"}
    out = {
        "model": "systematic",
        "axis": spec.axis,
        "reading": spec.reading,
        "source": spec.source,
        "u_per_angle_arcsec": math.sqrt(spec.per_angle_var),
        "u_scale_arcsec": math.sqrt(spec.scale_var),
    }
    if spec.table is None:
        out.update(bound_arcsec=spec.bound_arcsec, distribution=spec.distribution)
    else:
        out.update(distribution="normal", calibration=spec.calibration.entry())
    return out


def budget_entries(
    budget_raw: Mapping[str, Mapping[str, float]],
    params: Mapping[str, Mapping[str, Any]],
    nu_eff: Mapping[str, float] | None = None,
) -> dict:
    """The result's ``uncertainty_budget``: each group scaled so that they add up (in
    quadrature) to the reported sd; the total u, the effective degrees of freedom
    ``nu_eff`` (None: not evaluated, k = 2), the coverage factor k = t₉₅.₄₅(ν_eff)
    (GUM G.6.4; :func:`inference.dof.coverage_factor`) and U = k·u (``expanded``).

    ``budget_raw`` may hold a line ``hyperparameters`` (uₕ, :mod:`chekan.fit.typea`), which
    is not in the linearised total (it is added to it here)."""
    out = {}
    for name in ("b1", "b2"):
        raw = dict(budget_raw[name])
        lin = raw.pop("total_linearised")
        if "hyperparameters" in raw:
            lin = float(np.hypot(lin, raw["hyperparameters"]))
        sd = params[name]["sd"]
        scale = sd / lin if lin > 0 and sd else 1.0
        e: dict[str, float | None] = {k: v * scale for k, v in raw.items()}
        e["total"] = sd
        nu = (nu_eff or {}).get(name)
        k = coverage_factor(nu) if nu is not None else 2.0
        e["nu_eff"] = float(nu) if nu is not None else None
        finite = bool(np.isfinite(k))  # ν_eff < 1: no finite k, no U (a flagged problem)
        e["coverage_factor"] = k if finite else None
        e["expanded"] = k * sd if sd is not None and finite else None
        out[name] = e
    return out


def flag_prior_dominated(params: dict, diag: dict) -> dict:
    """``diag`` with ``prior_dominated`` (and notes): a posterior sd above half the prior
    sd means this program cannot separate the parameter."""
    dominated = [
        n for n, psd in PRIOR_SD.items() if n in params and (params[n]["sd"] or 0) > 0.5 * psd
    ]
    notes = list(diag.get("notes", []))
    for n in dominated:
        notes.append(
            f"{n} is prior-dominated (sd {params[n]['sd']:.3g} vs prior sd {PRIOR_SD[n]:g}): "
            "this program cannot separate it"
        )
    out = {**diag, "prior_dominated": dominated}
    if notes:
        out["notes"] = notes
    return out


def to_zero_problem(names: list[str]) -> list[str]:
    """The problem of EM passes that stopped at their cap with the variances ``names``
    still falling towards zero: as at a clip bound (:func:`hyper_at_bounds`)."""
    if not names:
        return []
    return [
        f"the EM of the hyperparameters stopped at its cap with {', '.join(names)} still"
        " falling towards zero, its lower bound: the data did not determine it, and the"
        " uncertainty that rests on it may be wrong"
    ]


def specified_accuracy(spec_y: AngleSensorSpec | None, spec_x: AngleSensorSpec | None) -> float:
    """The platform's angle accuracy (arcsec) that its random error may not exceed by much:
    the specification's 3″, or a larger bound the user states for one of its sensors."""
    specs = (spec_y, spec_x)
    return max([DEFAULT_BOUND_ARCSEC, *(s.bound_arcsec for s in specs if s is not None)])


def sampler_entries(samp: SamplingResult) -> dict[str, Any]:
    """What the diagnostics say of the sampler that ran: emcee's ensembles (walkers, steps,
    burn-in, thinning, τ, acceptance), and the importance sampling wherever it was tried
    (``importance``: taken or not, Pareto k̂, the smallest ESS, the draws weighed and the
    verdict in words; where it was refused, emcee's figures follow)."""
    out: dict[str, Any] = {}
    if samp.method == "emcee":
        out.update(
            n_walkers=int(samp.n_walkers),
            n_steps=int(samp.n_steps),
            burn=int(samp.burn),
            thin=int(samp.thin),
            tau_max=float(np.max(samp.tau)),
            acceptance=[float(a) for a in samp.acceptance],
        )
    v = samp.importance
    if v is not None:
        out["importance"] = {
            "taken": bool(samp.method == "importance"),
            "pareto_k": float(v.khat),
            "ess_min": float(v.min_ess),
            "limited_by": v.limiting,
            "n_points": int(v.n_points),
            "proposal_refits": int(v.refits),
            "message": v.message,
        }
    return out
