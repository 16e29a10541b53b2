"""The posterior's fast path: importance sampling from the fitted proposal where it is
reliable (PSIS k̂, ESS of every reported quantity), emcee otherwise and on request."""

from __future__ import annotations

import numpy as np
import pytest

from chekan.runtime.compiler import Compiler
from inference import SamplerConfig, sample
from inference.importance_path import weighted_ess, with_weighted_ess


def _gauss(z, data):
    """N(μ, diag(s²)) with μ = (1, −2, 0.5), s = (0.5, 2, 1)."""
    import jax.numpy as jnp

    mu, s = jnp.array([1.0, -2.0, 0.5]), jnp.array([0.5, 2.0, 1.0])
    return -0.5 * jnp.sum(((z - mu) / s) ** 2)


def _funnel(z, data):
    """Neal's funnel: v ~ N(0, 3²), x | v ~ N(0, e^v): no Gaussian-like proposal covers
    its neck and mouth at once, so importance sampling from one is unreliable."""
    import jax.numpy as jnp

    v, x = z[0], z[1:]
    return -0.5 * (v / 3.0) ** 2 - 0.5 * jnp.sum(x**2) * jnp.exp(-v) - 0.5 * x.size * v


def _shoulder(z, data):
    """0.8 N(0, I) + 0.2 of a shoulder at z₀ ~ N(−3, 1.5²), z₁ | z₀ ~ N(0.8(z₀ + 3) + 1,
    0.5²): the proposal fitted at the mode covers it thinly. Mean (−0.6, 0.2)."""
    import jax.numpy as jnp

    core = -0.5 * jnp.sum(z**2)
    u, v = (z[0] + 3.0) / 1.5, (z[1] - 0.8 * (z[0] + 3.0) - 1.0) / 0.5
    side = jnp.log(0.25 / 0.75) - 0.5 * (u**2 + v**2)
    return jnp.logaddexp(core, side)


def _config(**kw) -> SamplerConfig:
    base = dict(
        n_chains=4,
        moves="adaptive-independence",
        stop_rule="bulk",
        min_steps=0,
        max_steps=3000,
        check_every=25,
        tau_factor=10.0,
        max_draws=500,
        proposal_components=1,
        proposal_alpha=0.1,
        proposal_tail_scale=1.2,
        proposal_tail_df=3.0,
        progress=False,
        seed=5,
        sampler="auto",
    )
    base.update(kw)
    return SamplerConfig(**base)


def _derived(draws: np.ndarray) -> dict[str, np.ndarray]:
    return {"sum": draws.sum(axis=-1), "first_sq": draws[..., 0] ** 2}


def test_a_near_gaussian_posterior_takes_importance_sampling() -> None:
    z0 = np.array([0.9, -1.5, 0.3])
    res = sample(_gauss, None, z0, np.eye(3), _config(), executables=Compiler(), derived=_derived)
    assert res.method == "importance" and res.converged
    assert res.importance.accepted and res.importance.khat < 0.7
    assert res.importance.min_ess >= 1000
    assert res.n_steps == 0 and res.draws.shape[0] == 4  # a chain per independent batch
    flat = res.draws.reshape(-1, 3)
    mu, s = np.array([1.0, -2.0, 0.5]), np.array([0.5, 2.0, 1.0])
    # resampled draws: mean within 4 MC sd of the truth, sd within 10 %
    n_eff = res.ess
    assert np.all(np.abs(flat.mean(axis=0) - mu) < 4 * s / np.sqrt(n_eff))
    assert np.all(np.abs(flat.std(axis=0) / s - 1) < 0.1)
    # the derived quantities are the resampled draws' own, with the weights' ESS
    assert np.allclose(res.derived["sum"], res.draws.sum(axis=-1))
    assert set(res.weighted_ess) == {"sum", "first_sq"}
    assert all(b >= 1000 and t > 0 for b, t in res.weighted_ess.values())


def test_emcee_runs_where_importance_sampling_is_unreliable() -> None:
    z0 = np.zeros(4)
    cfg = _config(max_steps=50, check_every=25)  # emcee's figures do not matter here
    with pytest.warns(RuntimeWarning):
        res = sample(_funnel, None, z0, np.eye(4) * 0.5, cfg, executables=Compiler())
    assert res.method == "emcee" and res.n_steps > 0
    assert res.importance is not None and not res.importance.accepted
    assert "refused" in res.importance.message


def test_sampler_emcee_is_emcee_alone_and_unchanged_by_the_fast_path() -> None:
    z0 = np.array([0.9, -1.5, 0.3])
    alone = sample(_gauss, None, z0, np.eye(3), _config(sampler="emcee"), executables=Compiler())
    assert alone.method == "emcee" and alone.importance is None
    # where the fast path refuses, the emcee that follows draws exactly what emcee alone does
    strict = _config(khat_max=-1.0)  # no k̂ passes
    after = sample(_gauss, None, z0, np.eye(3), strict, executables=Compiler())
    assert after.method == "emcee" and not after.importance.accepted
    assert np.array_equal(after.draws, alone.draws)


