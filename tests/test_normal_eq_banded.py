"""Block elimination of the normal equations (inference.normal_eq.banded_factor) against the
dense Cholesky: a random block-tridiagonal + dense matrix, and the joint model's M on a
record of the paper's program and on one with rounds about both axes."""

import dense_oracle as cm
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chekan import joint
from inference.normal_eq import (
    NormalEquations,
    banded_factor,
    draw_beta_banded,
    marginal_loglik_banded,
    marginal_loglik_normal,
    posterior_beta_normal,
    solve_banded,
    solve_banded_transposed,
)
from inference.selected_inverse import selected_inverse


def _random_problem(H=7, k=3, m=5, seed=0):
    """M = P⁻¹ + G with G block-tridiagonal in the interleaved ``bands`` and dense elsewhere."""
    rng = np.random.default_rng(seed)
    p = H * k + m
    perm = rng.permutation(p)  # the bands scattered over β's layout
    bands, dense = perm[: H * k].reshape(H, k), perm[H * k :]
    A = np.zeros((p, p))
    for i in range(H):
        for j in (i - 1, i):
            if j >= 0:
                A[np.ix_(bands[i], bands[j])] = rng.standard_normal((k, k))
        A[np.ix_(dense, bands[i])] = rng.standard_normal((m, k))
    A[np.ix_(dense, dense)] = rng.standard_normal((m, m))
    G = A @ A.T  # band rows of A reach their own and the previous block: tridiagonal
    prior_var = rng.uniform(0.5, 2.0, p)
    ne = NormalEquations(
        jnp.asarray(3.0), jnp.asarray(rng.standard_normal(p)), jnp.asarray(G), jnp.asarray(1.5), 40
    )
    return ne, jnp.asarray(prior_var), bands


def test_selected_inverse_and_solve_equal_the_dense_inverse():
    """The entries of M⁻¹ on M's pattern (diagonal and sub-diagonal hold blocks, their rows
    against the dense variables, the dense block) and M⁻¹U equal the dense inverse's."""
    ne, pv, bands = _random_problem(H=9, k=3, m=6, seed=4)
    Z = np.linalg.inv(np.asarray(ne.G) + np.diag(1.0 / np.asarray(pv)))
    dense = np.setdiff1d(np.arange(Z.shape[0]), bands.reshape(-1))
    f = banded_factor(ne, pv, bands)
    s = selected_inverse(f)
    scale = np.max(np.abs(Z))
    for i in range(len(bands)):
        np.testing.assert_allclose(s.diag[i], Z[np.ix_(bands[i], bands[i])], atol=1e-13 * scale)
        np.testing.assert_allclose(s.cross[i], Z[np.ix_(bands[i], dense)], atol=1e-13 * scale)
        if i:
            want = Z[np.ix_(bands[i], bands[i - 1])]
            np.testing.assert_allclose(s.sub[i], want, atol=1e-13 * scale)
    assert np.all(np.asarray(s.sub[0]) == 0)
    np.testing.assert_allclose(s.dense, Z[np.ix_(dense, dense)], atol=1e-13 * scale)
    U = np.random.default_rng(5).standard_normal((Z.shape[0], 4))
    np.testing.assert_allclose(solve_banded(f, bands, jnp.asarray(U)), Z @ U, atol=1e-12 * scale)


def test_banded_equals_dense_on_a_random_structure():
    ne, pv, bands = _random_problem()
    G = np.asarray(ne.G)
    assert all(
        np.all(G[np.ix_(bands[i], bands[j])] == 0)
        for i in range(len(bands))
        for j in range(len(bands))
        if abs(i - j) > 1
    )
    assert float(marginal_loglik_banded(ne, pv, bands)) == pytest.approx(
        float(marginal_loglik_normal(ne, pv)), rel=1e-13
    )
    # β | y: the mean (ξ = 0) and the covariance L⁻ᵀL⁻¹ = M⁻¹
    mean, _ = posterior_beta_normal(ne, pv)
    f = banded_factor(ne, pv, bands)
    u = jnp.concatenate([f.y, f.c])
    np.testing.assert_allclose(solve_banded_transposed(f, bands, u), mean, rtol=1e-11, atol=1e-12)
    p = u.size
    X = np.asarray(jax.vmap(lambda e: solve_banded_transposed(f, bands, e))(jnp.eye(p)))
    Minv = np.linalg.inv(np.asarray(ne.G) + np.diag(1 / np.asarray(pv)))
    np.testing.assert_allclose(X.T @ X, Minv, rtol=1e-9, atol=1e-12)
    draws = jax.vmap(lambda k: draw_beta_banded(k, ne, pv, bands))(
        jax.random.split(jax.random.PRNGKey(0), 4000)
    )
    z = (np.asarray(draws).mean(axis=0) - np.asarray(mean)) / np.sqrt(np.diag(Minv) / 4000)
    assert np.max(np.abs(z)) < 4.5


@pytest.fixture(scope="module")
def dual_axis_record():
    """Two rounds about Y and X (300 s dwells): a record with the X-response terms."""
    from chekan.physics.program import build_program
    from chekan.records.simulate import Truth, simulate_session

    prog = build_program([4.5, 5.0], axis="xy", rounds=2, dwell_s=300, settle_s=120)
    return simulate_session(prog, Truth(), seed=3)[0]


@pytest.mark.parametrize("record", ["short", "dual"])
def test_model_normal_equations_are_banded_and_agree(short_session, dual_axis_record, record):
    """M couples each hold's (o₁, o₂, δ) only with its neighbours, and the log-density by
    block elimination equals the dense one (to round-off) at points around the prior's
    centre, on a record of the paper's angles and on one about both axes."""
    from chekan.joint.angles import AngleSensorSpec

    rec = short_session[1] if record == "short" else dual_axis_record
    spec = AngleSensorSpec(3.0)
    _, model = joint.prepare(rec, None, angle_spec=spec, angle_spec_x=spec)
    prob = joint.problem_for(model.structure)
    bands = model.structure.hold_bands
    space = prob.bayes_space
    rng = np.random.default_rng(1)
    z0 = np.asarray(space.to_z(space.to_values(np.zeros(space.size))))

    @jax.jit
    def parts(z, data):
        v = space.to_values(z)
        ne, _ = cm.normal_equations(v, v, model.structure, data)
        return ne, cm.beta_prior_var(v, model.structure, data), prob.log_density(z, data)

    for z in z0 + 0.3 * rng.standard_normal((2, space.size)):
        ne, pv, logp = parts(jnp.asarray(z), model.data)
        G = np.asarray(ne.G)
        H = len(bands)
        off = max(
            np.abs(G[np.ix_(bands[i], bands[j])]).max()
            for i in range(H)
            for j in range(H)
            if abs(i - j) > 1
        )
        assert off == 0.0
        dense = float(marginal_loglik_normal(ne, pv))
        assert float(marginal_loglik_banded(ne, pv, bands)) == pytest.approx(dense, rel=1e-12)
        assert float(logp) == pytest.approx(
            dense + float(space.log_prior(jnp.asarray(z))), rel=1e-12
        )
