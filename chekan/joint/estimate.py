"""``--method map|bayes`` on a record: from the record to the ``chekan-result/1`` dict.

:func:`estimate` prepares the record, fits the MAP (:mod:`chekan.joint.map`), and hands
the fit to :func:`map_result` or :func:`posterior_result`.
"""

from __future__ import annotations

import functools
import time
import warnings
from typing import cast

import numpy as np

from chekan.holds import HoldTable
from chekan.joint import em
from chekan.joint.angles import DEFAULT_BOUND_ARCSEC, angle_sensor_entry
from chekan.joint.binning import prepare
from chekan.joint.budget import budget_entries, flag_prior_dominated, uncertainty_budget
from chekan.joint.map import MapFit, fit_map_em
from chekan.joint.predictive import drift_curve, posterior_predictive_delta_g, write_netcdf
from chekan.joint.reported import map_derived
from chekan.joint.sampling import sample_posterior, sampler_config
from chekan.joint.start import initial_values
from chekan.joint.xresponse import horizontal_prior
from chekan.options import CalibrationOptions
from chekan.outputs import check_room
from chekan.parameters import PARAMETER_UNITS
from chekan.result import param_entry, posterior_entry
from chekan.runtime.engine import (
    FIRST_RUN_NOTICE,
    compiled_before,
    prefetch_after_map,
    prefetch_em,
)
from chekan.runtime.padding import padded_for
from chekan.runtime.process import single_threaded_blas
from chekan.settling import settled_items, tau_from_transients


def estimate(data, *, kind: str, classical, base: dict, options: CalibrationOptions) -> dict:
    """Run ``map`` or ``bayes`` on a record or protocol; return the result dict (BLAS on
    one thread: :func:`chekan.runtime.process.single_threaded_blas`)."""
    with single_threaded_blas():
        return _estimate(data, kind=kind, classical=classical, base=base, options=options)


def _estimate(data, *, kind: str, classical, base: dict, options: CalibrationOptions) -> dict:
    if kind == "protocol":
        from chekan.joint.legacy import estimate_protocol

        return estimate_protocol(data, classical=classical, base=base, options=options)
    t_start = time.perf_counter()
    record = data
    holds, model = prepare(
        record,
        options.settle_s,
        encoder=options.encoder_error,
        angle_spec=options.angle_spec(
            record.meta, str(base.get("record", "record")), record.angle_calibration
        ),
        angle_spec_x=options.angle_spec(
            record.meta, str(base.get("record", "record")), record.angle_calibration, axis="x"
        ),
        horizontal_u_pix=horizontal_prior(options.horizontal_u_pix)[0],
    )
    if options.method == "bayes":  # a full disk shows now, not after the sampling
        check_room(options.netcdf, netcdf_bytes(model, options), "the posterior NetCDF")
    init = initial_values(classical, record.g_local_mgal)
    if options.progress:
        print(
            f"model: {model.n_holds} holds, {model.n_bins} bins × 2 systems, "
            f"{model.n_beta} marginalised linear parameters"
        )
    model = padded_for(model)  # its bucket's engine, shared by map and bayes
    # a new process loads the stored executables it will need next while the MAP runs
    prefetch_em(model)
    if options.progress and not compiled_before(model):
        print(FIRST_RUN_NOTICE)
    sampler_imports = prefetch_after_map(model, options.method)
    fit = fit_map_em(
        model,
        init,
        progress=options.progress,
        solver=options.map_solver,
        tau_hint_s=functools.partial(tau_from_transients, record, holds),
    )
    if options.method == "map":
        out = map_result(fit, base, options, t_start)
    else:
        assert sampler_imports is not None
        sampler_imports.result()  # done before this thread imports more (deadlock-free)
        out = posterior_result(fit, holds, record, base, options, t_start)
    return settled_items(out, holds, record, classical=classical, a_fixed=options.a_fixed)


def netcdf_bytes(model, options: CalibrationOptions) -> int:
    """About the most the posterior NetCDF of ``model`` takes (the draws kept at most, each
    with its pointwise log-likelihood per bin and system, the per-hold and scalar
    quantities), plus a megabyte for the result JSON beside it."""
    cfg = sampler_config(options)
    draws = cfg.n_chains * (cfg.max_draws or 1000)
    per_draw = 2 * model.n_bins + 3 * model.n_holds + 64
    return 8 * draws * per_draw + 16 * model.n_bins + (1 << 20)


def _common(fit: MapFit, base: dict, options: CalibrationOptions) -> tuple[dict, dict]:
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
    capped = [p["iteration"] + 1 for p in fit.history if p.get("hyper_converged") is False]
    to_zero = sorted({n for p in fit.history for n in p.get("hyper_to_zero", [])})
    diag = {
        "converged": bool(res.converged) and not capped,
        "map_steps": int(res.num_steps),
        "map_passes": list(fit.history),
        "jacobian_cond": float(res.jacobian_cond),
        "not_identified": list(res.degenerate),
        "data": "bin means inside holds (lag modelled), β marginalised",
        "problems": ([] if res.converged else [f"MAP did not converge: {res.message}"])
        + em.capped_passes(capped)
        + list(base.get("program_coverage", {}).get("problems", []))
        + em.hyper_at_bounds(fit.hyper)
        + em.residual_misfit(fit.hyper)
        + em.implausible_angle_error(fit.hyper, _specified_accuracy(model)),
    }
    if to_zero:  # EM converging to a boundary, slowly: as at a clip bound (hyper_at_bounds)
        diag["problems"] = [
            *cast(list[str], diag["problems"]),
            f"the EM of the hyperparameters stopped at its cap with {', '.join(to_zero)} still"
            " falling towards zero, its lower bound: the data did not determine it, and the"
            " uncertainty that rests on it may be wrong",
        ]
    return out, diag


