"""``inference.barrier.fusion_barrier``: values and derivatives pass unchanged, and the
compiled program keeps the barrier (XLA's CPU compiler drops ``optimization_barrier``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from inference.barrier import fusion_barrier


def _expensive(x):
    """An elementwise chain XLA would fuse into a broadcasting consumer."""
    y = x
    for _ in range(6):
        y = jnp.sin(y) / (1.0 + y * y) + jnp.exp(-y)
    return y


def _model(x, barrier: bool):
    s = _expensive(x)
    if barrier:
        s = fusion_barrier(s)
    return jnp.sum(jnp.outer(x, x) * s[None, :]) + jnp.sum(s)


def test_values_of_a_pytree_pass_unchanged():
    tree = {"a": jnp.arange(5.0), "b": (jnp.array(3, jnp.int32), jnp.array([True, False]))}
    out = jax.jit(fusion_barrier)(tree)
    assert jax.tree.structure(out) == jax.tree.structure(tree)
    for got, want in zip(jax.tree.leaves(out), jax.tree.leaves(tree), strict=True):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)


def test_nan_and_empty_leaves_pass_unchanged():
    x = jnp.array([jnp.nan, 1.0])
    np.testing.assert_array_equal(jax.jit(fusion_barrier)(x), x)
    out = jax.jit(fusion_barrier)((jnp.zeros(0), jnp.ones(2)))
    assert out[0].shape == (0,)
    np.testing.assert_array_equal(out[1], jnp.ones(2))


def test_an_empty_tree_is_refused():
    with pytest.raises(ValueError, match="at least one array"):
        fusion_barrier(())


def test_derivatives_and_vmap_equal_those_without_the_barrier():
    x = jnp.linspace(-0.7, 1.3, 7)
    with_b = jax.jit(lambda x: _model(x, True))
    without = jax.jit(lambda x: _model(x, False))
    np.testing.assert_allclose(with_b(x), without(x), rtol=1e-14)
    np.testing.assert_allclose(jax.grad(with_b)(x), jax.grad(without)(x), rtol=1e-13)
    np.testing.assert_allclose(jax.jacfwd(with_b)(x), jax.jacfwd(without)(x), rtol=1e-13)
    xs = jnp.stack([x, 2 * x, x - 1])
    np.testing.assert_allclose(jax.vmap(with_b)(xs), jax.vmap(without)(xs), rtol=1e-14)


def test_the_compiled_program_keeps_the_barrier():
    """Without it the expensive chain is fused into the (7, 7) consumer; with it the chain
    is computed once, in a loop the compiler cannot remove."""
    x = jnp.linspace(-0.7, 1.3, 7)

    def compiled(barrier):
        return jax.jit(lambda x: _model(x, barrier)).lower(x).compile().as_text()

    assert " while(" in compiled(True)
    assert " while(" not in compiled(False)
    assert (
        "opt-barrier"
        not in jax.jit(lambda x: jax.lax.optimization_barrier(_expensive(x)) * 2.0)
        .lower(x)
        .compile()
        .as_text()
    )


def test_reverse_mode_and_higher_orders_pass_through():
    """The barrier is linear and its own transpose: ``grad``, ``hessian``, forward over
    forward and ``vmap`` of ``grad`` give the derivatives of the same function without it."""
    x = jnp.linspace(-0.7, 1.3, 7)
    xs = jnp.stack([x, 0.5 * x])
    with_b = lambda x: _model(x, True)  # noqa: E731
    without = lambda x: _model(x, False)  # noqa: E731
    for transform, arg in (
        (jax.hessian, x),
        (lambda f: jax.jacfwd(jax.jacfwd(f)), x),
        (lambda f: jax.jit(jax.jacrev(jax.jacfwd(f))), x),
        (lambda f: jax.vmap(jax.grad(f)), xs),
    ):
        np.testing.assert_allclose(transform(with_b)(arg), transform(without)(arg), rtol=1e-12)


def test_tangents_are_materialised_too():
    """Under ``jacfwd`` the tangents pass through a loop of their own: the Jacobian's program
    has two loops (value and tangents), so its consumers do not recompute either."""
    x = jnp.linspace(-0.7, 1.3, 7)
    text = jax.jit(jax.jacfwd(lambda x: _model(x, True))).lower(x).compile().as_text()
    assert text.count(" while(") == 2
