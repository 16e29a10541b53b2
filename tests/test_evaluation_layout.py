"""The 0.3.3 evaluation changes give the same model: both systems' normal equations at
once, the slews' angle columns factored by hold (against the dense design, padded and
with systematic terms), the equilibrium with the systems on the leading axis, and the
posterior predictive's equilibria for all draws in one call."""

from __future__ import annotations

import dense_oracle as lk
import jax.numpy as jnp
import numpy as np
import pytest

from chekan.physics import sensor as fm


def _systematic_model(short_session, theta: dict, pad: bool):
    from chekan.joint.angles import AngleSensorSpec
    from chekan.joint.binning import prepare

    _, model = prepare(short_session[1], 200, angle_spec=AngleSensorSpec(3.0))
    assert model.structure.n_systematic > 0
    if pad:
        model = model.pad(model.n_holds + 2, model.n_bins + 7, model.structure.n_moves + 3)
    h = {
        "noise_scale": jnp.asarray([1.3, 0.7]),
        "sigma_theta_arcsec": jnp.asarray(2.0),
        "sigma_hold_pix": jnp.asarray(0.08),
        "slew_error": jnp.asarray(0.02),
    }
    return model, theta, h


def test_normal_equations_equal_the_dense_products(short_session, short_session_theta):
    """AᵀWA, AᵀWr and rᵀWr from the hold-factored assembly equal the dense design's,
    entry by entry, with padding (bins, holds, slew samples) and systematic terms."""
    for pad in (False, True):
        model, v, h = _systematic_model(short_session, short_session_theta, pad)
        data, st = model.data, model.structure
        ne, pieces = lk.normal_equations(v, h, st, data)
        _, _, _, r, W, _, _, P = pieces
        _, A = lk.predict(v, st, data)
        A = np.asarray(A)  # (N, 2, p)
        Wn, rn = np.asarray(W), np.asarray(r)
        M = np.einsum("njp,nj,njq->pq", A, Wn, A)
        g = np.einsum("njp,nj,nj->p", A, Wn, rn)
        scale = np.sqrt(np.outer(np.diag(M), np.diag(M))) + 1e-300
        assert np.max(np.abs(np.asarray(ne.G) - M) / scale) < 1e-11, pad
        np.testing.assert_allclose(np.asarray(ne.g), g, rtol=1e-9, atol=1e-9 * np.abs(g).max())
        assert np.isclose(float(ne.rNr), np.sum(Wn * rn * rn), rtol=1e-13)
        # A·β without forming A, also through the factored slew columns
        beta = np.random.default_rng(3).normal(size=st.n_beta)
        got = lk.apply_A(jnp.asarray(beta), pieces[1], pieces[2], st, data, P)
        np.testing.assert_allclose(np.asarray(got), A @ beta, rtol=1e-10, atol=1e-10)


def test_gram_of_both_systems_equals_dense(short_session, short_session_theta):
    """Gᵀ diag(wⱼ) G for both systems at once (trailing axis) equals the dense product."""
    model, v, _ = _systematic_model(short_session, short_session_theta, pad=True)
    G = lk.linear_terms(v, model.data)[1]
    sp = lk._hold_sparse(G, model.data)
    w = np.random.default_rng(4).uniform(0.5, 2.0, (G.shape[0], 2))
    got = np.asarray(sp.gram(jnp.asarray(w)))
    Gn = np.asarray(G)
    for j in range(2):
        np.testing.assert_allclose(got[..., j], Gn.T @ (w[:, j, None] * Gn), atol=1e-13)


def test_equilibrium_by_system_is_the_transposed_equilibrium():
    """Systems on the leading axis: the same numbers as the (…, 2) layout, for scalar,
    1-d and 2-d attitudes (the slews' shape)."""
    p = fm.make_params(
        g_mgal=981_600.0,
        K_pix_per_rad=59_600.0,  # a = g/(2K²) ≈ 1.4e-4 mGal/pix², as measured
        b_mgal_per_pix=[6.9, 7.1],
        m_level_pix=[1010.0, 1040.0],
        eps_rad=[0.001, -0.002],
        gamma_rad=0.003,
    )
    rng = np.random.default_rng(5)
    for shape in ((), (7,), (4, 6)):
        tx = rng.uniform(-1e-4, 1e-4, shape)
        ty = rng.uniform(-0.09, 0.09, shape)
        lead = np.asarray(fm.equilibrium_by_system(p, tx, ty))
        trail = np.asarray(fm.equilibrium_readings(p, tx, ty))
        assert lead.shape == (2, *shape) and trail.shape == (*shape, 2)
        # to rounding: this call runs op by op, equilibrium_readings is jitted (fused)
        np.testing.assert_allclose(np.moveaxis(lead, 0, -1), trail, rtol=1e-14)
        # level: the reading at zero tilt is the level reading
        np.testing.assert_allclose(
            np.asarray(fm.equilibrium_by_system(p, 0.0, 0.0)), [1010.0, 1040.0], rtol=1e-13
        )


