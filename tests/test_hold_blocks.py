"""The normal equations assembled straight into the hold blocks
(:mod:`chekan.joint.hold_blocks`, β | θ: :mod:`chekan.joint.beta_posterior`) against the
dense assembly (the oracle, ``tests/dense_oracle.py``, which no production code imports):
the blocks gathered from the dense M, the MAP's residual, its Jacobian and M⁻¹, the
log-density, A·β and the β draws, to round-off, on a record of the paper's angles (padded
and not) and on one with rounds about both axes (X-response terms); marked slow, on the
paper's full 9 h program and the bench's dual-axis record (160 holds)."""

from __future__ import annotations

import dense_oracle as cm
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chekan import joint
from chekan.joint import beta_posterior as bp
from chekan.joint import hold_blocks as hb
from inference.normal_eq import (
    banded_factor_blocks,
    blocks_of,
    draw_beta_banded,
    draw_beta_blocks,
    marginal_loglik_normal,
    posterior_beta_normal,
    solve_banded_transposed,
    split_prior,
)


@pytest.fixture(scope="module")
def dual_axis_record():
    """Two rounds about Y and X (300 s dwells): a record with the X-response terms."""
    from chekan.physics.program import build_program
    from chekan.records.simulate import Truth, simulate_session

    prog = build_program([4.5, 5.0], axis="xy", rounds=2, dwell_s=300, settle_s=120)
    return simulate_session(prog, Truth(), seed=3)[0]


def _full_record(record: str):
    """The paper's 9 h program or the bench's dual-axis record (160 holds, p 558)."""
    from bench.several_records import dual_axis_program
    from chekan.demo import demo_program
    from chekan.records.simulate import Truth, simulate_session

    prog = demo_program(False) if record == "paper-9h" else dual_axis_program(False)
    return simulate_session(prog, Truth(), seed=3)[0]


def _model(short_session, dual_axis_record, record: str):
    from chekan.joint.angles import AngleSensorSpec

    if record in ("paper-9h", "bench-xy"):
        rec = _full_record(record)
    else:
        rec = dual_axis_record if record == "dual" else short_session[1]
    spec = AngleSensorSpec(3.0)
    _, model = joint.prepare(rec, None, angle_spec=spec, angle_spec_x=spec)
    if record == "padded":
        model = model.pad(model.n_holds + 2, model.n_bins + 7, model.structure.n_moves + 3)
    return model


def _rel(x, y) -> float:
    x, y = np.asarray(x), np.asarray(y)
    return float(np.max(np.abs(x - y)) / max(np.max(np.abs(y)), 1e-300)) if y.size else 0.0


@pytest.mark.parametrize(
    "record",
    [
        "short",
        "padded",
        "dual",
        pytest.param("paper-9h", marks=pytest.mark.slow),
        pytest.param("bench-xy", marks=pytest.mark.slow),
    ],
)
def test_hold_blocks_equal_the_dense_normal_equations(short_session, dual_axis_record, record):
    """Every block (holds' diagonal and sub-diagonal, their rows against the dense
    variables, the dense block, both right-hand sides, rᵀWr, log|N|, n) equals the one
    gathered from the dense M to round-off; the log-density equals the dense Cholesky's,
    A·β equals the dense oracle's ``apply_A``, and a β draw equals the one made
    from the dense M's blocks with the same key (the same factor to round-off)."""
    model = _model(short_session, dual_axis_record, record)
    st, data = model.structure, model.data
    if record == "dual":
        assert st.n_x_response > 0 and st.n_systematic > 0
    prob = joint.problem_for(st)
    space = prob.bayes_space
    bands = st.hold_bands

    @jax.jit
    def parts(z, beta, key, data):
        v = space.to_values(z)
        ne, (_, G, s, _, _, _, _, P) = cm.normal_equations(v, v, st, data)
        blocks, t = hb.block_normal_equations(v, v, st, data)
        pv = cm.beta_prior_var(v, st, data)
        return (
            ne,
            blocks,
            pv,
            prob.log_density(z, data),
            cm.apply_A(beta, G, s, st, data, P),
            hb.apply_blocks(beta, t, st, data),
            draw_beta_banded(key, ne, pv, bands),
            draw_beta_blocks(key, blocks, *split_prior(pv, bands), bands),
        )

    rng = np.random.default_rng(1)
    z0 = np.asarray(space.to_z(space.to_values(np.zeros(space.size))))
    for i, z in enumerate(z0 + 0.3 * rng.standard_normal((2, space.size))):
        beta = jnp.asarray(rng.standard_normal(st.n_beta))
        key = jax.random.PRNGKey(i)
        ne, blocks, pv, logp, yA, yB, d_ref, d_new = parts(jnp.asarray(z), beta, key, data)
        want = blocks_of(ne, bands)
        for name, got, ref in zip(want._fields, blocks, want, strict=True):
            if name == "sub":  # block 0 (before the first hold) is unused
                got, ref = got[1:], ref[1:]
            assert _rel(got, ref) < 1e-13, name
        dense = float(marginal_loglik_normal(ne, pv)) + float(space.log_prior(jnp.asarray(z)))
        assert float(logp) == pytest.approx(dense, rel=1e-12)
        seen = np.asarray(data.mask)  # padding bins (no data, no weight) read by no one
        np.testing.assert_allclose(
            np.asarray(yB)[seen], np.asarray(yA)[seen], rtol=1e-11, atol=1e-11
        )
        np.testing.assert_allclose(np.asarray(d_new), np.asarray(d_ref), rtol=1e-8, atol=1e-10)
        # the β mean (ξ = 0) from the blocks equals the dense solve
        f = banded_factor_blocks(blocks, *split_prior(pv, bands))
        mean = solve_banded_transposed(f, bands, jnp.concatenate([f.y, f.c]))
        ref_mean, _ = posterior_beta_normal(ne, pv)
        np.testing.assert_allclose(np.asarray(mean), np.asarray(ref_mean), rtol=1e-8, atol=1e-10)


