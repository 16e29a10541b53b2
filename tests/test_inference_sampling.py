"""emcee sampling against an analytic posterior; diagnostics; ArviZ/NetCDF round trip."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from chekan.runtime.compiler import Compiler
from inference import (
    LeastSquaresProblem,
    Param,
    ParamSpace,
    SamplerConfig,
    convergence_report,
    load_netcdf,
    sample,
    save_netcdf,
    summarize_draws,
    to_inference_data,
)
from inference.arviz_io import summary as idata_summary
from inference.sampling import integrated_time

SIGMA, PRIOR_SD = 0.5, 2.0
rng = np.random.default_rng(11)
X = np.c_[np.ones(30), np.linspace(-1, 1, 30), np.linspace(-1, 1, 30) ** 2]
Y = X @ np.array([0.3, -1.0, 0.8]) + SIGMA * rng.normal(size=30)
DATA = {"X": X, "y": Y}
SPACE = ParamSpace([Param("beta", scale=PRIOR_SD, shape=(3,))])
PROBLEM = LeastSquaresProblem(SPACE, lambda v, d: (d["y"] - d["X"] @ v["beta"]) / SIGMA, Compiler())
COV = np.linalg.inv(X.T @ X / SIGMA**2 + np.eye(3) / PRIOR_SD**2)
MEAN = COV @ X.T @ Y / SIGMA**2


def _blob(z, data):
    return {"fit": data["X"] @ SPACE.to_values(z)["beta"]}


@pytest.fixture(scope="module")
def run():
    # start from the analytic posterior in z = beta/PRIOR_SD (what fit_map would return)
    z0, cov_z = MEAN / PRIOR_SD, COV / PRIOR_SD**2
    # τ ≈ 10 steps here: 30 τ is plenty for a 3-D Gaussian and keeps the test short
    cfg = SamplerConfig(
        n_chains=4, min_steps=200, tau_factor=30, check_every=100, progress=False, seed=1
    )
    return sample(PROBLEM.log_density, DATA, z0, cov_z, cfg, blob_fn=_blob, executables=Compiler())


def test_emcee_matches_analytic_posterior(run) -> None:
    res = run
    assert res.converged, res.message
    assert res.draws.shape[0] == 4 and res.draws.shape[2] == 3
    assert res.n_steps >= 30 * res.tau.max()
    beta = res.values(SPACE)["beta"]  # (chain, draw, 3)
    summ = summarize_draws({"beta": beta}, hdi_prob=0.9)
    sd_true = np.sqrt(np.diag(COV))
    for i in range(3):
        s = summ[f"beta[{i}]"]
        assert s["r_hat"] < 1.01, s
        assert s["ess_bulk"] >= 400, s
        mc_err = sd_true[i] / np.sqrt(s["ess_bulk"])
        assert abs(s["mean"] - MEAN[i]) < 4 * mc_err, (i, s["mean"], MEAN[i], mc_err)
        # sd of a Gaussian sample: relative MC error ≈ 1/√(2 ESS)
        assert abs(s["sd"] / sd_true[i] - 1) < 4 / np.sqrt(2 * s["ess_bulk"]), (i, s["sd"])
        assert s["hdi_low"] < MEAN[i] < s["hdi_high"]
    ok, problems = convergence_report(summ)
    assert ok, problems
    assert 0.1 < res.acceptance.min() < 0.9
    # blobs: evaluated on the retained draws
    np.testing.assert_allclose(res.blobs["fit"], beta @ X.T, rtol=1e-12)
    # log_prob is the log density of the retained draws
    i = (1, 5)
    assert res.log_prob[i] == pytest.approx(float(PROBLEM.log_density(res.draws[i], DATA)))


def test_arviz_netcdf_round_trip(run, tmp_path) -> None:
    res = run
    post = res.values(SPACE)
    idata = to_inference_data(
        post,
        sample_stats={"lp": res.log_prob},
        observed_data={"y": Y},
        posterior_predictive={"fit": res.blobs["fit"]},
        dims={"beta": ["coef"], "fit": ["obs"]},
        coords={"coef": ["c0", "c1", "c2"]},
        attrs={"model": "quadratic"},
    )
    path = save_netcdf(idata, tmp_path / "sub" / "post.nc")
    back = load_netcdf(path)
    np.testing.assert_array_equal(back.posterior["beta"].values, post["beta"])
    np.testing.assert_array_equal(back.observed_data["y"].values, Y)
    assert back.attrs["model"] == "quadratic"
    summ = idata_summary(back, ["beta"], hdi_prob=0.94)
    assert set(summ) == {"beta[0]", "beta[1]", "beta[2]"}
    assert set(summ["beta[0]"]) >= {"mean", "sd", "hdi_low", "hdi_high", "r_hat", "ess_bulk"}
    with pytest.raises(FileNotFoundError):
        load_netcdf(tmp_path / "missing.nc")


def test_short_run_is_flagged() -> None:
    """A deliberately short run: not converged, warned, and the report says why."""
    cfg = SamplerConfig(max_steps=30, check_every=15, min_steps=0, progress=False, seed=2)
    with pytest.warns(RuntimeWarning, match="NOT converged"):
        res = sample(PROBLEM.log_density, DATA, np.full(3, 3.0), 1e-4, cfg, executables=Compiler())
    assert not res.converged
    ok, problems = convergence_report(summarize_draws({"z": res.draws}, hdi_prob=0.9))
    assert not ok
    assert any("R-hat" in p for p in problems) and any("ESS" in p for p in problems)


def test_sampler_input_errors() -> None:
    with pytest.raises(ValueError, match="even"):
        SamplerConfig(n_walkers=7).walkers(3)
    with pytest.raises(ValueError, match="2·ndim"):
        SamplerConfig(n_walkers=4).walkers(3)
    assert SamplerConfig().walkers(3) == 16 and SamplerConfig().walkers(10) == 22
    with pytest.raises(ValueError, match="not finite"):
        sample(
            lambda z, d: -np.inf * z.sum(),
            None,
            np.ones(2),
            np.eye(2),
            SamplerConfig(),
            executables=Compiler(),
        )


def test_vectorised_tau_equals_emcee() -> None:
    emcee = pytest.importorskip("emcee")
    r = np.random.default_rng(0)
    x = np.cumsum(r.normal(size=(2000, 6, 2)), axis=0) * 0.05 + r.normal(size=(2000, 6, 2))
    np.testing.assert_allclose(
        integrated_time(x), emcee.autocorr.integrated_time(x, tol=0), rtol=1e-10
    )


def test_snooker_move_samples_the_target() -> None:
    """emcee 3.1.6's DESnookerMove gives variance ≈ 0.80 on N(0, I₃); ours must give 1."""
    import emcee

    from inference.sampling import SnookerMove

    sampler = emcee.EnsembleSampler(
        16, 3, lambda x: -0.5 * np.sum(x**2, axis=1), moves=SnookerMove(), vectorize=True
    )
    state = emcee.State(
        np.random.default_rng(0).normal(size=(16, 3)),
        random_state=np.random.RandomState(0).get_state(),
    )
    sampler.run_mcmc(state, 1200)
    chain = sampler.get_chain(discard=100)
    tau = integrated_time(chain).max()
    ess = chain.shape[0] * chain.shape[1] / tau
    var = np.mean(chain**2)  # pooled over the 3 coordinates; MC sd ≈ √(2/(3·ESS))
    assert abs(var - 1) < 5 * np.sqrt(2 / (3 * ess)), (var, ess)


