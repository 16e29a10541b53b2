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

Derivatives pass through unchanged (the barrier is the identity) and are materialised the
same way: under ``jacfwd`` the tangents of a value are as costly as the
value, and without a barrier of their own XLA recomputed them in every consumer (the 9 h
record's three estimation executables: 57 500 HLO instructions, 51 600 with it; the jitted
Jacobian of a 3 h record's residuals 2.8–3.0 ms, 0.8–1.6 ms with it). The barrier is a
primitive, linear (the identity) and its own transpose, lowered to the loop: it works under
``jvp``, ``grad``, ``jacfwd``, ``hessian`` and ``vmap``.
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

import functools
from typing import TypeVar

import jax
import jax.numpy as jnp
from jax.interpreters import ad, batching, mlir

__all__ = ["fusion_barrier"]

T = TypeVar("T")


def fusion_barrier(tree: T) -> T:
    """``tree`` unchanged, computed once: its consumers read it from memory (module
    docstring), and so do the consumers of its derivatives. The leaves must be arrays (at
    least one of them)."""
    leaves, treedef = jax.tree.flatten(tree)
    if not leaves:
        raise ValueError("fusion_barrier needs at least one array")
    return jax.tree.unflatten(treedef, _barrier().bind(*map(jnp.asarray, leaves)))


def _loop_once(*leaves):
    """``leaves`` routed through a loop of one trip that the compiler cannot count."""
    first = jnp.ravel(leaves[0])[:1].astype(float)
    # 1 trip; 0 if the value is NaN (or empty): the body is the identity either way, but
    # the compiler cannot know the count and must keep the loop
    trips = jnp.sum(jnp.where(first == first, 1, 0)).astype(jnp.int32)

    def body(carry):
        i, values = carry
        keep = i >= 0  # always true, unknown to the compiler
        return i + 1, [jnp.where(keep, a, jnp.zeros_like(a)) for a in values]

    return jax.lax.while_loop(lambda c: c[0] < trips, body, (jnp.int32(0), list(leaves)))[1]


def _through_barrier(values: list) -> list:
    """``values`` with each that is not a symbolic zero passed through one barrier (the
    zeros stay symbolic: nothing to materialise)."""
    out = list(values)
    live = [i for i, v in enumerate(values) if type(v) is not ad.Zero]
    if live:
        for i, v in zip(live, _barrier().bind(*[values[i] for i in live]), strict=True):
            out[i] = v
    return out


def _jvp(primals, tangents):
    """Linear (the identity): the tangents pass through a barrier of their own."""
    return _barrier().bind(*primals), _through_barrier(tangents)


def _transpose(cotangents, *args):
    """The identity's transpose is the identity (a barrier again)."""
    return _through_barrier(cotangents)


@functools.cache
def _barrier():
    """The primitive, defined on first use: only tracing needs it (a process that loads
    stored executables never does), and ``jax.extend`` imports Pallas (≈ 0.1 s of start-up).

    A primitive, not a ``custom_jvp`` around the loop: reverse mode transposes the tangents'
    barrier (a ``while_loop`` has no transpose) and ``vmap`` batches it."""
    from jax.extend.core import Primitive

    p = Primitive("fusion_barrier")
    p.multiple_results = True
    p.def_impl(lambda *leaves: list(leaves))  # eager: nothing is fused
    p.def_abstract_eval(lambda *avals: list(avals))
    ad.primitive_jvps[p] = _jvp
    ad.primitive_transposes[p] = _transpose
    batching.primitive_batchers[p] = lambda args, dims: (p.bind(*args), dims)
    mlir.register_lowering(p, mlir.lower_fun(_loop_once, multiple_results=True))
    return p
