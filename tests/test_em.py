"""The EM between MAP passes (chekan.joint.em): one compiled loop for both MAP solvers.

Checked against what it must compute: the level moves by ĉ, σ_θ and σ_o are the closed-form
M-steps, (s₁, s₂, κ) a stationary point of the noise M-step's objective inside its box, the
result a fixed point of the update; where EM creeps Newton reaches that fixed point.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from chekan import joint
from chekan.classical.fit import calibrate_record
from chekan.fit import fit_map_em, initial_values
from chekan.fit.map import between_passes
from chekan.joint import em
from chekan.joint.angles import AngleSensorSpec
from chekan.joint.beta_posterior import solve_beta
from chekan.runtime.padding import padded_shape


def _fit(rec, solver="gn"):
    cres, _ = calibrate_record(rec, settle_s=200)
    _, model = joint.prepare(rec, 200, angle_spec=AngleSensorSpec(3.0))
    prob = joint.problem_for(model.structure)
    fit = fit_map_em(model, initial_values(cres, rec.g_local_mgal), solver=solver)
    return fit, prob


def test_one_update_is_the_closed_form_m_steps_and_a_stationary_noise_m_step(short_session):
    _, rec, _ = short_session
    fit, prob = _fit(rec)
    z, h, model = fit.result.z, joint.default_hyper(), fit.model
    st, data = model.structure, model.data
    v = prob.map_space.to_values(z)
    new = jax.jit(lambda v, h, d: em.em_update(v, h, st, d))(v, h, data)
    rw, beta, var, base, trans, lev = (
        np.asarray(x) for x in jax.jit(lambda v, h, d: em.beta_moments(v, h, st, d))(v, h, data)
    )
    hold = np.asarray(data.hold_mask)
    d_ix = np.asarray(st.beta_blocks["angle_error"])[hold]
    o_ix = np.asarray(st.beta_blocks["hold_offset"])[np.tile(hold, 2)]
    want_theta = np.sqrt(np.mean(beta[d_ix] ** 2 + var[d_ix]))
    want_hold = np.sqrt(np.mean(beta[o_ix] ** 2 + var[o_ix]))
    np.testing.assert_allclose(float(new["sigma_theta_arcsec"]), want_theta, rtol=1e-12)
    np.testing.assert_allclose(float(new["sigma_hold_pix"]), want_hold, rtol=1e-12)
    # the noise M-step: its objective's gradient vanishes at (log s₁, log s₂, log κ) where
    # that coordinate is inside the box
    mask = np.asarray(data.mask)
    nv = base + (float(h["slew_error"]) * trans) ** 2
    e2 = np.where(mask, (rw.reshape(mask.shape) ** 2 + lev) * nv, 0.0)
    b0 = base / np.asarray(h["noise_scale"])[None, :] ** 2

    def objective(x):
        ls, lk = x[:2], x[2]
        var_ = jnp.where(mask, jnp.exp(2 * ls)[None, :] * b0 + jnp.exp(2 * lk) * trans**2, 1.0)
        val = 0.5 * jnp.sum(mask * (jnp.log(var_) + e2 / var_))
        return (
            val
            + 0.5 * jnp.sum(((ls - em.S_LOC) / em.S_SD) ** 2)
            + 0.5 * ((lk - em.K_LOC) / em.K_SD) ** 2
        )

    x = np.log(np.r_[np.asarray(new["noise_scale"]), float(new["slew_error"])])
    g = np.asarray(jax.grad(objective)(jnp.asarray(x)))
    inside = (x > em.NOISE_LOWER + 1e-6) & (x < em.NOISE_UPPER - 1e-6)
    assert inside[:2].all(), x
    assert np.all(np.abs(g[inside]) < 1e-6 * (1 + np.sum(mask))), g


def test_between_passes_moves_the_level_by_c_and_ends_at_a_fixed_point(short_session):
    _, rec, _ = short_session
    fit, prob = _fit(rec)
    z, h = fit.result.z, joint.default_hyper()
    model = fit.model
    m_ref_before = np.array(model.data.m_ref)
    moved, h_new, n, _ = between_passes(model, z, h)
    v = prob.map_space.to_values(z)
    beta = solve_beta(v, h, model.structure, model.data).beta
    c = np.asarray(beta)[model.structure.beta_blocks["c"]]
    np.testing.assert_allclose(
        np.asarray(moved.data.m_ref), np.asarray(model.data.m_ref) + c, rtol=0, atol=1e-9
    )
    np.testing.assert_array_equal(np.asarray(model.data.m_ref), m_ref_before)  # new state
    assert 1 < n < em.HYPER_MAX_UPDATES
    # a fixed point: one more update (θ integrated in its E-step, as between passes) moves
    # no log-hyperparameter by more than the tolerance
    st, data = moved.structure, moved.data
    space = prob.map_space
    again = jax.jit(
        lambda h: em.em_update_theta(jnp.asarray(z), h, data, space=space, structure=st)
    )(h_new)
    for k in h_new:
        assert np.max(np.abs(np.log(again[k]) - np.log(h_new[k]))) < 2 * em.HYPER_TOL, k


def test_lm_changes_only_the_solver_of_the_passes(short_session):
    """``map_solver="lm"`` runs the same EM: the hyperparameters and θ̂ of both solvers agree
    to the solvers' tolerance (1e-4 sd; the EM's 1e-4 in log)."""
    _, rec, _ = short_session
    gn, _ = _fit(rec, "gn")
    lm, _ = _fit(rec, "lm")
    for k in gn.hyper:
        np.testing.assert_allclose(np.log(lm.hyper[k]), np.log(gn.hyper[k]), atol=1e-3)
    sd = np.sqrt(np.diag(gn.result.cov_z))
    assert np.all(np.abs(lm.result.z - gn.result.z) < 1e-3 * sd), (lm.result.z - gn.result.z) / sd


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
    # in its shape bucket, as calibrate fits it (the padding carries no weight): the
    # structure of test_map_restart's short session, whose compiled solver it shares
    model = model.pad(*padded_shape([model]))
    prob = joint.problem_for(model.structure)
    fit = fit_map_em(model, initial_values(cres, rec.g_local_mgal))
    z, h0 = fit.result.z, joint.default_hyper()
    moved, h, n, _ = between_passes(fit.model, z, h0)
    assert em.EM_UPDATES_BEFORE_NEWTON < n < em.HYPER_MAX_UPDATES
    assert "em_newton" in {name for name, _ in joint.engine_for(model.structure).store.events}
    st, data = model.structure, moved.data
    space = prob.map_space
    update = jax.jit(
        lambda h: em.em_update_theta(jnp.asarray(z), h, data, space=space, structure=st)
    )
    again = update(h)
    for k in h:
        assert np.max(np.abs(np.log(again[k]) - np.log(h[k]))) < 1e-6, k
    capped = jax.jit(
        lambda h: jax.lax.fori_loop(0, em.HYPER_MAX_UPDATES, lambda _, x: update(x), h)
    )
    plain = capped(h0)  # EM alone: still creeping after its 200 updates
    gap = max(float(np.max(np.abs(np.log(plain[k]) - np.log(h[k])))) for k in h)
    assert gap > 0.05, gap
