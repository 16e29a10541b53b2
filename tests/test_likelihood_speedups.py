"""The 0.3.2 evaluation changes give the same model: the unsettled carry in closed form
against its recurrence, the shared slew path against separate evaluations, and MAP passes
that go straight to Levenberg–Marquardt once Gauss–Newton has failed on a record."""

from __future__ import annotations

import dense_oracle as lk
import jax.numpy as jnp
import numpy as np

from chekan.fit import map as jmap


def _carry_by_recurrence(E, Mv, wprev, rho):
    """Rₖ by the recurrence of the docstring, step by step (the 0.3.1 scan)."""
    y0, R = E[0].copy(), [np.zeros(E.shape[1])]
    for k in range(1, E.shape[0]):
        y0 = wprev[k] * (E[k - 1] + (y0 - E[k - 1]) * rho[k - 1]) + Mv[k]
        R.append(y0 - wprev[k] * E[k - 1] - Mv[k])
    return np.array(R)


def test_closed_form_carry_equals_the_recurrence():
    rng = np.random.default_rng(7)
    for H, rho_max in ((1, 0.5), (2, 0.9), (11, 0.95), (36, 1e-9)):
        E = rng.normal(size=(H, 2)) * 30.0
        Mv = rng.normal(size=(H, 2))
        wprev = rng.uniform(0.0, 1.0, H)
        rho = rng.uniform(0.0, rho_max, H)
        want = _carry_by_recurrence(E, Mv, wprev, rho)
        got = np.asarray(lk._unsettled_carry(*map(jnp.asarray, (E, Mv, wprev, rho))))
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(E).max())
        np.testing.assert_array_equal(got[0], 0.0)


def _values_and_data(short_session, theta):
    from chekan.joint.binning import prepare

    _, model = prepare(short_session[1], None)
    return theta, model.data


def test_shared_slew_path_equals_separate_evaluations(short_session, short_session_theta):
    """E along the slews from the forward-mode pass equals the plain evaluation, and the
    pieces built from one shared pass equal those built on their own."""
    from chekan.physics import sensor as fm

    v, data = _values_and_data(short_session, short_session_theta)
    path = lk.slew_path(v, data)
    plain = fm.equilibrium_readings(lk.sensor_params(v, data), data.mv_tx, data.mv_ty)
    # to rounding: the forward-mode pass runs op by op here, the plain one fused (FMA)
    np.testing.assert_allclose(np.moveaxis(np.asarray(path.readings), 0, -1), plain, rtol=2e-15)
    for a, b in zip(lk.linear_terms(v, data, path), lk.linear_terms(v, data), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(
        np.asarray(lk.slew_angle_columns(v, data, path)),
        np.asarray(lk.slew_angle_columns(v, data)),
    )


class _Result:
    def __init__(self, converged: bool):
        self.converged = converged


def test_a_record_gauss_newton_failed_on_goes_straight_to_lm(monkeypatch):
    """GN converges: the pass keeps GN. GN fails: LM redoes the pass, and the next pass
    of that record is solved by LM only (the MAP of one record, issue 28)."""
    calls: list[tuple[str, object]] = []

    def fake_solve(lsq, args, z, solver):
        calls.append((solver, args))
        return _Result(solver == "lm" or args != "hard")

    monkeypatch.setattr(jmap, "_solve", fake_solve)
    res, after = jmap._solve_pass(None, "easy", None, "gn")
    assert calls == [("gn", "easy")] and after == "gn" and res.converged
    calls.clear()
    res, after = jmap._solve_pass(None, "hard", None, "gn")
    assert calls == [("gn", "hard"), ("lm", "hard")] and after == "lm" and res.converged
    calls.clear()
    jmap._solve_pass(None, "hard", None, after)
    assert calls == [("lm", "hard")]