def test_unsettled_carry_by_scan_equals_the_product_matrix():
    """The associative scan of the carry recurrence equals the cumulative-product form of
    the dense oracle's ``_unsettled_carry``."""
    rng = np.random.default_rng(2)
    H, J = 37, 5
    E, Mv = jnp.asarray(rng.standard_normal((H, J))), jnp.asarray(rng.standard_normal((H, J)))
    wprev, rho = jnp.asarray(rng.uniform(0, 1, H)), jnp.asarray(rng.uniform(0, 1, H))
    np.testing.assert_allclose(
        np.asarray(hb.unsettled_carry(E, Mv, wprev, rho)),
        np.asarray(cm._unsettled_carry(E, Mv, wprev, rho)),
        rtol=1e-12,
        atol=1e-14,
    )


def test_log_density_gradient_equals_the_dense_assemblys(dual_axis_record):
    """The gradient of the log-density (NUTS, a gradient mode search) through the hold
    blocks equals the one through the dense M's blocks, to round-off."""
    from inference.normal_eq import marginal_loglik_banded

    model = _model(None, dual_axis_record, "dual")
    st, data = model.structure, model.data
    prob = joint.problem_for(st)
    space = prob.bayes_space

    def dense(z, data):
        v = space.to_values(z)
        ne, _ = cm.normal_equations(v, v, st, data)
        ll = marginal_loglik_banded(ne, cm.beta_prior_var(v, st, data), st.hold_bands)
        return space.log_prior(z) + ll

    z0 = np.asarray(space.to_z(space.to_values(np.zeros(space.size))))
    z = jnp.asarray(z0 + 0.1 * np.random.default_rng(2).standard_normal(space.size))
    got = np.asarray(jax.jit(jax.grad(prob.log_density))(z, data))
    want = np.asarray(jax.jit(jax.grad(dense))(z, data))
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())


@pytest.mark.parametrize("record", ["short", "padded", "dual"])
def test_e_step_moments_from_the_blocks_equal_the_dense_inverse(
    short_session, dual_axis_record, record
):
    """What the EM's E-step reads (:func:`chekan.joint.beta_posterior.block_moments`): β̂, the
    variances diag(M⁻¹), the whitened residuals and the bins' leverages (Ã M⁻¹ Ãᵀ)ᵢᵢ equal
    those of the dense M and its inverse; the design's rows by their support
    (:func:`~chekan.joint.beta_posterior.bin_rows`) hold every non-zero of the dense design."""
    model = _model(short_session, dual_axis_record, record)
    st, data = model.structure, model.data
    prob = joint.problem_for(st)
    space = prob.bayes_space

    @jax.jit
    def parts(z, data):
        v = space.to_values(z)
        ne, (_, G, s, r, _, nv, _, P) = cm.normal_equations(v, v, st, data)
        A = cm.dense_design(G, s, st, data, P)
        return ne, cm.beta_prior_var(v, st, data), A, r, nv, bp.block_moments(v, v, st, data)

    z0 = np.asarray(space.to_z(space.to_values(np.zeros(space.size))))
    z = z0 + 0.3 * np.random.default_rng(3).standard_normal(space.size)
    ne, pv, A, r, nv, m = parts(jnp.asarray(z), data)
    Z = np.linalg.inv(np.asarray(ne.G) + np.diag(1.0 / np.asarray(pv)))
    beta = Z @ np.asarray(ne.g)
    mask = np.asarray(data.mask)
    sw = np.where(mask, 1.0 / np.sqrt(np.asarray(nv)), 0.0)
    At = np.asarray(A) * sw[..., None]
    lev = np.einsum("njp,pq,njq->nj", At, Z, At)
    rw = sw * (np.asarray(r) - np.einsum("njp,p->nj", np.asarray(A), beta))
    np.testing.assert_allclose(m.beta, beta, rtol=1e-9, atol=1e-10 * np.abs(beta).max())
    np.testing.assert_allclose(m.var, np.diag(Z), rtol=1e-9)
    np.testing.assert_allclose(m.rw, rw, atol=1e-9 * np.abs(rw).max())
    np.testing.assert_allclose(m.lev, lev, rtol=1e-9, atol=1e-12)
    # the rows' support holds all of the design: scattered back, they are At itself
    back = np.zeros_like(At)
    cols, vals = np.asarray(m.rows.columns), np.asarray(m.rows.values)
    for n in np.flatnonzero(mask.any(axis=1)):
        np.add.at(back[n], (slice(None), cols[n]), vals[n])
    np.testing.assert_allclose(back, At, atol=1e-12 * np.abs(At).max())


