"""β̂'s derivative by the implicit function theorem (inference.normal_eq) equals the
derivative through the assembly and Cholesky factorisation it replaces, and the MAP
Jacobian of the joint model is unchanged by it."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from inference.normal_eq import NormalEquations, implicit_stationary_point, posterior_beta_normal


def _problem(p):
    """β̂(p) for y = A(p)β + e, prior β ~ N(0, diag(pv)), A and the noise depending on p."""
    rng = np.random.default_rng(3)
    A0, A1 = rng.normal(size=(2, 40, 6))
    y = rng.normal(size=40)
    pv = jnp.asarray(rng.uniform(0.5, 2.0, 6))

    def pieces(p):
        A = jnp.asarray(A0) + jnp.sin(p[0]) * jnp.asarray(A1)
        w = jnp.exp(p[1] * jnp.linspace(-1, 1, 40))  # noise weights depend on p too
        return A, w

    def direct(p):
        A, w = pieces(p)
        ne = NormalEquations(jnp.sum(w * y * y), A.T @ (w * y), A.T @ (w[:, None] * A), 0.0, 40)
        return posterior_beta_normal(ne, pv)

    def implicit(p):
        beta, L = jax.lax.stop_gradient(direct(p))
        A, w = pieces(p)

        def log_post(b):
            e = y - A @ b
            return -0.5 * (jnp.sum(w * e * e) + jnp.sum(b * b / pv))

        return implicit_stationary_point(beta, L, jax.grad(log_post))

    return direct, implicit


def test_value_is_unchanged_and_derivatives_equal_the_direct_ones():
    p = jnp.array([0.3, -0.2])
    direct, implicit = _problem(p)
    np.testing.assert_array_equal(np.asarray(implicit(p)), np.asarray(direct(p)[0]))
    fwd_d = jax.jacfwd(lambda q: direct(q)[0])(p)
    fwd_i = jax.jacfwd(implicit)(p)
    np.testing.assert_allclose(np.asarray(fwd_i), np.asarray(fwd_d), rtol=1e-10, atol=1e-12)
    rev_i = jax.jacrev(implicit)(p)  # reverse mode goes through the same rule
    np.testing.assert_allclose(np.asarray(rev_i), np.asarray(fwd_d), rtol=1e-10, atol=1e-12)
    # and both against central differences (the derivative is not merely self-consistent)
    h = 1e-6
    for k in range(2):
        e = jnp.zeros(2).at[k].set(h)
        fd = (direct(p + e)[0] - direct(p - e)[0]) / (2 * h)
        np.testing.assert_allclose(np.asarray(fwd_i[:, k]), np.asarray(fd), rtol=1e-6, atol=1e-8)


def test_map_jacobian_of_the_joint_model_is_unchanged(short_session, short_session_theta):
    """The projected residuals' Jacobian with the implicit β̂ derivative against the one
    through the normal equations' assembly and Cholesky (their derivative taken directly):
    the MAP's residual (by the hold blocks) against the dense oracle's."""
    import dense_oracle as lk

    from chekan.joint.angles import AngleSensorSpec
    from chekan.joint.beta_posterior import solve_beta
    from chekan.joint.binning import prepare

    _, model = prepare(short_session[1], 200, angle_spec=AngleSensorSpec(3.0))
    st, data = model.structure, model.data
    h = {  # slew error > 0: the noise weights depend on θ through the transients
        "noise_scale": jnp.asarray([1.3, 0.7]),
        "sigma_theta_arcsec": jnp.asarray(2.0),
        "sigma_hold_pix": jnp.asarray(0.08),
        "slew_error": jnp.asarray(0.02),
    }

    def through_factorisation(v):
        ne, (_, G, s, r, _, nv, _, P) = lk.normal_equations(v, h, st, data)
        beta, _ = posterior_beta_normal(ne, lk.beta_prior_var(h, st, data))
        sqrt_w = jnp.where(data.mask, 1.0 / jnp.sqrt(nv), 0.0)
        return (sqrt_w * (r - lk.apply_A(beta, G, s, st, data, P))).reshape(-1)

    def implicit(v):
        return solve_beta(v, h, st, data).rw

    v = short_session_theta
    j_ref = jax.jit(jax.jacfwd(through_factorisation))(v)
    j_new = jax.jit(jax.jacfwd(implicit))(v)
    scale = max(float(jnp.max(jnp.abs(j_ref[k]))) for k in v)
    for k in v:
        np.testing.assert_allclose(np.asarray(j_new[k]), np.asarray(j_ref[k]), atol=1e-9 * scale)


def test_map_jacobian_equals_central_differences(short_session, short_session_theta):
    """The projected residuals' Jacobian (first derivatives of β̂ and second derivatives of
    the equilibrium, through the angle sensitivity) against central differences, column
    by column. With the equilibrium's second derivatives inexact (0.3.7) the log K column
    was off by ≈ 3·10⁻⁴ of its size, and Gauss–Newton stopped off the optimum."""
    from chekan.joint.angles import AngleSensorSpec
    from chekan.joint.beta_posterior import solve_beta
    from chekan.joint.binning import prepare

    _, model = prepare(short_session[1], 200, angle_spec=AngleSensorSpec(3.0))
    st, data = model.structure, model.data
    h = {
        "noise_scale": jnp.asarray([1.3, 0.7]),
        "sigma_theta_arcsec": jnp.asarray(2.0),
        "sigma_hold_pix": jnp.asarray(0.08),
        "slew_error": jnp.asarray(0.02),
    }
    res = jax.jit(lambda v: solve_beta(v, h, st, data).rw)
    v = short_session_theta
    jac = jax.jit(jax.jacfwd(lambda v: solve_beta(v, h, st, data).rw))(v)
    for k, x in v.items():
        step = 1e-3 * max(abs(float(x)), 0.1)  # fourth-order stencil: truncation ≈ 1e-12

        def at(n, k=k, x=x, step=step):
            return np.asarray(res({**v, k: x + n * step}))

        fd = (8 * (at(1) - at(-1)) - (at(2) - at(-2))) / (12 * step)
        col = np.asarray(jac[k])
        np.testing.assert_allclose(col, fd, atol=1e-6 * np.abs(col).max(), err_msg=k)
