r"""Minimise a smooth function of a few variables inside a box, by projected Newton steps.

.. math::  \hat x = \arg\min_{l \le x \le u} f(x)

For a handful of variables with exact derivatives (``jax.grad``, ``jax.hessian``) inside
compiled code (a ``lax.while_loop``: no host round trip). Optimistix 0.1 has no
bound-constrained minimiser, and SciPy's L-BFGS-B cannot run inside a compiled loop.

Each step (Bertsekas' projected Newton, 1982): the variables at a bound whose gradient
points outwards are held; on the others the Newton direction of the Hessian with its
eigenvalues made positive (|λ|, floored at 1e-12·max|λ|); a backtracking line search
along the projected path ``clip(x + t·d)`` with the Armijo condition. It stops when a step
moves no variable by more than ``xtol`` or after ``max_steps`` steps.
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["BoxNewtonResult", "minimise_in_box"]

_ARMIJO = 1e-4
_HALVINGS = 40


class BoxNewtonResult(NamedTuple):
    """The minimiser, f there, and the number of Newton steps taken."""

    x: jax.Array
    f: jax.Array
    num_steps: jax.Array


def minimise_in_box(
    f: Callable[[jax.Array], jax.Array],
    x0: jax.Array,
    lower: jax.Array,
    upper: jax.Array,
    *,
    xtol: float = 1e-12,
    max_steps: int = 100,
) -> BoxNewtonResult:
    """:math:`\\arg\\min f` over ``lower ≤ x ≤ upper`` from ``x0`` (clipped into the box);
    traceable (use it inside ``jit``). ``f`` maps a 1-D array to a scalar."""
    grad = jax.grad(f)
    hess = jax.hessian(f)
    n = x0.shape[0]
    eye = jnp.eye(n, dtype=x0.dtype)

    def direction(x):
        g = grad(x)
        held = ((x <= lower) & (g > 0)) | ((x >= upper) & (g < 0))
        free = ~held
        H = jnp.where(free[:, None] & free[None, :], hess(x), eye)
        w, V = jnp.linalg.eigh(H)
        w = jnp.maximum(jnp.abs(w), 1e-12 * jnp.max(jnp.abs(w)) + 1e-300)
        gf = jnp.where(free, g, 0.0)
        d = -(V @ ((V.T @ gf) / w))
        return jnp.where(free, d, 0.0), g

    def line_search(x, fx, d, g):
        def cond(c):
            _, x_new, f_new, k = c
            return (f_new > fx + _ARMIJO * jnp.dot(g, x_new - x)) & (k < _HALVINGS)

        def body(c):
            t, _, _, k = c
            t = 0.5 * t
            x_new = jnp.clip(x + t * d, lower, upper)
            return t, x_new, f(x_new), k + 1

        x1 = jnp.clip(x + d, lower, upper)
        _, x_new, f_new, _ = jax.lax.while_loop(cond, body, (1.0, x1, f(x1), 0))
        ok = f_new <= fx + _ARMIJO * jnp.dot(g, x_new - x)
        return jnp.where(ok, x_new, x), jnp.where(ok, f_new, fx)

    def cond(c):
        _, _, moved, k = c
        return (moved > xtol) & (k < max_steps)

    def body(c):
        x, fx, _, k = c
        d, g = direction(x)
        x_new, f_new = line_search(x, fx, d, g)
        return x_new, f_new, jnp.max(jnp.abs(x_new - x)), k + 1

    x = jnp.clip(x0, lower, upper)
    x, fx, _, k = jax.lax.while_loop(cond, body, (x, f(x), jnp.inf, 0))
    return BoxNewtonResult(x, fx, jnp.asarray(k))
