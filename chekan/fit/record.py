"""``--method map|bayes`` on a record or protocol: from the data to a typed fit.

:func:`estimate` prepares the record, fits the MAP (:mod:`chekan.fit.map`), and, for
``bayes``, samples the posterior; it returns a :mod:`chekan.fit.fitted` value, which
:func:`chekan.results.joint.joint_result` writes as the ``chekan-result/1`` dict.
"""

from __future__ import annotations

import functools
import time
from typing import TYPE_CHECKING, TypeAlias

import numpy as np

from chekan.classical.settling import JointValues, settle, tau_from_transients
from chekan.files.outputs import check_room
from chekan.fit.budget import uncertainty_budget
from chekan.fit.fitted import MapEstimate, PosteriorEstimate
from chekan.fit.map import MapFit, fit_map_em
from chekan.fit.predictive import drift_curve, posterior_predictive_delta_g, write_netcdf
from chekan.fit.reported import ReportedDraws, map_derived
from chekan.fit.sampling import sample_posterior, sampler_config
from chekan.fit.start import initial_values
from chekan.joint.binning import prepare
from chekan.joint.xresponse import horizontal_prior
from chekan.options import CalibrationOptions
from chekan.physics.parameters import PARAMETER_UNITS
from chekan.runtime.engine import (
    FIRST_RUN_NOTICE,
    compiled_before,
    prefetch_after_map,
    prefetch_em,
)
from chekan.runtime.padding import padded_for
from chekan.runtime.process import single_threaded_blas

if TYPE_CHECKING:
    from chekan.fit.protocol import ProtocolEstimate
    from chekan.records.holds import HoldTable

#: What :func:`estimate` returns.
JointEstimate: TypeAlias = "MapEstimate | PosteriorEstimate | ProtocolEstimate"


def estimate(
    data,
    *,
    kind: str,
    classical,
    source: str,
    options: CalibrationOptions,
    holds: HoldTable | None = None,
) -> JointEstimate:
    """Run ``map`` or ``bayes`` on a record or protocol (``source``: the input's name, for
    messages; ``holds``: a record's holds where found already, as
    :func:`chekan.records.inputs.ready_input` finds them); the typed fit (BLAS on one
    thread: :func:`chekan.runtime.process.single_threaded_blas`)."""
    with single_threaded_blas():
        return _estimate(
            data, kind=kind, classical=classical, source=source, options=options, holds=holds
        )


def _estimate(
    data,
    *,
    kind: str,
    classical,
    source: str,
    options: CalibrationOptions,
    holds: HoldTable | None,
) -> JointEstimate:
    if kind == "protocol":
        from chekan.fit.protocol import estimate_protocol

        return estimate_protocol(data, classical=classical, options=options)
    t_start = time.perf_counter()
    record = data
    holds, model = prepare(
        record,
        options.settle_s,
        holds=holds,
        encoder=options.encoder_error,
        angle_spec=options.angle_spec(record.meta, source, record.angle_calibration),
        angle_spec_x=options.angle_spec(record.meta, source, record.angle_calibration, axis="x"),
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
        return _map_estimate(fit, holds, record, classical, options, t_start)
    assert sampler_imports is not None
    sampler_imports.result()  # done before this thread imports more (deadlock-free)
    return _posterior_estimate(fit, holds, record, classical, options, t_start)


def _values(fit: MapFit, record, means: dict, m_level_pix, converged: bool) -> JointValues:
    """What the settled items rest on (:class:`chekan.classical.settling.JointValues`)."""
    return JointValues(
        a=means.get("a"),
        means=means,
        m_level_pix={"m1": float(m_level_pix[0]), "m2": float(m_level_pix[1])},
        g_local_mgal=float(record.g_local_mgal),
        ccd_center_pix=float(record.ccd_center_pix),
        converged=converged,
    )


def _map_estimate(fit: MapFit, holds, record, classical, options, t_start) -> MapEstimate:
    """The MAP's derived quantities with delta-method sds (with the hyperparameters'
    estimation), its raw budget, and the settled classical items."""
    budget = uncertainty_budget(fit)
    md = map_derived(fit)
    seconds = time.perf_counter() - t_start
    means = {name: value for name, (value, _) in md.values.items()}
    values = _values(fit, record, means, md.m_level_pix, fit.converged)
    found = settle(values, holds, record, classical=classical, a_fixed=options.a_fixed)
    return MapEstimate(fit, md, budget, found, seconds)


def _posterior_estimate(
    fit: MapFit, holds, record, classical, options, t_start
) -> PosteriorEstimate:
    """The posterior: draws, their summary and convergence, the posterior predictive of the
    residual table, the NetCDF, and the settled classical items."""
    from inference.diagnostics import convergence_report, summarize_draws
    from inference.importance_path import with_weighted_ess

    budget = uncertainty_budget(fit)
    model = fit.model
    samp = sample_posterior(fit, options)
    draws = samp.derived
    assert isinstance(draws, ReportedDraws)
    scalar = {k: v for k, v in draws.items() if v.ndim == 2}
    summ = with_weighted_ess(summarize_draws(scalar, hdi_prob=options.hdi_prob), samp.weighted_ess)
    ok, problems = convergence_report(summ, rhat_max=1.01, ess_min=400)
    seconds = time.perf_counter() - t_start
    # posterior predictive of the paper's residual table
    rng = np.random.default_rng(options.seed)
    rep = posterior_predictive_delta_g(
        holds, record.g_local_mgal, dict(draws), model, rng, options.a_fixed
    )
    cols = classical.column_names
    netcdf = None
    if options.netcdf:
        netcdf = write_netcdf(options.netcdf, draws, samp, model, rep, cols)
    means = {name: summ[name]["mean"] for name in PARAMETER_UNITS}
    mh = draws["m_level_pix"].reshape(-1, 2).mean(axis=0)
    converged = bool(ok and fit.result.converged)
    values = _values(fit, record, means, mh, converged)
    found = settle(values, holds, record, classical=classical, a_fixed=options.a_fixed)
    drift = drift_curve(draws, model, hp=options.hdi_prob)
    return PosteriorEstimate(
        fit, budget, samp, summ, bool(ok), tuple(problems), rep, netcdf, found, seconds, drift
    )


def netcdf_bytes(model, options: CalibrationOptions) -> int:
    """About the most the posterior NetCDF of ``model`` takes (the draws kept at most, each
    with its pointwise log-likelihood per bin and system, the per-hold and scalar
    quantities), plus a megabyte for the result JSON beside it."""
    cfg = sampler_config(options)
    draws = cfg.n_chains * (cfg.max_draws or 1000)
    per_draw = 2 * model.n_bins + 3 * model.n_holds + 64
    return 8 * draws * per_draw + 16 * model.n_bins + (1 << 20)
