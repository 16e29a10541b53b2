"""inference.dof against closed forms: the REML information of variance components, ν_eff
(the mean of n observations: n − 1; Welch's two means; a balanced one-way random-effects
mean: groups − 1), the shift of an estimate with its variances, and Student's k."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from inference.dof import (
    coverage_factor,
    log_var_cov,
    t_two_sided,
    type_a_reliability,
)


def _hat(J: np.ndarray) -> np.ndarray:
    return J @ np.linalg.solve(J.T @ J, J.T)


def _influence(J: np.ndarray, q: np.ndarray) -> np.ndarray:
    return q @ np.linalg.solve(J.T @ J, J.T)


def test_mean_of_n_observations_has_n_minus_one_degrees_of_freedom():
    """y ~ N(μ, σ²), μ flat: u² = σ²/n, and u rests on σ̂ with n − 1 degrees of freedom
    (REML); the mean does not move with σ (uₕ = 0)."""
    rng = np.random.default_rng(1)
    for n in (3, 7, 40):
        sigma = 0.7
        y = rng.normal(2.0, sigma, n)
        J = np.full((n, 1), 1.0 / sigma)  # whitened rows
        R = (y - y.mean()) / sigma
        rel = type_a_reliability(_influence(J, np.ones(1)), R, _hat(J), np.ones((1, n)))
        assert rel.u2 == pytest.approx(sigma**2 / n, rel=1e-12)
        assert rel.nu_eff == pytest.approx(n - 1, rel=1e-9)
        assert rel.u2_components == pytest.approx(0.0, abs=1e-20)
        # V of log σ̂²: 2/(n − 1)
        assert rel.cov_log_var[0, 0] == pytest.approx(2.0 / (n - 1), rel=1e-9)


def test_difference_of_two_means_is_welch_satterthwaite():
    """μ₁ − μ₂ from groups of n₁, n₂ with their own variances: Welch's ν."""
    n1, n2, s1, s2 = 5, 12, 1.3, 0.4
    n = n1 + n2
    J = np.zeros((n, 2))
    J[:n1, 0] = 1 / s1
    J[n1:, 1] = 1 / s2
    D = np.zeros((2, n))
    D[0, :n1] = 1.0
    D[1, n1:] = 1.0
    rng = np.random.default_rng(2)
    R = rng.normal(size=n)
    R[:n1] -= R[:n1].mean()
    R[n1:] -= R[n1:].mean()
    rel = type_a_reliability(_influence(J, np.array([1.0, -1.0])), R, _hat(J), D)
    u1, u2 = s1**2 / n1, s2**2 / n2
    welch = (u1 + u2) ** 2 / (u1**2 / (n1 - 1) + u2**2 / (n2 - 1))
    assert rel.u2 == pytest.approx(u1 + u2, rel=1e-12)
    assert rel.nu_eff == pytest.approx(welch, rel=1e-9)


def test_one_way_random_effects_information_and_groups_minus_one():
    """yᵢⱼ = μ + aᵢ + eᵢⱼ, m groups of n, a ~ N(0, σₐ²), e ~ N(0, σ²), μ flat. REML: the
    between mean square (m − 1 dof) estimates λ = σ² + nσₐ², the within one (m(n − 1))
    σ²; the information of (log σ², log σₐ²) follows, and var(ȳ) = λ/(mn) has m − 1
    degrees of freedom."""
    m, n, s, sa = 6, 4, 0.5, 0.8
    rows = m * n + m  # data rows, then the prior rows of the aᵢ
    J = np.zeros((rows, 1 + m))
    for i in range(m):
        J[i * n : (i + 1) * n, 0] = 1 / s
        J[i * n : (i + 1) * n, 1 + i] = 1 / s
        J[m * n + i, 1 + i] = 1 / sa
    D = np.zeros((2, rows))
    D[0, : m * n] = 1.0
    D[1, m * n :] = 1.0
    lam = s**2 + n * sa**2
    w = np.array([s**2 / lam, n * sa**2 / lam])  # ∂log λ/∂(log σ², log σₐ²)
    want = 0.5 * (m - 1) * np.outer(w, w) + 0.5 * m * (n - 1) * np.diag([1.0, 0.0])
    V = log_var_cov(_hat(J), D)
    np.testing.assert_allclose(np.linalg.inv(V), want, rtol=1e-10)
    q = np.zeros(1 + m)
    q[0] = 1.0
    rel = type_a_reliability(_influence(J, q), np.zeros(rows), _hat(J), D)
    assert rel.u2 == pytest.approx(lam / (m * n), rel=1e-10)
    assert rel.nu_eff == pytest.approx(m - 1, rel=1e-9)


def test_shift_is_the_derivative_of_the_estimate_with_its_variances():
    """d = ∂q̂/∂log σₐ² and g = ∂u²/∂log σₐ² against finite differences of the weighted
    least squares (two noise groups, a line fitted)."""
    rng = np.random.default_rng(3)
    x = np.linspace(-1, 1, 30)
    grp = (np.arange(30) % 3 == 0).astype(int)
    sig = np.array([0.3, 1.1])
    y = 1.0 + 2.0 * x + rng.normal(size=30) * sig[grp]

    def solve(log_var):
        sd = np.exp(0.5 * np.asarray(log_var))[grp]
        X = np.stack([np.ones(30), x], axis=1) / sd[:, None]
        cov = np.linalg.inv(X.T @ X)
        return cov @ X.T @ (y / sd), cov, X

    lv = 2 * np.log(sig)
    beta, _, X = solve(lv)
    R = X @ beta - y / np.exp(0.5 * lv)[grp]  # the residual whose Jacobian is X
    D = np.stack([(grp == 0).astype(float), (grp == 1).astype(float)])
    rel = type_a_reliability(_influence(X, np.array([0.0, 1.0])), R, _hat(X), D)
    for a in range(2):
        e = np.zeros(2)
        e[a] = 1e-6
        bp, cp, _ = solve(lv + e)
        bm, cm, _ = solve(lv - e)
        assert rel.shift[a] == pytest.approx((bp[1] - bm[1]) / 2e-6, rel=1e-6)
        assert rel.gradient[a] == pytest.approx((cp[1, 1] - cm[1, 1]) / 2e-6, rel=1e-6)
    assert rel.u2_components > 0