@pytest.mark.parametrize("m0", [1024.0, 900.0])
def test_predictive_equilibria_equal_per_draw_evaluation(m0):
    """All draws in one vectorised call equal make_params + evaluation per draw (also a
    draw with a ≤ 0, which takes the design K), at the record's CCD centre ``m0``."""
    from types import SimpleNamespace

    from chekan.fit.predictive import _equilibria, equilibria_of
    from chekan.joint.problem import K_DESIGN
    from chekan.physics.units import ARCMIN_PER_RAD
    from chekan.runtime.engine import PREDICTIVE
    from chekan.runtime.store import ExecutableStore

    g = 981_600.0
    flat = {
        "a": np.array([1.38e-4, -1.0e-6, 1.41e-4]),
        "b1": np.array([6.9, 7.0, 6.8]),
        "b2": np.array([7.1, 7.2, 7.0]),
        "m_level_pix": np.array([[1010.0, 1040.0], [1011.0, 1039.0], [990.0, 1050.0]]),
        "eps1_arcmin": np.array([3.9, 4.1, 4.0]),
        "eps2_arcmin": np.array([-2.0, -2.1, -1.9]),
        "dgamma_arcmin": np.array([1.0, 0.0, -1.0]),
    }
    holds = SimpleNamespace(
        tilt_x_rad=np.zeros(5), tilt_y_rad=np.radians([0.0, 1.9, -1.9, 5.1, -5.1])
    )
    take = np.array([2, 0, 1])
    E, S = _equilibria(g, m0, flat, take, holds)
    # through an executable store (as calibrate runs it): the same numbers
    compiled = ExecutableStore(None, "test").jit(PREDICTIVE, equilibria_of)
    E2, S2 = _equilibria(g, m0, flat, take, holds, compiled)
    np.testing.assert_array_equal(E2, E)
    np.testing.assert_array_equal(S2, S)
    # padded to a bucket's shape (more draws, more holds) and cut back: the same numbers
    E3, S3 = _equilibria(g, m0, flat, take, holds, compiled, (8, 9))
    assert E3.shape == E.shape == (3, 5, 2)
    np.testing.assert_allclose(E3, E, rtol=1e-13)
    np.testing.assert_allclose(S3, S, rtol=1e-13)
    for n, i in enumerate(take):
        a = flat["a"][i]
        sp = fm.make_params(
            g_mgal=g,
            K_pix_per_rad=float(np.sqrt(g / 2 / a)) if a > 0 else K_DESIGN,
            b_mgal_per_pix=[flat["b1"][i], flat["b2"][i]],
            m_level_pix=flat["m_level_pix"][i],
            eps_rad=np.array([flat["eps1_arcmin"][i], flat["eps2_arcmin"][i]]) / ARCMIN_PER_RAD,
            gamma_rad=flat["dgamma_arcmin"][i] / ARCMIN_PER_RAD,
            m0_pix=m0,
        )
        np.testing.assert_allclose(
            E[n], fm.equilibrium_readings(sp, holds.tilt_x_rad, holds.tilt_y_rad), rtol=1e-14
        )
        np.testing.assert_allclose(
            S[n],
            fm.reading_sensitivity_to_tilt(sp, holds.tilt_x_rad, holds.tilt_y_rad),
            rtol=1e-12,
        )


def test_the_posterior_predictive_uses_the_records_ccd_centre():
    """Replicas of noise-free draws give the classical δg of the model evaluated at the
    record's ``ccd_center_pix`` (900 here), which the fit uses; it took 1024 before 0.3.9."""

    from chekan.classical.fit import fit_classical, increments_from_holds
    from chekan.demo import demo_program
    from chekan.fit.predictive import posterior_predictive_delta_g
    from chekan.physics.units import ARCMIN_PER_RAD
    from chekan.records.holds import segment_record
    from chekan.records.simulate import Truth, simulate_session
    from chekan.warmup import padded_model

    rec, truth = simulate_session(
        demo_program(quick=True), Truth(serial="M0", m0_pix=900.0), seed=3
    )
    holds = segment_record(rec, settle_s=200.0)
    g = rec.g_local_mgal
    t = truth
    one = {
        "a": np.array([g / 2 / t.K_pix_per_rad**2]),
        "b1": np.array([t.b_mgal_per_pix[0]]),
        "b2": np.array([t.b_mgal_per_pix[1]]),
        "m_level_pix": np.array([t.m_level_pix]),
        "eps1_arcmin": np.array([t.eps_arcmin[0]]),
        "eps2_arcmin": np.array([t.eps_arcmin[1]]),
        "dgamma_arcmin": np.array([t.dgamma_arcmin]),
        "drift_coeffs": np.zeros((1, 2, 3)),
        **{k: np.zeros(1) for k in ("sigma_hold_pix", "sigma_theta_arcsec")},
        **{k: np.zeros(1) for k in ("sigma1_pix", "sigma2_pix")},
    }
    draws = {k: v[None] for k, v in one.items()}  # (chain, draw, ...)
    model = padded_model(rec)  # as bayes fits it
    assert float(model.data.m0) == 900.0 and model.drift_degree == 3
    rep = posterior_predictive_delta_g(holds, g, draws, model, np.random.default_rng(0))
    sp = fm.make_params(
        g_mgal=g,
        K_pix_per_rad=t.K_pix_per_rad,
        b_mgal_per_pix=t.b_mgal_per_pix,
        m_level_pix=t.m_level_pix,
        eps_rad=np.array(t.eps_arcmin) / ARCMIN_PER_RAD,
        gamma_rad=t.dgamma_arcmin / ARCMIN_PER_RAD,
        m0_pix=900.0,
    )
    E = np.asarray(fm.equilibrium_readings(sp, holds.tilt_x_rad, holds.tilt_y_rad))
    want = fit_classical(
        increments_from_holds(holds.__class__(**{**holds.__dict__, "m_mean_pix": E}), g)
    )
    np.testing.assert_allclose(rep[0], want.delta_g_mgal, atol=1e-9)
