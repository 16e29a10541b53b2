r"""Linear-Gaussian marginalisation from the normal equations (structured models).

Same model as :mod:`inference.linear`, :math:`y = f + A\beta + e`, :math:`e\sim N(0, N)`,
:math:`\beta\sim N(0, P)`, for models that can assemble the normal-equation blocks
:math:`G = A^\top N^{-1}A` and :math:`g = A^\top N^{-1}r` cheaply from their structure
(without forming :math:`A`). With :math:`M = P^{-1} + G = LL^\top`:

.. math::
    \log p(y) = -\tfrac12\bigl(r^\top N^{-1}r - \lVert L^{-1}g\rVert^2\bigr)
                -\tfrac12\bigl(\log|N| + \log|P| + 2\textstyle\sum\log L_{ii}\bigr)
                -\tfrac n2\log 2\pi,

(matrix determinant lemma), and :math:`\beta\mid y \sim N(M^{-1}g, M^{-1})`.

When :math:`f, A, N` depend on parameters :math:`p` (variable projection), the derivative of
:math:`\hat\beta(p) = M^{-1}g` follows from its stationarity, not from differentiating the
assembly and the factorisation (:func:`implicit_stationary_point`).
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jax import Array

__all__ = [
    "NormalEquations",
    "implicit_stationary_point",
    "marginal_loglik_normal",
    "posterior_beta_normal",
]

_LOG_2PI = math.log(2.0 * math.pi)


class NormalEquations(NamedTuple):
    """rᵀN⁻¹r, AᵀN⁻¹r, AᵀN⁻¹A, log|N| and the number of rows (a JAX pytree)."""

    rNr: Array
    g: Array
    G: Array
    logdet_noise: Array
    n: Array


def _chol(ne: NormalEquations, prior_var: Array):
    _, g, G, _, _ = ne
    M = G + jnp.diag(1.0 / prior_var)
    return jnp.linalg.cholesky(M), g


def marginal_loglik_normal(ne: NormalEquations, prior_var: Array) -> Array:
    """log N(r; 0, N + A P Aᵀ) from the normal equations (module docstring)."""
    rNr, _, _, logdet_n, n = ne
    L, g = _chol(ne, prior_var)
    c = jsl.solve_triangular(L, g, lower=True)
    logdet = logdet_n + jnp.sum(jnp.log(prior_var)) + 2.0 * jnp.sum(jnp.log(jnp.diagonal(L)))
    return -0.5 * (rNr - jnp.sum(c**2) + logdet + n * _LOG_2PI)


def posterior_beta_normal(ne: NormalEquations, prior_var: Array) -> tuple[Array, Array]:
    """``(mean, L)`` of β | y: mean = M⁻¹g; the covariance is M⁻¹ = L⁻ᵀL⁻¹."""
    L, g = _chol(ne, prior_var)
    return jsl.cho_solve((L, True), g), L


def implicit_stationary_point(x: Array, chol: Array, gradient: Callable[[Array], Array]) -> Array:
    r"""``x`` = :math:`\hat x(p)`, the maximiser of a concave quadratic :math:`\Phi(x; p)`, with
    its derivative in :math:`p` by the implicit function theorem.

    :math:`\nabla_x\Phi(\hat x; p) = 0` and :math:`-\nabla_x^2\Phi = M = LL^\top` (``chol``)
    give :math:`d\hat x = M^{-1}\,\partial_p\nabla_x\Phi(\hat x; p)\,dp`. ``gradient(x)``
    is :math:`\nabla_x\Phi(x; p)`, closing over :math:`p` (traced values). The result's value
    is ``x`` bit for bit (:math:`F - F = 0`); its derivatives, forward or reverse, go through
    ``gradient`` and one solve with ``chol`` per tangent, never through the assembly of
    :math:`M` and its factorisation (which cost a dense :math:`M` tangent and a Cholesky
    derivative, O(p³), per tangent direction).
    """
    x = jax.lax.stop_gradient(x)
    F = gradient(x)
    return x + jsl.cho_solve((jax.lax.stop_gradient(chol), True), F - jax.lax.stop_gradient(F))


def draw_beta_normal(key: Array, ne: NormalEquations, prior_var: Array) -> Array:
    """One draw of β | y: mean + L⁻ᵀ ξ, ξ ~ N(0, I)."""
    mean, L = posterior_beta_normal(ne, prior_var)
    xi = jax.random.normal(key, mean.shape, dtype=mean.dtype)
    return mean + jsl.solve_triangular(L.T, xi, lower=False)
