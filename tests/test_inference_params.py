"""ParamSpace: the map z ↔ named values, priors, naming, and the errors it raises."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from inference import Param, ParamSpace


@pytest.fixture
def space() -> ParamSpace:
    return ParamSpace(
        [
            Param("a", loc=1.0, scale=2.0),
            Param("b", loc=-1.0, scale=0.5, transform="log", shape=(2,)),
            Param("c", shape=(2, 2), typical=3.0),  # flat prior
        ]
    )


def test_layout_and_names(space: ParamSpace) -> None:
    assert space.size == 1 + 2 + 4
    assert space.names == ("a", "b", "c")
    assert space.slices["b"] == slice(1, 3)
    assert space.flat_names() == ["a", "b[0]", "b[1]", "c[0,0]", "c[0,1]", "c[1,0]", "c[1,1]"]
    assert space.n_prior == 3
    assert space.subset(["c", "a"]).names == ("c", "a")
    np.testing.assert_array_equal(space.flat_indices(["c", "a"]), [3, 4, 5, 6, 0])


def test_round_trip_and_scaling(space: ParamSpace) -> None:
    values = {"a": 2.5, "b": np.array([0.2, 3.0]), "c": np.arange(4.0).reshape(2, 2)}
    z = space.to_z(values)
    # u = loc + typical*z with typical = scale (finite) or the given typical
    np.testing.assert_allclose(z[0], (2.5 - 1.0) / 2.0)
    np.testing.assert_allclose(z[1:3], (np.log([0.2, 3.0]) + 1.0) / 0.5)
    np.testing.assert_allclose(z[3:], np.arange(4.0) / 3.0)
    back = space.to_values(z)
    for k, v in values.items():
        np.testing.assert_allclose(back[k], v, rtol=1e-14)
    # missing names go to the prior loc (z = 0)
    np.testing.assert_array_equal(space.to_z({"a": 1.0}), np.zeros(space.size))


def test_batched_and_jit(space: ParamSpace) -> None:
    z = np.random.default_rng(0).normal(size=(3, 4, space.size))
    vals = jax.jit(space.to_values)(z)
    assert vals["c"].shape == (3, 4, 2, 2) and vals["b"].shape == (3, 4, 2)
    assert bool(jnp.all(vals["b"] > 0))
    assert space.log_prior(z).shape == (3, 4)
    flat = space.flatten(vals)
    assert set(flat) == set(space.flat_names()) and flat["c[1,0]"].shape == (3, 4)


def test_prior_matches_scipy(space: ParamSpace) -> None:
    z = np.random.default_rng(1).normal(size=space.size)
    u = np.asarray(space.to_u(z))
    want = stats.norm.logpdf(u[0], 1.0, 2.0) + stats.norm.logpdf(u[1:3], -1.0, 0.5).sum()
    np.testing.assert_allclose(space.log_prior(z), want, rtol=1e-13)
    np.testing.assert_allclose(
        space.prior_residuals(z), np.r_[(u[0] - 1) / 2, (u[1:3] + 1) / 0.5], rtol=1e-13
    )


def test_prior_sd_in_z_units_is_the_spread_of_prior_draws(space: ParamSpace) -> None:
    """scale/typical per element (typical defaults to scale: 1), inf where the prior is
    flat; the prior's own draws in z have that spread."""
    sd = space.prior_sd_z
    np.testing.assert_array_equal(sd[:3], [1.0, 1.0, 1.0])
    assert np.all(np.isinf(sd[3:]))
    sub = ParamSpace([Param("k", loc=-5.8, scale=1.5, transform="log", typical=0.3), space["a"]])
    np.testing.assert_allclose(sub.prior_sd_z, [5.0, 1.0])
    draws = sub.sample_prior_z(np.random.default_rng(0), 20_000)
    np.testing.assert_allclose(draws.std(axis=0), sub.prior_sd_z, rtol=0.03)


def test_errors_explain() -> None:
    with pytest.raises(ValueError, match="transform"):
        Param("x", transform="sqrt")
    with pytest.raises(ValueError, match="scale must be > 0"):
        Param("x", scale=0.0)
    with pytest.raises(ValueError, match="duplicate"):
        ParamSpace([Param("x"), Param("x")])
    sp = ParamSpace([Param("x", transform="log"), Param("y", shape=(3,))])
    with pytest.raises(ValueError, match="must be > 0"):
        sp.to_z({"x": -1.0})
    with pytest.raises(ValueError, match="does not fit"):
        sp.to_z({"y": np.ones(2)})
    with pytest.raises(KeyError, match="unknown"):
        sp.to_z({"zz": 1.0})
    with pytest.raises(ValueError, match="needs"):
        sp.to_values(np.zeros(3))
    with pytest.raises(ValueError, match="flat"):
        sp.sample_prior_z(np.random.default_rng(0))
    assert math.isinf(sp["x"].scale)


def test_map_values_of_a_diverged_pass_are_inf_without_a_warning():
    """A pass that ran into the far tails can end beyond exp's range: the host values say
    ``inf`` and no RuntimeWarning reaches the user (the pass is judged by its flags)."""
    import warnings

    from inference.map import _host_values

    space = ParamSpace([Param("b", loc=0.0, scale=1.0, transform="log")])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        values = _host_values(space, np.array([1e4]))
    assert values["b"] == np.inf