def _specified_accuracy(model) -> float:
    """The platform's angle accuracy (arcsec) that its random error may not exceed by much:
    the specification's 3″, or a larger bound the user states for one of its sensors."""
    specs = (model.angle_spec, model.angle_spec_x)
    return max([DEFAULT_BOUND_ARCSEC, *(s.bound_arcsec for s in specs if s is not None)])


def map_result(fit: MapFit, base: dict, options: CalibrationOptions, t_start: float) -> dict:
    """The ``map`` result: MAP values, delta-method sds (with the hyperparameters'
    estimation), the budget, ν_eff and U = k·u (:mod:`chekan.joint.typea`)."""
    out, diag = _common(fit, base, options)
    budget_raw = uncertainty_budget(fit)
    md = map_derived(fit)
    nu = md["_nu_eff"]
    params = {
        name: param_entry(
            md[name][0],
            md[name][1],
            options.hdi_prob,
            PARAMETER_UNITS.get(name, ""),
            nu_eff=nu.get(name),
        )
        for name in md
        if not name.startswith("_")
    }
    out["parameters"] = params
    out["level_reading_pix"] = {"m1": float(md["_m_level"][0]), "m2": float(md["_m_level"][1])}
    for name in ("b1", "b2"):  # the estimate's move with the estimated hyperparameters
        budget_raw[name]["hyperparameters"] = md["_u_hyper"][name]
    out["uncertainty_budget"] = budget_entries(budget_raw, params, nu)
    diag = flag_prior_dominated(params, diag)
    if md["_type_a_clipped"]:  # inference.dof.log_var_cov took the positive part
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
    diag["seconds"] = time.perf_counter() - t_start
    out["diagnostics"] = diag
    return out


def posterior_result(
    fit: MapFit,
    holds: HoldTable,
    record,
    base: dict,
    options: CalibrationOptions,
    t_start: float,
) -> dict:
    """The ``bayes`` result: posterior summaries, diagnostics, predictive, drift, NetCDF."""
    from inference.diagnostics import convergence_report, summarize_draws

    out, diag = _common(fit, base, options)
    budget_raw = uncertainty_budget(fit)
    model = fit.model
    samp = sample_posterior(fit, options)
    C, Dn = samp.draws.shape[:2]
    draws = dict(samp.derived)
    scalar = {k: v for k, v in draws.items() if v.ndim == 2}
    summ = summarize_draws(scalar, hdi_prob=options.hdi_prob)
    ok, problems = convergence_report(summ, rhat_max=1.01, ess_min=400)
    params = {name: posterior_entry(summ[name], unit) for name, unit in PARAMETER_UNITS.items()}
    out["parameters"] = params
    mh = draws["m_level_pix"].reshape(-1, 2).mean(axis=0)
    out["level_reading_pix"] = {"m1": float(mh[0]), "m2": float(mh[1])}
    out["uncertainty_budget"] = budget_entries(budget_raw, params)
    diag = flag_prior_dominated(params, diag)
    diag["problems"] = diag["problems"] + problems
    diag.update(
        converged=bool(ok and fit.result.converged),
        r_hat_max=float(max(params[n]["r_hat"] for n in params)),
        ess_bulk_min=float(min(params[n]["ess_bulk"] for n in params)),
        n_draws=int(C * Dn),
        n_chains=int(C),
        n_walkers=int(samp.n_walkers),
        n_steps=int(samp.n_steps),
        burn=int(samp.burn),
        thin=int(samp.thin),
        tau_max=float(np.max(samp.tau)),
        acceptance=[float(a) for a in samp.acceptance],
        sampler_message=samp.message,
        seconds=time.perf_counter() - t_start,
    )
    if not diag["converged"]:
        msg = "; ".join(diag["problems"]) or "not converged"
        warnings.warn(f"posterior NOT converged: {msg}", RuntimeWarning, stacklevel=2)
        if options.progress:
            print(f"WARNING: posterior NOT converged: {msg}")
    out["diagnostics"] = diag
    # posterior predictive of the paper's residual table
    rng = np.random.default_rng(options.seed)
    rep = posterior_predictive_delta_g(
        holds, record.g_local_mgal, draws, model, rng, options.a_fixed
    )
    cols = out.get("residuals_mgal", {}).get("columns", [])
    out["posterior_predictive_mgal"] = _predictive_summary(rep, cols, options.hdi_prob)
    out["drift_curve"] = drift_curve(draws, model, hp=options.hdi_prob)
    angle = draws["angle_error_arcsec"].reshape(C * Dn, -1)
    out["angle_error_arcsec"] = {
        "step": [int(s) for s in model.hold_steps],
        "mean": list(angle.mean(axis=0)),
        "sd": list(angle.std(axis=0)),
    }
    if options.netcdf:
        out["posterior_netcdf"] = str(write_netcdf(options.netcdf, draws, samp, model, rep, cols))
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