@pytest.mark.parametrize("nu", [1, 2, 3, 5, 10, 30, 999, 2000, 2001, 10**5])
@pytest.mark.parametrize("p", [0.5, 0.9545, 0.99])
def test_student_quantile(nu, p):
    assert t_two_sided(nu, p) == pytest.approx(stats.t.ppf(0.5 + p / 2, nu), rel=1e-9)


def test_coverage_factor_is_ea_4_02s_table():
    """EA-4/02 M: 2022 table E.1 (k for 95.45 %), ν truncated to an integer."""
    table = {1: 13.97, 2: 4.53, 3: 3.31, 4: 2.87, 5: 2.65, 10: 2.28, 20: 2.13, 50: 2.05}
    for nu, k in table.items():
        assert round(coverage_factor(nu + 0.9), 2) == k
    assert coverage_factor(np.inf) == pytest.approx(2.0, abs=1e-4)
    # below one degree of freedom GUM's truncation leaves none: no finite k
    assert coverage_factor(0.5) == math.inf
    for bad in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError):
            coverage_factor(bad)


def test_an_indefinite_information_gives_a_covariance_not_a_negative_variance():
    """A 'hat' that is not a projection (the sum of θ's and β's hats that typea once used, on
    a record that barely determines its parameters, had an eigenvalue 1.59) made the
    components' information
    indefinite, its inverse no covariance, and uₕ² = dᵀVd negative: a six-hold record of the
    designer's stated sd(b₁) = 0. V is now the inverse of the information's positive part,
    and the reliability says so."""
    from inference.dof import component_information, indefinite

    rng = np.random.default_rng(13)
    n = 8
    A = rng.normal(size=(n, n))
    hat = 0.3 * (A + A.T)  # symmetric, eigenvalues well above 1: not a projection
    shares = np.abs(rng.normal(size=(2, n)))
    assert indefinite(np.linalg.eigvalsh(component_information(hat, shares)))
    V = log_var_cov(hat, shares)
    assert np.linalg.eigvalsh(V).min() >= -1e-12 * np.abs(V).max()
    d = rng.normal(size=n)
    r = type_a_reliability(d, rng.normal(size=n), hat, shares, cov_log_var=V, clipped=True)
    assert r.u2_components >= 0.0 and r.clipped
    # a proper information is inverted as before
    B = rng.normal(size=(n, 3))
    H = B @ np.linalg.pinv(B)
    info = component_information(H, shares)
    assert not indefinite(np.linalg.eigvalsh(info))
    assert np.array_equal(log_var_cov(H, shares), np.linalg.pinv(info, hermitian=True))


def test_projection_hat_is_the_least_squares_hat_also_when_rank_deficient():
    from inference.dof import projection_hat

    rng = np.random.default_rng(5)
    B = rng.normal(size=(20, 4))
    H = projection_hat(B)
    np.testing.assert_allclose(H, B @ np.linalg.solve(B.T @ B, B.T), atol=1e-12)
    # a repeated column adds nothing: still the projector onto the same span (rank 4)
    Hd = projection_hat(np.concatenate([B, B[:, :1] * 3.0], axis=1))
    np.testing.assert_allclose(Hd, H, atol=1e-12)
    np.testing.assert_allclose(Hd @ Hd, Hd, atol=1e-12)
    assert np.trace(Hd) == pytest.approx(4.0)
    # two hats whose spans are not orthogonal do not add up to a projection
    C = B[:, :2] + 0.5 * rng.normal(size=(20, 2))
    summed = projection_hat(B[:, :2]) + projection_hat(C)
    assert np.linalg.eigvalsh(summed).max() > 1.0 + 1e-6
    assert projection_hat(np.zeros((5, 2))).shape == (5, 5)
    assert not projection_hat(np.zeros((5, 2))).any()


def test_the_information_from_the_basis_equals_the_one_from_the_hat():
    """basis_information(U, D) = component_information(U Uᵀ, D) (the identity in its
    docstring), with shares that touch some rows only and a rank-deficient basis; and the
    pivoted QR's basis spans what the SVD's did."""
    from inference.dof import basis_information, component_information, projection_basis

    rng = np.random.default_rng(21)
    B = rng.normal(size=(60, 7))
    B = np.concatenate([B, B[:, :2] @ np.array([[2.0], [-1.0]])], axis=1)  # rank 7
    U = projection_basis(B)
    assert U.shape == (60, 7)
    np.testing.assert_allclose(U.T @ U, np.eye(7), atol=1e-12)
    Us, s, _ = np.linalg.svd(B, full_matrices=False)
    Us = Us[:, s > 1e-8 * s.max()]
    np.testing.assert_allclose(U @ U.T, Us @ Us.T, atol=1e-12)
    shares = np.abs(rng.normal(size=(4, 60)))
    shares[0, 30:] = 0.0  # a component of the first rows only
    shares[1, :45] = 0.0
    shares[3] = 0.0  # one that touches nothing
    want = component_information(U @ U.T, shares)
    got = basis_information(U, shares)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    assert not got[3].any()
    assert projection_basis(np.zeros((5, 2))).shape == (5, 0)
