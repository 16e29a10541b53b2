"""The compiled EM between MAP passes agrees with the host EM of 0.2 (chekan.joint.em)."""

from __future__ import annotations

import jax
import numpy as np

from chekan import joint
from chekan.classical import calibrate_record
from chekan.joint import em, em_compiled
from chekan.joint.angles import AngleSensorSpec


def _model_and_start(rec):
    cres, _ = calibrate_record(rec, settle_s=200)
    _, model = joint.prepare(rec, 200, angle_spec=AngleSensorSpec(3.0))
    prob = joint.problem_for(model.structure)
    fit = joint.fit_map_em(model, joint.initial_values(cres, rec.g_local_mgal))
    return fit, prob


def test_one_update_equals_the_host_update_to_the_m_steps_precision(short_session):
    _, rec, _ = short_session
    fit, prob = _model_and_start(rec)
    z, h, model = fit.result.z, joint.default_hyper(), fit.model
    host = em.em_update(model, z, h)
    v = prob.map_space.to_values(z)
    compiled = jax.jit(lambda v, h, d: em_compiled.em_update(v, h, model.structure, d))(
        v, h, model.data
    )
    for k in host:  # σ_θ and σ_o are closed form; (s, κ): L-BFGS-B stops at ~1e-5
        np.testing.assert_allclose(np.asarray(compiled[k]), np.asarray(host[k]), rtol=1e-4)


def test_between_passes_reaches_the_host_fixed_point_and_level(short_session):
    _, rec, _ = short_session
    fit, _ = _model_and_start(rec)
    z, h = fit.result.z, joint.default_hyper()
    m_host, h_host, n_host = em.between_passes(fit.model, z, h)
    m_comp, h_comp, n_comp = em_compiled.between_passes(fit.model, z, h)
    np.testing.assert_allclose(
        np.asarray(m_comp.data.m_ref), np.asarray(m_host.data.m_ref), rtol=0, atol=1e-6
    )
    assert 1 < n_comp < em.HYPER_MAX_UPDATES and 1 < n_host
    for k in h_host:  # both stop when no log-hyperparameter moves by more than 1e-4
        np.testing.assert_allclose(np.log(h_comp[k]), np.log(h_host[k]), atol=2e-3)
    # it is a fixed point: one more compiled update moves nothing beyond the tolerance
    again = em_compiled.between_passes(m_comp, z, h_comp)[1]
    for k in h_comp:
        assert np.max(np.abs(np.log(again[k]) - np.log(h_comp[k]))) < 2e-3


def test_between_passes_reaches_the_fixed_point_where_em_creeps(tmp_path):
    """A short one-round archive session: σ_θ creeps towards its floor and 200 EM updates
    stop far from the fixed point; after EM_UPDATES_BEFORE_NEWTON updates Newton solves
    h = EM(h), so one more update moves no log-hyperparameter by more than 1e-6."""
    from chekan.archive.synth import InstrumentSpec, short_program, write_session
    from chekan.options import CalibrationOptions
    from chekan.pipeline import classical_stage

    path = tmp_path / "session.csv"
    write_session(
        path, InstrumentSpec("T-6", seed=7), "2012-05-01", seed=7, program=short_program()
    )
    opts = CalibrationOptions(method="map", progress=False)
    rec, _, cres, _ = classical_stage(path, opts)
    _, model = joint.prepare(rec, None, angle_spec=opts.angle_spec(rec.meta, "r"))
    prob = joint.problem_for(model.structure)
    fit = joint.fit_map_em(model, joint.initial_values(cres, rec.g_local_mgal))
    z, h0 = fit.result.z, joint.default_hyper()
    moved, h, n = em_compiled.between_passes(fit.model, z, h0)
    assert em_compiled.EM_UPDATES_BEFORE_NEWTON < n < em.HYPER_MAX_UPDATES
    v = prob.map_space.to_values(z)
    st, data = model.structure, moved.data
    update = jax.jit(lambda h: em_compiled.em_update(v, h, st, data))
    again = update(h)
    for k in h:
        assert np.max(np.abs(np.log(again[k]) - np.log(h[k]))) < 1e-6, k
    capped = jax.jit(
        lambda h: jax.lax.fori_loop(0, em.HYPER_MAX_UPDATES, lambda _, x: update(x), h)
    )
    plain = capped(h0)  # EM alone: still creeping after its 200 updates
    gap = max(float(np.max(np.abs(np.log(plain[k]) - np.log(h[k])))) for k in h)
    assert gap > 0.05, gap