def _banana_t(z, data):
    """u ~ N(0, 1), v | u ~ N(u²/2, 1), w ~ t₆: mean (0, 0.5, 0), var (1, 1.5, 1.5)."""
    import jax.numpy as jnp

    u, v, w = z[0], z[1], z[2]
    return -0.5 * u**2 - 0.5 * (v - 0.5 * u**2) ** 2 - 3.5 * jnp.log1p(w**2 / 6.0)


def test_independence_moves_sample_a_non_gaussian_target() -> None:
    cfg = SamplerConfig(
        n_chains=4,
        moves="de-independence",
        min_steps=150,
        tau_factor=20,
        check_every=50,
        progress=False,
        seed=3,
    )
    res = sample(_banana_t, None, np.zeros(3), np.eye(3) * 0.1, cfg, executables=Compiler())
    assert res.converged, res.message
    assert res.tau.max() < 10  # DE alone: ~30 steps on this target
    flat = res.draws.reshape(-1, 3)
    summ = summarize_draws({"x": res.draws}, hdi_prob=0.9)
    for i, (mean, var) in enumerate(((0.0, 1.0), (0.5, 1.5), (0.0, 1.5))):
        ess = summ[f"x[{i}]"]["ess_bulk"]
        assert summ[f"x[{i}]"]["r_hat"] < 1.01
        assert abs(flat[:, i].mean() - mean) < 4 * np.sqrt(var / ess), i
        assert abs(flat[:, i].var() / var - 1) < 0.15, (i, flat[:, i].var())


def test_independence_move_log_ratio_is_the_proposal_ratio() -> None:
    from scipy import stats

    from inference.sampling import IndependenceMove

    mean, cov = np.array([1.0, -2.0]), np.array([[2.0, 0.3], [0.3, 0.5]])
    move = IndependenceMove(mean, cov, df=4.0)
    x0 = np.array([[0.0, 0.0], [3.0, -1.0]])
    x, factor = move.get_proposal(x0, np.random.RandomState(0))
    ref = stats.multivariate_t(mean, cov, df=4.0)
    np.testing.assert_allclose(factor, ref.logpdf(x0) - ref.logpdf(x), rtol=1e-10)