def test_a_proposal_refitted_to_the_weighted_draws_covers_a_shoulder() -> None:
    """Population Monte Carlo: where k̂ refuses the first draws, the mixture fitted anew to
    them, and draws made afresh from it, stand for the posterior; without refits emcee
    runs."""
    z0 = np.zeros(2)
    kw = dict(proposal_components=3, max_steps=50, seed=3)
    with pytest.warns(RuntimeWarning):  # emcee, cut short here
        plain = sample(
            _shoulder,
            None,
            z0,
            np.eye(2),
            _config(importance_refits=0, **kw),
            executables=Compiler(),
        )
    assert plain.method == "emcee" and plain.importance.khat >= 0.7
    res = sample(
        _shoulder, None, z0, np.eye(2), _config(importance_refits=2, **kw), executables=Compiler()
    )
    assert res.method == "importance" and 1 <= res.importance.refits <= 2
    assert res.importance.khat < 0.7 and res.importance.min_ess >= 1000
    flat = res.draws.reshape(-1, 2)
    sd = np.sqrt([2.69, 0.8 + 0.2 * (0.25 + 1.44 + 1.0) - 0.04])
    assert np.all(np.abs(flat.mean(axis=0) - [-0.6, 0.2]) < 4 * sd / np.sqrt(res.ess))


def test_a_refit_that_cannot_change_the_proposal_is_not_made() -> None:
    """A t proposal alone gives its Gaussian components no weight, and too few weighted
    points fit none: refit returns the proposal itself, and the path draws nothing more."""
    from inference.proposal import MixtureProposal, refit

    rng = np.random.default_rng(0)
    q0 = MixtureProposal.t_only(np.zeros(2), np.eye(2), 5.0)
    x = rng.standard_normal((500, 2))
    assert refit(q0, x, np.ones(500), rng) is q0
    mixed = MixtureProposal(
        q0.mean0, q0.chol0, 5.0, 0.2, np.ones(1), np.zeros((1, 2)), np.eye(2)[None]
    )
    assert refit(mixed, x[:20], np.ones(20), rng, components=3) is mixed
    moved = refit(mixed, x + 3.0, np.ones(500), rng, components=1)
    assert moved is not mixed and np.allclose(moved.means[0], (x + 3.0).mean(axis=0))


def test_weighted_ess_of_equal_weights_is_the_number_of_points() -> None:
    rng = np.random.default_rng(0)
    f = rng.standard_normal(4000)
    bulk, tail = weighted_ess({"f": f}, np.zeros(4000))["f"]
    assert bulk == pytest.approx(4000, rel=1e-9)
    assert tail == pytest.approx(4000, rel=1e-9)
    # a point that carries all the weight leaves no effective draw beyond itself
    lw = np.full(4000, -np.inf)
    lw[:2] = 0.0
    assert weighted_ess({"f": f}, lw)["f"][0] == pytest.approx(2.0)


def test_summary_takes_the_weights_ess() -> None:
    summary = {"b1": {"mean": 1.0, "sd": 2.0, "ess_bulk": 4096.0, "ess_tail": 4096.0}}
    out = with_weighted_ess(summary, {"b1": (1600.0, 900.0)})
    assert out["b1"]["ess_bulk"] == 1600.0 and out["b1"]["ess_tail"] == 900.0
    assert out["b1"]["mcse_mean"] == pytest.approx(2.0 / 40.0)
    assert summary["b1"]["ess_bulk"] == 4096.0  # not changed
    assert with_weighted_ess(summary, None) == summary


def test_console_and_certificate_say_which_sampler_ran() -> None:
    from chekan.report.i18n import tr
    from chekan.report.tables import _sampler
    from chekan.results.summary import sampler_words

    taken = {
        "sampler": "importance",
        "importance": {"taken": True, "pareto_k": 0.41, "ess_min": 1523.0, "n_points": 2048},
    }
    refused = {"sampler": "emcee", "importance": {**taken["importance"], "pareto_k": 0.93}}
    refused["importance"]["message"] = "importance sampling refused: k̂ = 0.93 ≥ 0.70"
    assert "importance sampling" in sampler_words(taken) and "k = 0.41" in sampler_words(taken)
    assert sampler_words(refused).startswith("emcee (importance sampling refused: k̂ = 0.93")
    assert sampler_words({"sampler": "emcee"}) == "emcee"
    refit = {**taken, "importance": {**taken["importance"], "proposal_refits": 1}}
    assert "proposal refitted to weighted draws 1×" in sampler_words(refit)
    assert "refitted" not in sampler_words(taken)
    for lang in ("en", "ru"):
        t = tr(lang)
        assert "0.41" in _sampler(taken, t) and "1523" in _sampler(taken, t).replace(" ", "")
        assert "0.93" in _sampler(refused, t) and "emcee" in _sampler(refused, t)
        assert _sampler({"sampler": "emcee"}, t) == t("sampler_emcee")
