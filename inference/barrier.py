r"""A fusion barrier that XLA's CPU compiler keeps.

XLA fuses elementwise producers into their consumers and, when a producer is itself a
fusion, duplicates it into every consumer, also into consumers that broadcast it: a value
of shape (H,) computed by ~200 operations and used as ``X * s[None, :]`` with X of shape
(H, p) is then recomputed H·p times instead of H. ``jax.lax.optimization_barrier`` does
not stop this on CPU: the compiler removes the barrier before fusion (jax 0.10.2; the
compiled module has no ``opt-barrier``, measured).

:func:`fusion_barrier` routes the values through a loop that runs once. The compiler cannot
see its trip count (it depends on a value known only at run time), so it keeps the loop,
and the loop's outputs are buffers: consumers read them instead of recomputing them.

Derivatives pass straight through (``custom_jvp`` with the identity as tangent), so the
barrier works under ``jvp``, ``grad``, ``jacfwd`` and ``vmap``; only the primal values are
materialised.
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

from typing import TypeVar

import jax
import jax.numpy as jnp

__all__ = ["fusion_barrier"]

T = TypeVar("T")


@jax.custom_jvp
def fusion_barrier(tree: T) -> T:
    """``tree`` unchanged, computed once: its consumers read it from memory (module
    docstring). The leaves must be arrays (at least one of them)."""
    leaves = jax.tree.leaves(tree)
    if not leaves:
        raise ValueError("fusion_barrier needs at least one array")
    first = jnp.ravel(jnp.asarray(leaves[0]))[:1].astype(float)
    # 1 trip; 0 if the value is NaN (or empty): the body is the identity either way, but
    # the compiler cannot know the count and must keep the loop
    trips = jnp.sum(jnp.where(first == first, 1, 0)).astype(jnp.int32)

    def body(carry):
        i, values = carry
        keep = i >= 0  # always true, unknown to the compiler
        return i + 1, jax.tree.map(lambda a: jnp.where(keep, a, jnp.zeros_like(a)), values)

    return jax.lax.while_loop(lambda c: c[0] < trips, body, (jnp.int32(0), tree))[1]


@fusion_barrier.defjvp
def _fusion_barrier_jvp(primals, tangents):
    (tree,), (tangent,) = primals, tangents
    return fusion_barrier(tree), tangent
