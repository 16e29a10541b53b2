"""The MAP's Type A terms on a simulated record (issue 29), against independent computations:

- θ's terms of the E-step (:func:`chekan.joint.em.theta_terms`) are what the joint Laplace
  posterior of (θ, β) adds to that of β given θ, formed here from the joint Jacobian;
- ∂b̂/∂log h² and ∂u²/∂log h² of :mod:`chekan.fit.typea` are finite differences of MAP
  passes re-solved with one hyperparameter moved;
- the reported sd is the Laplace sd and uₕ in quadrature, the budget's U is t₉₅.₄₅(ν_eff)·u.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from dense_oracle import (
    apply_A,
    beta_prior_var,
    normal_equations,
    solve_beta,
)

from chekan import joint
from chekan.classical.fit import calibrate_record
from chekan.fit import fit_map_em, initial_values, typea
from chekan.fit.map import _solve_pass
from chekan.fit.reported import map_derived
from chekan.joint import em
from chekan.joint.angles import AngleSensorSpec
from chekan.runtime.engine import engine_for
from inference.dof import coverage_factor


@pytest.fixture(scope="module")
def fitted(short_session):
    _, rec, _ = short_session
    cres, _ = calibrate_record(rec, settle_s=200)
    _, model = joint.prepare(rec, 200, angle_spec=AngleSensorSpec(3.0))
    fit = fit_map_em(model, initial_values(cres, rec.g_local_mgal))
    return fit, joint.problem_for(fit.model.structure)


@pytest.fixture(scope="module")
def joint_jacobian(fitted) -> np.ndarray:
    """∂R/∂(z, β) of the stacked rows at (ẑ, β̂) with the hyperparameters fixed: the
    Jacobian of the joint problem (bins × 2, β's prior rows, θ's prior rows)."""
    fit, prob = fitted
    model, h = fit.model, fit.hyper
    st, data = model.structure, model.data
    space = prob.map_space
    z = jnp.asarray(fit.result.z)

    def joint_rows(zb):
        zz, beta = zb[: space.size], zb[space.size :]
        v = space.to_values(zz)
        _, (_, G, s, r, _, nv, _, P) = normal_equations(v, h, st, data)
        res = jnp.where(data.mask, (r - apply_A(beta, G, s, st, data, P)) / jnp.sqrt(nv), 0.0)
        pv = beta_prior_var(h, st, data)
        return jnp.concatenate([res.reshape(-1), beta / jnp.sqrt(pv), space.prior_residuals(zz)])

    beta_hat = np.asarray(solve_beta(space.to_values(z), h, st, data)[1])
    return np.asarray(jax.jit(jax.jacfwd(joint_rows))(jnp.concatenate([z, beta_hat])))


def test_theta_terms_of_the_e_step_are_the_joint_laplace_posteriors(fitted, joint_jacobian):
    """diag Cov(β) and the bins' hat matrix of the joint (θ, β) problem, minus those of β
    given θ, are B C_θ Bᵀ and J_r C_θ J_rᵀ (hold offsets and angle errors; all bins)."""
    fit, prob = fitted
    model, h = fit.model, fit.hyper
    st, data = model.structure, model.data
    space = prob.map_space
    z = jnp.asarray(fit.result.z)
    var_beta, lev = (
        np.asarray(x) for x in jax.jit(lambda z, h: em.theta_terms(z, h, st, data, space))(z, h)
    )
    J = joint_jacobian
    C = np.linalg.inv(J.T @ J)
    q, N = space.size, st.n_bins
    Jb = J[:, q:]
    Minv = np.linalg.inv(Jb.T @ Jb)  # β given θ
    ix = np.concatenate([st.beta_blocks["angle_error"], st.beta_blocks["hold_offset"]])
    extra = np.diag(C[q:, q:])[ix] - np.diag(Minv)[ix]
    np.testing.assert_allclose(var_beta[ix], extra, rtol=0.05, atol=1e-3 * extra.max())
    Jd = J[: 2 * N]
    lev_joint = np.einsum("ni,ij,nj->n", Jd, C, Jd)
    lev_beta = np.einsum("ni,ij,nj->n", Jd[:, q:], Minv, Jd[:, q:])
    want = (lev_joint - lev_beta).reshape(N, 2)
    np.testing.assert_allclose(lev, want, rtol=0.05, atol=1e-3 * want.max())
    assert float(lev.sum()) > 1.0  # θ's 7 parameters take more than one bin's worth


def test_the_hat_of_the_type_a_terms_is_the_joint_problems(fitted, joint_jacobian):
    """The stacked rows' hat that the components' information rests on is the joint (θ, β)
    problem's, J(JᵀJ)⁻¹Jᵀ with the joint Jacobian from JAX: a projection. The sum of θ's and
    β's hats was not (the variable projection's J is not orthogonal to β's columns: an
    eigenvalue 1.6 on this record, which on a six-hold record made the information
    indefinite)."""
    fit, _ = fitted
    _, _, _, Minv, _, A_w, _, _, pv = _pieces(fit)
    dR = typea.beta_columns(fit, A_w, pv)
    U = typea.stacked_basis(fit, dR)
    hat = U @ U.T
    J = joint_jacobian
    want = J @ np.linalg.solve(J.T @ J, J.T)
    np.testing.assert_allclose(hat, want, atol=1e-8)
    np.testing.assert_allclose(hat @ hat, hat, atol=1e-8)
    assert np.trace(hat) == pytest.approx(J.shape[1])
    # β's columns are J's derivative in β, and the MAP's J is orthogonal to them
    q = fit.result.z.size
    np.testing.assert_allclose(dR, J[:, q:], rtol=1e-6, atol=1e-9 * np.abs(dR).max())
    Jt = np.asarray(fit.result.jacobian)
    scale = np.linalg.norm(Jt, axis=0).max() * np.linalg.norm(dR, axis=0).max()
    assert np.abs(Jt.T @ dR).max() < 1e-4 * scale
    # the former reading: β's data columns with the other sign, and a sum of two hats
    K = np.concatenate(
        [-dR[: 2 * fit.model.structure.n_bins], dR[2 * fit.model.structure.n_bins :]]
    )
    C = np.asarray(fit.result.cov_z)
    assert np.linalg.eigvalsh(K @ Minv @ K.T + Jt @ C @ Jt.T).max() > 1.1  # not a projection


def test_e_step_with_theta_terms_raises_the_variances_it_estimates(fitted):
    """At one θ and h, the E-step that integrates θ gives larger σ_θ and σ_o than the one
    given θ (it adds positive terms to the same moments)."""
    fit, prob = fitted
    model, h = fit.model, fit.hyper
    st, data = model.structure, model.data
    z = jnp.asarray(fit.result.z)
    space = prob.map_space
    plain = jax.jit(lambda z, h: em.em_update(space.to_values(z), h, st, data))(z, h)
    integrated = jax.jit(lambda z, h: em.em_update_theta(z, h, data, space=space, structure=st))(
        z, h
    )
    for k in ("sigma_theta_arcsec", "sigma_hold_pix"):
        assert float(integrated[k]) > float(plain[k]) * 1.001, k


def _pieces(fit):
    from chekan.jaxconfig import device_array

    out = engine_for(fit.model.structure).map_derived(
        device_array(fit.result.z), fit.hyper, fit.model.data, fit.model.duration_h
    )
    return [np.asarray(x) for x in out]


def test_shift_and_gradient_of_b1_are_finite_differences_of_the_map(fitted):
    fit, prob = fitted
    _, Jz, Jb, Minv, _, A_w, base, trans, pv = _pieces(fit)
    rel = typea.reliabilities(fit, Jz, Jb, Minv, A_w, base, trans, pv)[0]  # b1
    step = prob.map_space.step[0]
    keys = [
        ("noise_scale", 0),
        ("noise_scale", 1),
        ("slew_error", None),
        ("sigma_theta_arcsec", None),
        ("sigma_hold_pix", None),
    ]
    assert typea.COMPONENTS == (
        "noise_scale_1",
        "noise_scale_2",
        "slew_error",
        "sigma_theta",
        "sigma_hold",
    )
    eps = 0.02  # in log σ²
    for a, (k, j) in enumerate(keys):
        b, var = [], []
        for sign in (1, -1):
            h = {kk: jnp.asarray(vv) for kk, vv in fit.hyper.items()}
            f = np.exp(sign * eps / 2)
            h[k] = h[k] * f if j is None else h[k].at[j].multiply(f)
            res, _ = _solve_pass(prob.lsq, (fit.model.data, h), fit.result.z, "gn")
            b.append(float(res.values["b1"]))
            var.append(float(res.cov_z[0, 0]) * step**2)
        # to 2 %, or to 0.1 % of u (κ's, of little weight, is the least linear)
        tol = {"rel": 0.02, "abs": 1e-3 * np.sqrt(rel.u2)}
        assert rel.shift[a] == pytest.approx((b[0] - b[1]) / (2 * eps), **tol), k
        tol = {"rel": 0.02, "abs": 1e-3 * rel.u2}
        assert rel.gradient[a] == pytest.approx((var[0] - var[1]) / (2 * eps), **tol), k


def test_reported_sd_and_budget_carry_the_type_a_terms(fitted):
    """u² of the reliability is the Laplace variance; the reported sd adds uₕ²; the budget's
    U is t₉₅.₄₅(ν_eff)·u, its lines add up to u and include the hyperparameters' line."""
    fit, _ = fitted
    md = map_derived(fit)
    _, Jz, Jb, Minv, _, A_w, base, trans, pv = _pieces(fit)
    rel = typea.reliabilities(fit, Jz, Jb, Minv, A_w, base, trans, pv)
    laplace = fit.result.cov_z[0, 0] * fit.result.space.step[0] ** 2
    assert rel[0].u2 == pytest.approx(laplace, rel=1e-8)
    # every quantity's influences add up to its delta-method variance, also where it has a β
    # part (a, b₀, the drift slopes: with β's data rows of the other sign, 0.90 for a drift)
    C = np.where(np.isfinite(fit.result.cov_z), fit.result.cov_z, 0.0)
    var = np.einsum("ij,jk,ik->i", Jz, C, Jz) + np.einsum("ij,jk,ik->i", Jb, Minv, Jb)
    np.testing.assert_allclose([r.u2 for r in rel], var, rtol=1e-4)
    sd = md.values["b1"][1]
    assert sd**2 == pytest.approx(laplace + md.u_hyper["b1"] ** 2, rel=1e-10)
    assert 3 < md.nu_eff["b1"] < 1e4
    from chekan.fit.budget import uncertainty_budget
    from chekan.results.document import param_entry
    from chekan.results.entries import budget_entries

    raw = uncertainty_budget(fit)
    raw["b1"]["hyperparameters"] = md.u_hyper["b1"]
    params = {
        n: param_entry(md.values[n][0], md.values[n][1], 0.95, nu_eff=md.nu_eff[n])
        for n in ("b1", "b2")
    }
    bud = budget_entries(raw, params, md.nu_eff)["b1"]
    k = coverage_factor(md.nu_eff["b1"])
    assert k > 2.0
    assert bud["coverage_factor"] == k and bud["expanded"] == pytest.approx(k * sd, rel=1e-12)
    lines = [
        v for n, v in bud.items() if n not in ("total", "nu_eff", "coverage_factor", "expanded")
    ]
    assert np.sqrt(np.sum(np.square(lines))) == pytest.approx(sd, rel=1e-6)
    assert bud["hyperparameters"] > 0
    # the parameter's 95 % interval is Student's too
    e = params["b1"]
    assert e["hdi_high"] - e["mean"] == pytest.approx(coverage_factor(e["nu_eff"], 0.95) * sd)
