r"""The fixed point of a contraction inside a box, by squared extrapolation (SQUAREM).

.. math::  x^* = \Pi(F(x^*)),\qquad l \le x^* \le u

A plain fixed-point iteration :math:`x \leftarrow F(x)` (an EM) converges linearly, at
the rate of :math:`F`'s largest eigenvalue, which goes to 1 where the fixed point sits on
a bound the iteration only approaches (a variance that the data do not show creeps down
to zero). SQUAREM (Varadhan and Roland 2008, scheme S3) takes two updates, extrapolates
along them and takes a third, stabilising update from there:

.. math::

    r = F(x) - x,\quad v = F(F(x)) - 2F(x) + x,\quad \alpha = -\max(1, \lVert r\rVert /
    \lVert v\rVert),\quad x' = F\bigl(\Pi(x - 2\alpha r + \alpha^2 v)\bigr)

(:math:`\Pi` the projection on the box; :math:`\alpha = -1` is two plain updates). A
non-finite extrapolation falls back to the plain :math:`F(F(x))`. It stops when the last
update moves no coordinate by ``tol`` or more, or after ``max_updates`` evaluations of
:math:`F`. Traceable: a ``lax.while_loop``, no host round trip; the caller compiles.
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["SquaremResult", "squarem"]


class SquaremResult(NamedTuple):
    """The iterate, the evaluations of F made, and the last update's largest move."""

    x: jax.Array
    num_updates: jax.Array
    change: jax.Array


def squarem(
    update: Callable[[jax.Array], jax.Array],
    x0: jax.Array,
    lower: jax.Array,
    upper: jax.Array,
    *,
    tol: float,
    max_updates: int,
    num_updates: jax.Array | int = 0,
    change: jax.Array | float = float("inf"),
) -> SquaremResult:
    """The fixed point of ``update`` (a map of a 1-D array into ``lower…upper``) from
    ``x0``, by SQUAREM steps of three updates (module docstring); ``num_updates``: the
    evaluations already made, counted against ``max_updates``; ``change``: the last
    update's largest move before ``x0`` (below ``tol``: ``x0`` is returned as it is)."""

    def step(c: SquaremResult) -> SquaremResult:
        x, n, _ = c
        f1 = update(x)
        f2 = update(f1)
        r, v = f1 - x, f2 - 2.0 * f1 + x
        ratio = jnp.linalg.norm(r) / jnp.maximum(jnp.linalg.norm(v), jnp.finfo(x.dtype).tiny)
        alpha = -jnp.maximum(1.0, ratio)
        jump = jnp.clip(x - 2.0 * alpha * r + alpha**2 * v, lower, upper)
        start = jnp.where(jnp.all(jnp.isfinite(jump)), jump, f2)
        new = update(start)
        return SquaremResult(new, n + 3, jnp.max(jnp.abs(new - start)))

    def going(c: SquaremResult):
        return (c.change >= tol) & (c.num_updates + 3 <= max_updates)

    start = SquaremResult(x0, jnp.asarray(num_updates), jnp.asarray(change, x0.dtype))
    return jax.lax.while_loop(going, step, start)