def test_refine_mode_finds_a_gaussians_mode_and_covariance() -> None:
    from inference.mode import refine_mode

    rng = np.random.default_rng(5)
    A = rng.normal(size=(4, 4))
    cov = A @ A.T + 0.5 * np.eye(4)
    prec = np.linalg.inv(cov)
    mu = np.array([1.0, -2.0, 0.5, 3.0])

    def logp(z):
        dz = z - mu
        return -0.5 * np.einsum("ni,ij,nj->n", dz, prec, dz)

    # start far away in a poor metric: the trust region brings it in, then Newton is exact
    z, c, info = refine_mode(logp, np.zeros(4), np.eye(4) * 0.01)
    assert info["laplace"] and info["grad_norm"] < 0.05
    np.testing.assert_allclose(z, mu, atol=1e-6)
    np.testing.assert_allclose(c, cov, rtol=1e-6, atol=1e-8)


def test_refine_mode_stays_put_outside_a_finite_support() -> None:
    from inference.mode import refine_mode

    def logp(z):  # finite only for z₀ > 0: the first FD stencil already leaves the support
        return np.where(z[:, 0] > 0, -0.5 * np.sum(z**2, axis=1), -np.inf)

    z, _, info = refine_mode(logp, np.array([0.01, 1.0]), np.eye(2))
    np.testing.assert_array_equal(z, [0.01, 1.0])
    assert not info["laplace"]


def test_concurrent_ensembles_give_the_same_draws() -> None:
    """Ensembles advanced in threads give exactly the draws of one thread (each has its own
    random state), with both kinds of moves; a bad thread count is refused."""
    for moves in ("de", "de-independence"):
        runs = []
        for threads in (1, 3):
            cfg = SamplerConfig(
                n_chains=4,
                moves=moves,
                max_steps=60,
                check_every=20,
                min_steps=0,
                progress=False,
                seed=5,
                threads=threads,
            )
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # short run: not converged
                runs.append(
                    sample(
                        _banana_t, None, np.zeros(3), np.eye(3) * 0.1, cfg, executables=Compiler()
                    )
                )
        np.testing.assert_array_equal(runs[0].draws, runs[1].draws)
        np.testing.assert_array_equal(runs[0].log_prob, runs[1].log_prob)
        assert runs[0].n_steps == runs[1].n_steps
    with pytest.raises(ValueError, match="threads"):
        SamplerConfig(threads=0).check()


def test_many_points_are_evaluated_in_order_whatever_the_threads() -> None:
    """The mode's and the proposal's hundreds of points go through the compiled batch in
    threads: every value lands at its own point, padding never leaks, and a batch of the
    sampler's size is evaluated in the calling thread."""
    import threading

    from inference.walkers import eval_any as _eval_any

    seen: list[str] = []

    def lnp(zs: np.ndarray) -> np.ndarray:
        assert zs.shape == (7, 3)  # always the compiled batch size
        seen.append(threading.current_thread().name)
        return -0.5 * np.sum(zs**2, axis=1) + zs[:, 0]

    pts = np.random.default_rng(4).standard_normal((101, 3))
    want = -0.5 * np.sum(pts**2, axis=1) + pts[:, 0]
    np.testing.assert_array_equal(_eval_any(lnp, pts, 7), want)
    assert len(seen) == 15
    seen.clear()
    np.testing.assert_array_equal(_eval_any(lnp, pts[:5], 7), want[:5])
    assert seen == [threading.current_thread().name]


def _bulk_config(max_steps: int) -> SamplerConfig:
    """The bulk stopping rule on the banana target: 4 DE ensembles, ESS ≥ 300, seed 3."""
    return SamplerConfig(
        n_chains=4,
        moves="de",
        stop_rule="bulk",
        target_ess=300.0,
        max_steps=max_steps,
        check_every=10,
        min_steps=0,
        tau_factor=10.0,
        progress=False,
        seed=3,
    )