@pytest.mark.parametrize("record", ["short", "padded", "dual"])
def test_map_residual_and_derived_inputs_from_the_blocks_equal_the_dense(
    short_session, dual_axis_record, record
):
    """The MAP's projected residual (:func:`chekan.joint.beta_posterior.solve_beta`) and its
    Jacobian in θ, β̂, log|M| and the quadratic form gᵀM⁻¹g from the block factor, M⁻¹ and
    the whitened design that :func:`chekan.joint.derived.map_derived_fn` hands on, against
    the dense oracle's assembly and Cholesky, at hyperparameters whose noise depends on θ
    (slew error > 0)."""
    model = _model(short_session, dual_axis_record, record)
    st, data = model.structure, model.data
    space = joint.problem_for(st).map_space
    h = joint.default_hyper(noise_scale=(1.3, 0.7), sigma_hold_pix=0.08, slew_error=0.02)

    @jax.jit
    def parts(z, data):
        v = space.to_values(z)
        sol = bp.solve_beta(v, h, st, data)
        rw_d, beta_d, L = cm.solve_beta(v, h, st, data)
        ne, (_, G, s, _, _, nv, _, P) = cm.normal_equations(v, h, st, data)
        sw = jnp.where(data.mask, 1.0 / jnp.sqrt(nv), 0.0)
        A_w = cm.dense_design(G, s, st, data, P) * sw[..., None]
        jac = jax.jacfwd(lambda zz: bp.solve_beta(space.to_values(zz), h, st, data).rw)(z)
        jac_d = jax.jacfwd(lambda zz: cm.solve_beta(space.to_values(zz), h, st, data)[0])(z)
        Linv = jax.scipy.linalg.solve_triangular(L, jnp.eye(L.shape[0]), lower=True)
        A_b = bp.dense_rows(bp.bin_rows(sol.terms, st, data), st.n_beta) * sw[..., None]
        return (
            (sol.rw, rw_d),
            (sol.beta, beta_d),
            (jac, jac_d),
            (bp.posterior_cov(sol.factor, st), Linv.T @ Linv),
            (A_b, A_w),
            (sol.factor, L, ne.g),
        )

    z0 = np.asarray(space.to_z(space.to_values(np.zeros(space.size))))
    for z in z0 + 0.3 * np.random.default_rng(4).standard_normal((2, space.size)):
        rw, beta, jac, minv, aw, (f, L, g) = parts(jnp.asarray(z), data)
        for name, (got, want), tol in (
            ("rw", rw, 1e-9),
            ("beta", beta, 1e-9),
            ("jacobian", jac, 1e-8),
            ("M⁻¹", minv, 1e-9),
            ("A_w", aw, 1e-12),
        ):
            assert _rel(got, want) < tol, name
        logdet_blocks = 2.0 * float(
            np.sum(np.log(np.diagonal(np.asarray(f.diag), axis1=1, axis2=2)))
            + np.sum(np.log(np.diagonal(np.asarray(f.L_S))))
        )
        logdet_dense = 2.0 * float(np.sum(np.log(np.diagonal(np.asarray(L)))))
        assert logdet_blocks == pytest.approx(logdet_dense, rel=1e-12)
        quad_blocks = float(np.sum(np.asarray(f.y) ** 2) + np.sum(np.asarray(f.c) ** 2))
        quad_dense = float(np.asarray(g) @ np.asarray(beta[1]))
        assert quad_blocks == pytest.approx(quad_dense, rel=1e-10)


def test_no_production_code_imports_the_dense_oracle():
    """The dense assembly is the tests' oracle only: nothing in the package, the inference
    library or the bench imports it, and the model forms neither a dense design nor dense
    normal equations (nor solves them: ``posterior_beta_normal``, ``marginal_loglik_normal``)."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    for folder in ("chekan", "inference", "hw", "bench"):
        for path in (root / folder).rglob("*.py"):
            text = path.read_text(encoding="utf-8")
            assert "dense_oracle" not in text.replace("tests/dense_oracle.py", ""), path
            if folder != "chekan":
                continue
            for name in ("normal_equations(", "dense_design(", "NormalEquations(", "_normal("):
                assert f" {name}" not in text and f".{name}" not in text, (path, name)
