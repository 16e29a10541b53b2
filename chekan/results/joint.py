"""The ``map`` and ``bayes`` ``chekan-result/1`` dicts, written from the typed fits of
:mod:`chekan.fit.fitted` and the classical result they start from (its header and
classical items, :func:`chekan.results.document.classical_result`), with their messages
(``diagnostics.problems``, notes, the warning of a posterior not converged).

Nothing here estimates: :func:`joint_result` only formats. The classical result handed in
is not changed.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from chekan.fit.fitted import MapEstimate, PosteriorEstimate
from chekan.fit.map import MapFit
from chekan.fit.protocol import ProtocolEstimate
from chekan.joint.xresponse import horizontal_prior
from chekan.options import CalibrationOptions
from chekan.physics.parameters import PARAMETER_UNITS, unit_of
from chekan.results.document import param_entry, posterior_entry, with_settled
from chekan.results.entries import (
    angle_sensor_entry,
    budget_entries,
    capped_problem,
    flag_prior_dominated,
    hyper_at_bounds,
    implausible_angle_error,
    residual_misfit,
    sampler_entries,
    specified_accuracy,
    to_zero_problem,
)


def joint_result(
    base: Mapping[str, Any],
    fitted: MapEstimate | PosteriorEstimate | ProtocolEstimate,
    options: CalibrationOptions,
) -> dict:
    """The result of a joint fit: the classical result ``base`` (not changed) with the fit's
    parameters, budget and diagnostics, and (a record's) the settled classical items."""
    if isinstance(fitted, ProtocolEstimate):
        return protocol_result(base, fitted, options)
    if isinstance(fitted, MapEstimate):
        out = map_result(base, fitted, options)
    else:
        out = posterior_result(base, fitted, options)
    return with_settled(out, fitted.settling)


def _common(fit: MapFit, base: Mapping[str, Any], options: CalibrationOptions):
    """The result's header and the MAP's diagnostics, shared by map and bayes."""
    res = fit.result
    out = dict(base)
    out["method"] = options.method
    model = fit.model
    out["angle_sensor"] = angle_sensor_entry(model.angle_spec or model.angle_spec_x)
    if model.angle_spec is not None and model.angle_spec_x is not None:
        out["angle_sensors"] = {
            "y": angle_sensor_entry(model.angle_spec),
            "x": angle_sensor_entry(model.angle_spec_x),
        }
    if model.structure.n_x_response:  # what the pendulums' horizontal was taken to be
        out["pendulum_horizontal"] = {
            "about": "ccd_center_pix",
            "u_pix": float(model.horizontal_u_pix),
            "source": horizontal_prior(options.horizontal_u_pix)[1],
        }
    out["classical"] = {k: base["parameters"][k] for k in ("b1", "b2") if k in base["parameters"]}
    to_zero = sorted({n for p in fit.history for n in p.get("hyper_to_zero", [])})
    bound = specified_accuracy(model.angle_spec, model.angle_spec_x)
    diag = {
        "converged": fit.converged,
        "map_steps": int(res.num_steps),
        "map_passes": list(fit.history),
        "jacobian_cond": float(res.jacobian_cond),
        "not_identified": list(res.degenerate),
        "data": "bin means inside holds (lag modelled), β marginalised",
        "problems": ([] if res.converged else [f"MAP did not converge: {res.message}"])
        + capped_problem(fit.capped_passes)
        + list(base.get("program_coverage", {}).get("problems", []))
        + hyper_at_bounds(fit.hyper)
        + residual_misfit(fit.hyper)
        + implausible_angle_error(fit.hyper, bound)
        + to_zero_problem(to_zero),
    }
    return out, diag


def map_result(base: Mapping[str, Any], est: MapEstimate, options: CalibrationOptions) -> dict:
    """The ``map`` result: MAP values, delta-method sds (with the hyperparameters'
    estimation), the budget, ν_eff and U = k·u (:mod:`chekan.fit.typea`); the classical
    items as Calibr.exe's (:func:`joint_result` settles them)."""
    out, diag = _common(est.fit, base, options)
    md = est.derived
    nu = md.nu_eff
    hp = options.hdi_prob
    params = {
        name: param_entry(value, sd, hp, PARAMETER_UNITS.get(name, ""), nu_eff=nu.get(name))
        for name, (value, sd) in md.values.items()
    }
    for name, value in md.hyper.items():  # at their EM values: no sd
        params[name] = param_entry(value, None, hp, PARAMETER_UNITS.get(name, ""))
    out["parameters"] = params
    out["level_reading_pix"] = {"m1": float(md.m_level_pix[0]), "m2": float(md.m_level_pix[1])}
    budget_raw = {  # the estimate's move with the estimated hyperparameters
        name: {**lines, "hyperparameters": md.u_hyper[name]} if name in ("b1", "b2") else lines
        for name, lines in est.budget.items()
    }
    out["uncertainty_budget"] = budget_entries(budget_raw, params, nu)
    diag = flag_prior_dominated(params, diag)
    if md.type_a_clipped:  # inference.dof.log_var_cov took the positive part
        diag["problems"] = [
            *diag["problems"],
            "the information on the noise variances is not positive definite on this record "
            "(it barely determines its parameters): the Type A part of u and ν_eff rest on "
            "an approximation that failed and may be understated; calibrate a program with "
            "more holds",
        ]
    few = [n for n in params if nu.get(n) is not None and nu[n] < 1.0]
    if few:  # GUM G.4.1 truncates ν_eff < 1 to no degree of freedom: no finite k
        diag["problems"] = [
            *diag["problems"],
            f"effective degrees of freedom below 1 for {', '.join(few)} (down to "
            f"{min(nu[n] for n in few):.2g}): the record is too short to estimate the Type A "
            "part of their uncertainty, so no interval or expanded uncertainty is stated for "
            "them; calibrate a program with more holds",
        ]
    diag["seconds"] = est.seconds
    out["diagnostics"] = diag
    return out


def posterior_result(
    base: Mapping[str, Any], est: PosteriorEstimate, options: CalibrationOptions
) -> dict:
    """The ``bayes`` result: posterior summaries, diagnostics, predictive, drift, NetCDF;
    the classical items as Calibr.exe's (:func:`joint_result` settles them)."""
    out, diag = _common(est.fit, base, options)
    model = est.fit.model
    samp = est.sampling
    draws = samp.derived or {}
    C, Dn = samp.draws.shape[:2]
    summ = est.summary
    params = {name: posterior_entry(summ[name], unit) for name, unit in PARAMETER_UNITS.items()}
    out["parameters"] = params
    mh = draws["m_level_pix"].reshape(-1, 2).mean(axis=0)
    out["level_reading_pix"] = {"m1": float(mh[0]), "m2": float(mh[1])}
    out["uncertainty_budget"] = budget_entries(est.budget, params)
    diag = flag_prior_dominated(params, diag)
    diag["problems"] = diag["problems"] + list(est.problems)
    diag.update(
        converged=bool(est.draws_converged and est.fit.result.converged),
        r_hat_max=float(max(params[n]["r_hat"] for n in params)),
        ess_bulk_min=float(min(params[n]["ess_bulk"] for n in params)),
        n_draws=int(C * Dn),
        n_chains=int(C),
        sampler=samp.method,
        sampler_message=samp.message,
        seconds=est.seconds,
    )
    diag.update(sampler_entries(samp))
    if not diag["converged"]:
        msg = "; ".join(diag["problems"]) or "not converged"
        warnings.warn(f"posterior NOT converged: {msg}", RuntimeWarning, stacklevel=2)
        if options.progress:
            print(f"WARNING: posterior NOT converged: {msg}")
    out["diagnostics"] = diag
    cols = out.get("residuals_mgal", {}).get("columns", [])
    out["posterior_predictive_mgal"] = _predictive_summary(est.replicates, cols, options.hdi_prob)
    out["drift_curve"] = est.drift
    angle = draws["angle_error_arcsec"].reshape(C * Dn, -1)
    out["angle_error_arcsec"] = {
        "step": [int(s) for s in model.hold_steps],
        "mean": list(angle.mean(axis=0)),
        "sd": list(angle.std(axis=0)),
    }
    if est.netcdf is not None:
        out["posterior_netcdf"] = str(est.netcdf)
    return out


def _predictive_summary(rep: np.ndarray, cols: list[str], hdi_prob: float) -> dict:
    """Mean and central interval of the replicated δg (draws, R, 2, angles) per column."""
    lo, hi = (1 - hdi_prob) / 2 * 100, (1 + hdi_prob) / 2 * 100

    def per_column(f) -> dict:
        return {c: list(f(rep[:, i // 2, i % 2])) for i, c in enumerate(cols)}

    return {
        "columns": cols,
        "delta_g_mean": per_column(lambda x: np.nanmean(x, axis=0)),
        "delta_g_low": per_column(lambda x: np.nanpercentile(x, lo, axis=0)),
        "delta_g_high": per_column(lambda x: np.nanpercentile(x, hi, axis=0)),
        "rms_mgal_mean": float(np.nanmean(np.sqrt(np.nanmean(rep**2, axis=-1)))),
        "n_replicates": int(rep.shape[0]),
    }


def protocol_result(
    base: Mapping[str, Any], est: ProtocolEstimate, options: CalibrationOptions
) -> dict:
    """The ``map`` or ``bayes`` result of a legacy protocol (:mod:`chekan.fit.protocol`):
    the model's b₁, b₂ (means over rounds), a (and the hyperparameters for bayes), the
    per-round b beside the classical ones, the budget and the diagnostics."""
    pm, res, hp = est.model, est.result, options.hdi_prob
    out = dict(base)
    out["method"] = options.method
    out["classical"] = {k: base["parameters"][k] for k in ("b1", "b2")}
    out.pop("fixed", None)
    diag: dict[str, Any] = {
        "converged": bool(res.converged),
        "map_steps": int(res.num_steps),
        "problems": [],
        "model": "characteristic per round (eq. 21) with shared angle errors marginalised"
        + ("" if pm.spec is None else "; systematic angle errors shared by all rounds (Type B)"),
    }
    out["angle_sensor"] = angle_sensor_entry(pm.spec)
    post = est.posterior
    if post is None:
        sd = res.sd()
        R = pm.rounds
        cov_b = res.cov_values([f"b_r{r + 1}_s{j + 1}" for r in range(R) for j in range(2)])
        params = _joint_b(res.values, cov_b, R, hp)
        params["a"] = param_entry(float(res.values["a"]), float(sd["a"]), hp, unit_of("a"))
        rounds = _per_round(R, lambda n: {"mean": float(res.values[n]), "sd": float(sd[n])})
    else:
        summ = post.summary
        params = {
            name: posterior_entry(summ[name], unit_of(name))
            for name in ("b1", "b2", "a", "sigma_theta_arcsec", "sigma_e_mgal")
        }
        keys = ("mean", "sd", "hdi_low", "hdi_high")
        rounds = _per_round(pm.rounds, lambda n: {k: summ[n][k] for k in keys})
    if "rounds" in out:
        out["rounds"] = _merged_rounds(out["rounds"], rounds)
    out["parameters"] = params
    out["uncertainty_budget"] = budget_entries(est.budget, params)
    if post is not None:
        samp = post.sampling
        diag.update(
            converged=bool(post.converged and res.converged),
            problems=list(post.problems),
            r_hat_max=float(max(s["r_hat"] for s in post.summary.values())),
            ess_bulk_min=float(min(s["ess_bulk"] for s in post.summary.values())),
            n_draws=int(samp.draws.shape[0] * samp.draws.shape[1]),
            n_steps=int(samp.n_steps),
        )
    diag["seconds"] = est.seconds
    out["diagnostics"] = diag
    if est.netcdf is not None:
        out["posterior_netcdf"] = str(est.netcdf)
    return out


def _per_round(R: int, entry) -> list[dict]:
    """``[{"b1": entry(r, 1), "b2": entry(r, 2)} for each round r]`` (per-round b names)."""
    return [{f"b{j}": entry(f"b_r{r + 1}_s{j}") for j in (1, 2)} for r in range(R)]


def _joint_b(values, cov_b, R, hp) -> dict:
    """b_j = mean over rounds, with the covariance of the per-round estimates."""
    out = {}
    for j in range(2):
        idx = [2 * r + j for r in range(R)]
        w = np.full(R, 1.0 / R)
        mean = float(sum(values[f"b_r{r + 1}_s{j + 1}"] for r in range(R)) / R)
        sd = float(np.sqrt(w @ cov_b[np.ix_(idx, idx)] @ w))
        out[f"b{j + 1}"] = param_entry(mean, sd, hp, unit_of(f"b{j + 1}"))
    return out


def _merged_rounds(classical: list[dict], model: list[dict]) -> list[dict]:
    """The classical rounds (not changed) each with the model's per-round b beside its own
    (``model_b1``, ``model_b2``)."""
    merged = [
        {**r, "model_b1": est["b1"], "model_b2": est["b2"]}
        for r, est in zip(classical, model, strict=False)
    ]
    return merged + list(classical[len(merged) :])