def test_bulk_rule_ranks_for_r_hat_only_where_every_ess_passes(monkeypatch) -> None:
    """The bulk stopping rule needs ESS ≥ target *and* R̂ ≤ max: R̂'s rank normalisation is
    computed only at checks where every ESS already passes, and the run stops at the same
    step with the same draws as when R̂ is computed at every check."""
    from inference import mcmc_stats, sampling

    cfg = _bulk_config(max_steps=600)
    passes: list[bool] = []
    ranked: list[int] = []
    ess_bulk, rhat_rank = mcmc_stats.ess_bulk, mcmc_stats.rhat_rank

    def counted_rhat(x):
        ranked.append(len(passes))
        return rhat_rank(x)

    def watched(samplers, tau, n_steps, config, nw):
        _, _, draws = sampling.retained(samplers, tau, n_steps, config, nw)
        passes.append(min(ess_bulk(draws[..., i]) for i in range(draws.shape[-1])) >= 300.0)
        return retained(samplers, tau, n_steps, config, nw)

    def every_check(samplers, tau, n_steps, config, nw):  # the rule before: R̂ always
        _, _, draws = sampling.retained(samplers, tau, n_steps, config, nw)
        ess = np.array([ess_bulk(draws[..., i]) for i in range(draws.shape[-1])])
        rhat = max(rhat_rank(draws[..., i]) for i in range(draws.shape[-1]))
        return np.where(np.isfinite(ess), ess, 0.0), float(np.nan_to_num(rhat, nan=np.inf))

    retained = sampling.retained_diagnostics
    monkeypatch.setattr(mcmc_stats, "rhat_rank", counted_rhat)
    monkeypatch.setattr(sampling, "retained_diagnostics", watched)
    fast = sample(_banana_t, None, np.zeros(3), np.eye(3) * 0.1, cfg, executables=Compiler())
    assert fast.converged and len(passes) >= 2 and not passes[0]
    assert sorted(set(ranked)) == [k + 1 for k, ok in enumerate(passes) if ok]
    monkeypatch.setattr(sampling, "retained_diagnostics", every_check)
    full = sample(_banana_t, None, np.zeros(3), np.eye(3) * 0.1, cfg, executables=Compiler())
    assert full.n_steps == fast.n_steps
    np.testing.assert_array_equal(full.draws, fast.draws)


def test_bulk_rule_holds_for_the_derived_quantities_too() -> None:
    """``derived``: what the caller reports from the kept draws. Where one of its scalars
    mixes worse than every coordinate (here a coordinate held over blocks of 16 kept
    draws), the run goes on until it too has bulk ESS ≥ the target; quantities
    that pass with the coordinates change nothing (the same steps and draws as without);
    the last evaluation comes back, at the kept draws; arrays that are not one scalar per
    draw and constants are not judged."""
    from inference import mcmc_stats

    cfg = _bulk_config(max_steps=2000)
    calls: list[tuple[int, ...]] = []

    def same(draws: np.ndarray) -> dict[str, np.ndarray]:
        calls.append(draws.shape)
        return {"x0": 2.0 * draws[..., 0], "vec": draws[..., :2], "const": 0 * draws[..., 0]}

    def held(draws: np.ndarray) -> dict[str, np.ndarray]:
        n = draws.shape[1]
        return {"slow": np.repeat(draws[:, ::16, 0], 16, axis=1)[:, :n], **same(draws)}

    plain = sample(_banana_t, None, np.zeros(3), np.eye(3) * 0.1, cfg, executables=Compiler())
    calls.clear()
    with_same = sample(
        _banana_t, None, np.zeros(3), np.eye(3) * 0.1, cfg, derived=same, executables=Compiler()
    )
    assert len(calls) == 1 and calls[0] == plain.draws.shape
    assert with_same.n_steps == plain.n_steps
    np.testing.assert_array_equal(with_same.draws, plain.draws)
    assert with_same.derived is not None
    np.testing.assert_array_equal(with_same.derived["x0"], 2.0 * plain.draws[..., 0])

    slow = sample(
        _banana_t, None, np.zeros(3), np.eye(3) * 0.1, cfg, derived=held, executables=Compiler()
    )
    assert slow.converged and slow.derived is not None
    assert slow.n_steps > plain.n_steps
    assert mcmc_stats.ess_bulk(slow.derived["slow"]) >= 300.0
    assert mcmc_stats.ess_bulk(held(plain.draws)["slow"]) < 300.0  # it would not have passed
    np.testing.assert_array_equal(slow.derived["x0"], 2.0 * slow.draws[..., 0])

    seen: list[np.ndarray] = []

    def never(draws: np.ndarray) -> dict[str, np.ndarray]:  # each chain its own level
        seen.append(draws)
        return {"level": np.arange(draws.shape[0])[:, None] + 0.01 * draws[..., 0]}

    short = _bulk_config(max_steps=300)
    with pytest.warns(RuntimeWarning, match="the derived level has"):
        stuck = sample(
            _banana_t,
            None,
            np.zeros(3),
            np.eye(3) * 0.1,
            short,
            derived=never,
            executables=Compiler(),
        )
    assert not stuck.converged and stuck.n_steps == 300 and stuck.derived is not None
    # the final draws are evaluated once: the last check's evaluation is the one returned
    assert sum(d.shape == stuck.draws.shape and np.array_equal(d, stuck.draws) for d in seen) == 1
    np.testing.assert_array_equal(stuck.derived["level"], never(stuck.draws)["level"])
