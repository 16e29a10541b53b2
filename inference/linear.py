r"""Closed-form marginalisation of parameters that enter linearly with a Gaussian prior.

Model: :math:`y = f(\theta) + A(\theta)\beta + e`, :math:`e \sim N(0, N)`,
:math:`N = \mathrm{diag}(\text{noise\_var})`, :math:`\beta \sim N(m_0, P)`,
:math:`P = \mathrm{diag}(\text{prior\_var})`. With :math:`r = y - f - A m_0` (``resid`` is
:math:`y - f`):

.. math::
    p(y\mid\theta) = N\!\left(r;\,0,\; N + A P A^\top\right).

Evaluated in :math:`O(np^2)` by Woodbury in the prior-whitened coordinates
:math:`\beta = m_0 + P^{1/2}\gamma`, with :math:`B = N^{-1/2} A P^{1/2}`:

.. math::
    \tilde M = I + B^\top B = L L^\top,\qquad
    \log p = -\tfrac12\bigl(r^\top N^{-1} r - \lVert L^{-1} b\rVert^2\bigr)
             - \tfrac12\log|N| - \log|L| - \tfrac n2\log 2\pi,\qquad
    b = B^\top N^{-1/2} r .

:math:`\tilde M` has eigenvalues ≥ 1, so its Cholesky never fails. The conditional
:math:`\beta\mid\theta,y` is Gaussian with covariance :math:`P^{1/2}\tilde M^{-1}P^{1/2}` and mean
:math:`m_0 + P^{1/2}\tilde M^{-1} b`.

``prior_var`` must be finite and > 0 (an improper flat prior has no normalisable marginal;
use a wide prior — the log-determinant then carries a large constant, harmless for sampling
θ). Rows with ``mask == False`` (padding) are ignored exactly. The public functions are pure
and jit/vmap/grad-safe: jit them where they run (eager JAX compiles every primitive apart).
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

import math

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jax import Array
from jax.typing import ArrayLike

__all__ = ["conditional_beta", "draw_beta", "marginal_loglik"]

_LOG_2PI = math.log(2.0 * math.pi)


def _prepare(resid, A, noise_var, prior_mean, prior_var, mask):
    resid = jnp.asarray(resid)
    A = jnp.asarray(A)
    if resid.ndim != 1 or A.ndim != 2 or A.shape[0] != resid.shape[0]:
        raise ValueError(
            f"need resid (n,) and A (n, p) with the same n; got {resid.shape} and {A.shape}"
        )
    n, p = A.shape
    noise_var = jnp.broadcast_to(jnp.asarray(noise_var, dtype=resid.dtype), (n,))
    prior_mean = jnp.broadcast_to(jnp.asarray(prior_mean, dtype=resid.dtype), (p,))
    prior_var = jnp.broadcast_to(jnp.asarray(prior_var, dtype=resid.dtype), (p,))
    mask = jnp.ones(n, bool) if mask is None else jnp.broadcast_to(jnp.asarray(mask, bool), (n,))
    # Double-where: masked rows never see inf/0 noise, so gradients stay finite.
    nv = jnp.where(mask, noise_var, 1.0)
    w = jnp.where(mask, 1.0 / jnp.sqrt(nv), 0.0)  # N^{-1/2}, zero on padding
    sp = jnp.sqrt(prior_var)  # P^{1/2}
    r = jnp.where(mask, resid - A @ prior_mean, 0.0)
    rw = w * r  # N^{-1/2} r
    B = (w[:, None] * A) * sp[None, :]  # N^{-1/2} A P^{1/2}
    Mt = jnp.eye(p, dtype=B.dtype) + B.T @ B
    L = jnp.linalg.cholesky(Mt)
    b = B.T @ rw
    logdet_n = jnp.sum(jnp.where(mask, jnp.log(nv), 0.0))
    n_eff = jnp.sum(mask)
    return rw, b, L, Mt, sp, prior_mean, logdet_n, n_eff


def marginal_loglik(
    resid: ArrayLike,
    A: ArrayLike,
    noise_var: ArrayLike,
    prior_mean: ArrayLike,
    prior_var: ArrayLike,
    *,
    mask: ArrayLike | None = None,
) -> Array:
    r""":math:`\log N(\text{resid};\, A m_0,\; \mathrm{diag}(\text{noise\_var}) + A\,\mathrm{diag}
    (\text{prior\_var})A^\top)` by Woodbury, :math:`O(np^2)`.

    ``resid`` (n,) = y − f(θ); ``A`` (n, p); ``noise_var`` (n,) or scalar; ``prior_mean``,
    ``prior_var`` (p,) or scalars; ``mask`` (n,) bool, False rows are excluded (padding).
    """
    rw, b, L, _, _, _, logdet_n, n_eff = _prepare(resid, A, noise_var, prior_mean, prior_var, mask)
    c = jsl.solve_triangular(L, b, lower=True)
    quad = jnp.sum(rw**2) - jnp.sum(c**2)
    logdet = logdet_n + 2.0 * jnp.sum(jnp.log(jnp.diagonal(L)))
    return -0.5 * (quad + logdet + n_eff * _LOG_2PI)


def conditional_beta(
    resid: ArrayLike,
    A: ArrayLike,
    noise_var: ArrayLike,
    prior_mean: ArrayLike,
    prior_var: ArrayLike,
    *,
    mask: ArrayLike | None = None,
) -> tuple[Array, Array]:
    r"""``(mean, chol_cov)`` of :math:`\beta\mid\theta,y`; ``chol_cov`` is lower triangular with
    ``chol_cov @ chol_cov.T`` = :math:`P^{1/2}\tilde M^{-1}P^{1/2}`.

    The lower factor of :math:`\tilde M^{-1}` is :math:`J L'^{-\top} J` where :math:`J` reverses
    the order and :math:`L'` is the Cholesky factor of :math:`J\tilde M J` (no explicit inverse).
    """
    _, b, L, Mt, sp, m0, _, _ = _prepare(resid, A, noise_var, prior_mean, prior_var, mask)
    c = jsl.solve_triangular(L, b, lower=True)
    gamma = jsl.solve_triangular(L.T, c, lower=False)  # M̃⁻¹ b
    mean = m0 + sp * gamma
    Lr = jnp.linalg.cholesky(Mt[::-1, ::-1])
    eye = jnp.eye(Lr.shape[0], dtype=Lr.dtype)
    upper_inv = jsl.solve_triangular(Lr.T, eye, lower=False)  # L'^{-T}, upper
    chol_minv = upper_inv[::-1, ::-1]  # lower, chol_minv @ chol_minv.T = M̃⁻¹
    return mean, sp[:, None] * chol_minv


def draw_beta(
    key: Array,
    resid: ArrayLike,
    A: ArrayLike,
    noise_var: ArrayLike,
    prior_mean: ArrayLike,
    prior_var: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    n: int | None = None,
) -> Array:
    r"""Draw(s) of :math:`\beta\mid\theta,y`: shape (p,) or (n, p) when ``n`` is given."""
    mean, chol = conditional_beta(resid, A, noise_var, prior_mean, prior_var, mask=mask)
    shape = mean.shape if n is None else (n, *mean.shape)
    eps = jax.random.normal(key, shape, dtype=mean.dtype)
    return mean + eps @ chol.T
