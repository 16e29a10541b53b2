"""Importance sampling from a fitted proposal (inference.importance): PSIS weights and k̂,
the per-quantity ESS, systematic resampling and the verdict, against analytic Gaussians."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from inference.arviz_io import psis_log_weights
from inference.importance import (
    KISH,
    ImportanceDraws,
    draw_importance,
    extend,
    judge,
    k_threshold,
    quantity_ess,
    quantity_ess_many,
    resample,
    weighted_mean_mcse,
)
from inference.proposal import MixtureProposal

MEAN = np.array([1.0, -2.0, 0.5])
COV = np.array([[2.0, 0.6, 0.0], [0.6, 1.0, -0.2], [0.0, -0.2, 0.5]])


def _gauss_logpdf(mean: np.ndarray, cov: np.ndarray):
    """log N(x; mean, cov) up to a constant, batched (n, d) → (n,)."""
    prec = np.linalg.inv(cov)

    def f(x: np.ndarray) -> np.ndarray:
        d = x - mean
        return -0.5 * np.einsum("ni,ij,nj->n", d, prec, d) + 7.0  # any constant

    return f


def _lse(a: np.ndarray) -> float:
    m = np.max(a)
    return float(m + np.log(np.sum(np.exp(a - m))))


def _wide() -> MixtureProposal:
    return MixtureProposal.t_only(MEAN, COV * 1.5**2, df=5.0)


def test_gaussian_target_weighted_moments_and_khat() -> None:
    rng = np.random.default_rng(3)
    draws = draw_importance(_gauss_logpdf(MEAN, COV), _wide(), 8000, 4, rng)
    assert draws.points.shape == (8000, 3) and draws.n_batches == 4
    assert np.bincount(draws.batch).tolist() == [2000] * 4
    assert draws.khat < 0.5
    assert _lse(draws.log_weights) == pytest.approx(0.0, abs=1e-12)
    assert 0.3 * 8000 < draws.ess < 8000
    mu, se = weighted_mean_mcse(draws.points, draws.log_weights)
    assert np.all(np.abs(mu - MEAN) < 4.0 * se), (mu, se)
    sq = (draws.points - MEAN) ** 2  # E[(x − m)²] = diag Σ
    v, vse = weighted_mean_mcse(sq, draws.log_weights)
    assert np.all(np.abs(v - np.diag(COV)) < 4.0 * vse), (v, vse)
    # the vectorised ESS is the scalar one column by column
    many = quantity_ess_many(draws.points, draws.log_weights)
    assert many.shape == (3,)
    for j in range(3):
        assert many[j] == pytest.approx(quantity_ess(draws.points[:, j], draws.log_weights))
    v_ok = judge(draws, {"x0": draws.points[:, 0], "x1": draws.points[:, 1]})
    assert v_ok.accepted, v_ok.message
    assert "k̂ = " in v_ok.message and "ESS ≥" in v_ok.message
    assert v_ok.min_ess == pytest.approx(min(many[:2]))


def test_quantity_ess_predicts_the_error_of_the_estimate() -> None:
    """Var_p(f)/ESS_f against the spread of μ̂ over independent repetitions (within 25 %)."""
    rng = np.random.default_rng(11)
    mean, cov = MEAN[:2], COV[:2, :2]
    target, prop = _gauss_logpdf(mean, cov), MixtureProposal.t_only(mean, cov * 2.0**2, 4.0)
    reps, n = 200, 1000
    est = np.empty((reps, 2))
    ess = np.empty((reps, 2))
    for r in range(reps):
        d = draw_importance(target, prop, n, 1, rng)
        f = np.column_stack([d.points[:, 0], (d.points[:, 1] - mean[1]) ** 2])
        est[r] = weighted_mean_mcse(f, d.log_weights)[0]
        ess[r] = quantity_ess_many(f, d.log_weights)
    var_p = np.array([cov[0, 0], 2.0 * cov[1, 1] ** 2])  # Var x₀; Var (x₁ − m)² = 2σ⁴
    predicted = var_p / ess.mean(axis=0)
    empirical = est.var(axis=0, ddof=1)
    np.testing.assert_allclose(empirical / predicted, 1.0, atol=0.25)


def test_narrow_proposal_has_a_large_khat_and_is_refused() -> None:
    rng = np.random.default_rng(5)
    narrow = MixtureProposal.t_only(MEAN, COV * 0.1**2, df=30.0)
    draws = draw_importance(_gauss_logpdf(MEAN, COV), narrow, 4000, 4, rng)
    assert draws.khat > 0.7
    v = judge(draws, {"x0": draws.points[:, 0]})
    assert not v.accepted
    assert "k̂" in v.message and f"{draws.khat:.2f}" in v.message and "refused" in v.message


def test_outside_the_support_weight_zero_no_nan() -> None:
    """Half-normal target: x₀ < 0 is −inf; those points get weight 0 and E x₀ = √(2/π)."""
    rng = np.random.default_rng(8)

    def half(x: np.ndarray) -> np.ndarray:
        return np.where(x[:, 0] > 0.0, -0.5 * np.sum(x * x, axis=1), -np.inf)

    prop = MixtureProposal.t_only(np.zeros(2), np.eye(2) * 1.5**2, 6.0)
    draws = draw_importance(half, prop, 6000, 4, rng)
    out = draws.points[:, 0] <= 0.0
    assert 2000 < out.sum() < 4000
    assert np.all(np.isneginf(draws.log_weights[out]))
    assert np.all(np.isfinite(draws.log_weights[~out]))
    assert not np.isnan(draws.log_weights).any() and np.isfinite(draws.khat)
    assert _lse(draws.log_weights) == pytest.approx(0.0, abs=1e-12)
    mu, se = weighted_mean_mcse(draws.points[:, 0], draws.log_weights)
    assert abs(mu - np.sqrt(2.0 / np.pi)) < 4.0 * se
    # a quantity undefined outside the support (log x₀) is fine: those points carry no weight
    with np.errstate(invalid="ignore", divide="ignore"):
        logx = np.log(draws.points[:, 0])
    assert np.isfinite(quantity_ess(logx, draws.log_weights))
    assert judge(draws, {"log x0": logx}, target_ess=100.0).accepted
    idx = resample(draws, 500, rng)
    assert np.all(draws.points[idx.ravel(), 0] > 0.0)  # never a point of weight 0
    with pytest.raises(ValueError, match="outside the support"):
        psis_log_weights(np.full(10, -np.inf))
    with pytest.raises(ValueError, match="NaN"):
        draw_importance(lambda x: np.full(x.shape[0], np.nan), prop, 100, 2, rng)


def test_resample_within_batches() -> None:
    rng = np.random.default_rng(2)
    draws = draw_importance(_gauss_logpdf(MEAN, COV), _wide(), 8000, 4, rng)
    m = 2000
    idx = resample(draws, m, rng)
    assert idx.shape == (4, m)
    for b in range(4):
        assert np.all(draws.batch[idx[b]] == b)
        members = draws.batch == b
        lw = draws.log_weights[members]
        want, _ = weighted_mean_mcse(draws.points[members], lw - _lse(lw))
        got = draws.points[idx[b]].mean(axis=0)
        # within the resampling error of m equal-weight draws, sd/√m (multinomial's; less)
        sd = np.sqrt(np.diag(COV) / m)
        assert np.all(np.abs(got - want) < 4.0 * sd), (b, got, want, sd)
        # systematic: point j taken ⌊m wⱼ⌋ or ⌈m wⱼ⌉ times
        w = np.exp(lw - _lse(lw))
        copies = np.bincount(np.searchsorted(np.flatnonzero(members), idx[b]), minlength=w.size)
        assert np.all((copies >= np.floor(m * w - 1e-9)) & (copies <= np.ceil(m * w + 1e-9)))
    # shuffled: the copies of a point are not all adjacent; unshuffled: sorted
    plain = resample(draws, m, np.random.default_rng(0), shuffle=False)
    assert np.all(np.diff(plain, axis=1) >= 0)
    assert not np.all(np.diff(idx, axis=1) >= 0)


def test_resample_equal_weights_takes_every_point_once() -> None:
    n, b = 103, 4
    batch = np.repeat(np.arange(b), [26, 26, 26, 25])
    pts = np.arange(n, dtype=float)[:, None]
    zeros = np.zeros(n)
    draws = ImportanceDraws(pts, zeros, zeros, np.full(n, -np.log(n)), 0.0, batch)
    for seed in range(5):
        idx = resample(draws, 25, np.random.default_rng(seed))
        assert np.array_equal(np.sort(idx[3]), np.flatnonzero(batch == 3))
    # weights 1:3 within a batch of two, 8 draws: exactly 2 and 6 copies
    two = ImportanceDraws(
        np.zeros((2, 1)), np.zeros(2), np.zeros(2), np.log([0.25, 0.75]), 0.0, np.zeros(2, int)
    )
    got = resample(two, 8, np.random.default_rng(1))
    assert np.bincount(got[0], minlength=2).tolist() == [2, 6]


def test_judge_names_the_quantity_short_of_its_ess() -> None:
    rng = np.random.default_rng(4)
    draws = draw_importance(_gauss_logpdf(MEAN, COV), _wide(), 4000, 4, rng)
    q = {
        "x0": draws.points[:, 0],
        "r2": np.sum((draws.points - MEAN) ** 2, axis=1),
        "vector": draws.points,  # not one number per point: skipped
        "label": np.array(["a"] * 4000),  # not numeric: skipped
    }
    e0, e1 = quantity_ess(q["x0"], draws.log_weights), quantity_ess(q["r2"], draws.log_weights)
    low, high = ("x0", "r2") if e0 < e1 else ("r2", "x0")
    assert abs(e0 - e1) > 50.0  # the two differ, so the test can tell them apart
    v = judge(draws, q, target_ess=0.5 * (e0 + e1))
    assert not v.accepted and v.limiting == low and repr(low) in v.message
    assert "ESS" in v.message and high not in v.message
    assert v.skipped == ("vector", "label") and set(v.ess) == {"x0", "r2"}
    assert v.min_ess == pytest.approx(min(e0, e1))
    ok = judge(draws, q, target_ess=min(e0, e1) - 1.0)
    assert ok.accepted and ok.limiting == low
    # a constant has no Monte-Carlo error; NaN at a weighted point refuses
    assert quantity_ess(np.full(4000, 2.5), draws.log_weights) == np.inf
    bad = q["x0"].copy()
    bad[7] = np.nan
    vb = judge(draws, {"x0": q["x0"], "bad": bad}, target_ess=10.0)
    assert not vb.accepted and vb.limiting == "bad" and "not finite at 1 point" in vb.message
    # no usable quantity: Kish's ESS
    vk = judge(draws, {}, target_ess=draws.ess + 1.0)
    assert not vk.accepted and vk.limiting == KISH and vk.min_ess == pytest.approx(draws.ess)


def test_extend_adds_points_and_smooths_the_union() -> None:
    rng = np.random.default_rng(6)
    target, prop = _gauss_logpdf(MEAN, COV), _wide()
    first = draw_importance(target, prop, 2000, 4, rng)
    before = first.log_weights.copy()
    more = extend(first, target, prop, 2002, rng)
    assert np.array_equal(first.log_weights, before) and first.points.shape[0] == 2000
    assert more.points.shape == (4002, 3) and np.array_equal(more.points[:2000], first.points)
    assert np.bincount(more.batch).tolist() == [1001, 1001, 1000, 1000]
    lw, k = psis_log_weights(more.log_ratios)
    np.testing.assert_array_equal(more.log_weights, lw)
    assert more.khat == k
    assert 1.6 * first.ess < more.ess < 2.4 * first.ess
    with pytest.raises(ValueError, match="coordinates"):
        extend(first, target, MixtureProposal.t_only(np.zeros(2), np.eye(2), 5.0), 100, rng)


def test_psis_log_weights_is_arviz_psislw_normalised() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz as az

    rng = np.random.default_rng(9)
    for scale in (0.3, 1.0, 2.5):
        lr = scale * rng.standard_normal(1500) + 40.0  # any offset
        before = lr.copy()
        lw, k = psis_log_weights(lr)
        ref_lw, ref_k = az.psislw(lr.copy(), reff=1.0)
        np.testing.assert_allclose(lw, ref_lw, rtol=0, atol=1e-12)
        assert k == pytest.approx(float(ref_k), rel=1e-12)
        assert _lse(lw) == pytest.approx(0.0, abs=1e-12)
        assert np.array_equal(lr, before)
    assert psis_log_weights(2.5 * rng.standard_normal(1500))[1] > 0.7  # lognormal σ 2.5: heavy
    # −inf: the finite ones smoothed as if alone
    lr = rng.standard_normal(1000)
    lr[::3] = -np.inf
    lw, k = psis_log_weights(lr)
    ref_lw, ref_k = az.psislw(lr[np.isfinite(lr)], reff=1.0)
    np.testing.assert_allclose(lw[np.isfinite(lr)], ref_lw, atol=1e-12)
    assert np.all(np.isneginf(lw[::3])) and k == pytest.approx(float(ref_k))
    # equal ratios: equal weights, no tail
    lw, k = psis_log_weights(np.full(50, 3.0))
    np.testing.assert_allclose(lw, -np.log(50))
    assert k == -np.inf
    with pytest.raises(ValueError, match="1-D"):
        psis_log_weights(np.zeros((2, 10)))


def test_k_threshold() -> None:
    assert k_threshold(100) == pytest.approx(0.5)
    assert k_threshold(10_000) == 0.7 and k_threshold(10_000, 0.6) == 0.6
    assert k_threshold(1) == -np.inf
