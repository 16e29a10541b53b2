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
import numpy as np
from jax import Array

__all__ = [
    "BandedFactor",
    "BlockNormalEquations",
    "NormalEquations",
    "banded_factor",
    "banded_factor_blocks",
    "blocks_of",
    "draw_beta_banded",
    "draw_beta_blocks",
    "implicit_stationary_point",
    "implicit_stationary_point_banded",
    "inverse_banded",
    "marginal_loglik_banded",
    "marginal_loglik_blocks",
    "marginal_loglik_normal",
    "posterior_beta_normal",
    "solve_banded",
    "solve_banded_transposed",
    "split_prior",
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
    chol = jax.lax.stop_gradient(chol)
    return _stationary(x, lambda u: jsl.cho_solve((chol, True), u), gradient)


def _stationary(x: Array, solve: Callable[[Array], Array], gradient: Callable[[Array], Array]):
    """x + M⁻¹(F − F), F = ``gradient``(x), x held: x's value, F's derivative through M⁻¹."""
    x = jax.lax.stop_gradient(x)
    F = gradient(x)
    return x + solve(F - jax.lax.stop_gradient(F))


def draw_beta_normal(key: Array, ne: NormalEquations, prior_var: Array) -> Array:
    """One draw of β | y: mean + L⁻ᵀ ξ, ξ ~ N(0, I)."""
    mean, L = posterior_beta_normal(ne, prior_var)
    xi = jax.random.normal(key, mean.shape, dtype=mean.dtype)
    return mean + jsl.solve_triangular(L.T, xi, lower=False)


# --------------------------------------------------------------------------- banded elimination
def _small_cholesky(A: Array) -> Array:
    """Cholesky factor of a small SPD matrix (k × k, k static), unrolled: no library call
    per block inside a loop (a LAPACK call costs more than the arithmetic at k = 3)."""
    k = A.shape[-1]
    L = [[jnp.zeros(A.shape[:-2]) for _ in range(k)] for _ in range(k)]
    for j in range(k):
        d = A[..., j, j] - sum((L[j][m] ** 2 for m in range(j)), jnp.zeros(A.shape[:-2]))
        L[j][j] = jnp.sqrt(d)
        for i in range(j + 1, k):
            off = A[..., i, j] - sum((L[i][m] * L[j][m] for m in range(j)), jnp.zeros(A.shape[:-2]))
            L[i][j] = off / L[j][j]
    return jnp.stack([jnp.stack(row, axis=-1) for row in L], axis=-2)


def _small_backward(L: Array, b: Array) -> Array:
    """L⁻ᵀb for a small lower-triangular L (k × k) and a vector b (k,), unrolled."""
    k = L.shape[-1]
    x: list[Array] = [jnp.zeros(())] * k
    for i in reversed(range(k)):
        acc = b[i]
        for m in range(i + 1, k):
            acc = acc - L[m, i] * x[m]
        x[i] = acc / L[i, i]
    return jnp.stack(x)


def _small_forward(L: Array, B: Array) -> Array:
    """L⁻¹B for a small lower-triangular L (k × k) and B (k × r), unrolled rows."""
    k = L.shape[-1]
    rows: list[Array] = []
    for i in range(k):
        acc = B[i]
        for m in range(i):
            acc = acc - L[i, m] * rows[m]
        rows.append(acc / L[i, i])
    return jnp.stack(rows)


class BandedFactor(NamedTuple):
    """The Cholesky factor of M in the order [banded part; dense part] (see
    :func:`banded_factor`): L = [[L_B, 0], [Yᵀ, L_S]] with L_B block lower-bidiagonal."""

    diag: Array  # (H, k, k) L_ii
    sub: Array  # (H, k, k) L_{i,i−1} (block 0: zeros)
    Y: Array  # (Hk, m) L_B⁻¹ C
    y: Array  # (Hk,) L_B⁻¹ g_B
    L_S: Array  # (m, m) Cholesky factor of the Schur complement D − YᵀY
    c: Array  # (m,) L_S⁻¹ (g_D − Yᵀ y)


class BlockNormalEquations(NamedTuple):
    """Normal equations whose variables are H blocks of k (block-tridiagonal among
    themselves) followed by m dense ones, given by their blocks (a JAX pytree; the prior
    is not included): M's part AᵀN⁻¹A as ``diag`` (H, k, k), ``sub`` (H, k, k: block
    (i, i − 1), block 0 unused), ``cross`` (H, k, m: banded rows, dense columns) and
    ``dense`` (m, m); AᵀN⁻¹r as ``g_band`` (H, k) and ``g_dense`` (m,); rᵀN⁻¹r, log|N|
    and the number of rows as in :class:`NormalEquations`. A model that knows its
    structure assembles these directly, never forming the (Hk + m)² matrix."""

    rNr: Array
    diag: Array
    sub: Array
    cross: Array
    dense: Array
    g_band: Array
    g_dense: Array
    logdet_noise: Array
    n: Array


def _dense_index(p: int, bands: np.ndarray) -> np.ndarray:
    return np.setdiff1d(np.arange(p), np.asarray(bands).reshape(-1))


def split_prior(prior_var: Array, bands: np.ndarray) -> tuple[Array, Array]:
    """``prior_var`` (p,) as (banded (H, k), dense (m,)) in the order of ``bands``."""
    bands = np.asarray(bands)
    return prior_var[bands], prior_var[_dense_index(prior_var.shape[0], bands)]


def blocks_of(ne: NormalEquations, bands: np.ndarray) -> BlockNormalEquations:
    """The blocks of dense normal equations whose variables ``bands`` (H, k) form a
    block-tridiagonal part (gathered from ``ne.G``; reference and tests)."""
    rNr, g, G, logdet_n, n = ne
    bands = np.asarray(bands)
    k = bands.shape[1]
    dense_idx = _dense_index(G.shape[0], bands)
    diag = G[bands[:, :, None], bands[:, None, :]]
    sub = G[bands[1:, :, None], bands[:-1, None, :]]
    sub = jnp.concatenate([jnp.zeros((1, k, k)), sub])
    cross = G[bands][:, :, dense_idx]
    dense = G[dense_idx[:, None], dense_idx[None, :]]
    return BlockNormalEquations(rNr, diag, sub, cross, dense, g[bands], g[dense_idx], logdet_n, n)


def banded_factor(
    ne: NormalEquations, prior_var: Array, bands: np.ndarray, unroll: int = 4
) -> BandedFactor:
    r"""Block elimination of :math:`M = P^{-1} + G` whose variables ``bands`` (H, k) form a
    block-tridiagonal part: ``M[bands[i], bands[j]] = 0`` for |i − j| > 1 (the caller's
    structure; every other variable, the m "dense" ones, may couple to anything): the
    blocks gathered (:func:`blocks_of`), then :func:`banded_factor_blocks`.
    """
    return banded_factor_blocks(blocks_of(ne, bands), *split_prior(prior_var, bands), unroll)


def banded_factor_blocks(
    b: BlockNormalEquations, prior_band: Array, prior_dense: Array, unroll: int = 4
) -> BandedFactor:
    r"""Block elimination of :math:`M = P^{-1} + G` given by its blocks (prior variances
    ``prior_band`` (H, k) and ``prior_dense`` (m,)).

    With the banded part first, :math:`M = \begin{pmatrix}B & C\\ C^\top & D\end{pmatrix}`,
    the block Cholesky :math:`B = L_BL_B^\top` runs over the H blocks
    (:math:`L_{ii}L_{ii}^\top = B_{ii} - L_{i,i-1}L_{i,i-1}^\top`,
    :math:`L_{i,i-1} = B_{i,i-1}L_{i-1,i-1}^{-\top}`) together with the forward solve
    :math:`[Y\; y] = L_B^{-1}[C\; g_B]`; then the Schur complement
    :math:`S = D - Y^\top Y = L_SL_S^\top` and :math:`c = L_S^{-1}(g_D - Y^\top y)`.
    O(H k³ + H k m² + m³) instead of the dense O((Hk + m)³).
    """
    H, k = b.g_band.shape
    m = b.g_dense.shape[0]
    Bd = b.diag + jax.vmap(jnp.diag)(1.0 / prior_band)
    rhs = jnp.concatenate([b.cross, b.g_band[:, :, None]], axis=2)

    def step(carry, blocks):
        L_prev, Y_prev = carry
        b_ii, b_io, r_i = blocks
        Lo = jnp.transpose(_small_forward(L_prev, b_io.T))  # B_{i,i−1} L_{i−1}⁻ᵀ
        L_ii = _small_cholesky(b_ii - Lo @ Lo.T)
        Y_i = _small_forward(L_ii, r_i - Lo @ Y_prev)
        return (L_ii, Y_i), (L_ii, Lo, Y_i)

    sub = b.sub.at[0].set(0.0)
    first = (jnp.eye(k), jnp.zeros((k, m + 1)))
    _, (diag, sub, Yall) = jax.lax.scan(step, first, (Bd, sub, rhs), unroll=unroll)
    Yall = Yall.reshape(H * k, -1)
    Y, y = Yall[:, :-1], Yall[:, -1]
    YtY = Yall.T @ Yall  # [YᵀY Yᵀy; yᵀY yᵀy] in one product (slicing Y first copies it)
    D = b.dense + jnp.diag(1.0 / prior_dense)
    L_S = jnp.linalg.cholesky(D - YtY[:m, :m])
    c = jsl.solve_triangular(L_S, b.g_dense - YtY[:m, m], lower=True)
    return BandedFactor(diag, sub, Y, y, L_S, c)


def _loglik_of_factor(rNr, logdet_n, n, log_prior_det, f: BandedFactor) -> Array:
    logdet_m = 2.0 * (
        jnp.sum(jnp.log(jnp.diagonal(f.diag, axis1=1, axis2=2)))
        + jnp.sum(jnp.log(jnp.diagonal(f.L_S)))
    )
    logdet = logdet_n + log_prior_det + logdet_m
    return -0.5 * (rNr - jnp.sum(f.y**2) - jnp.sum(f.c**2) + logdet + n * _LOG_2PI)


def marginal_loglik_blocks(
    b: BlockNormalEquations, prior_band: Array, prior_dense: Array, unroll: int = 4
) -> Array:
    """:func:`marginal_loglik_banded` from the blocks (:func:`banded_factor_blocks`)."""
    f = banded_factor_blocks(b, prior_band, prior_dense, unroll)
    return marginal_loglik_factor(b, prior_band, prior_dense, f)


def marginal_loglik_factor(
    b: BlockNormalEquations, prior_band: Array, prior_dense: Array, f: BandedFactor
) -> Array:
    """:func:`marginal_loglik_blocks` with the factor ``f`` of those blocks already formed
    (by :func:`banded_factor_blocks`; shared with :func:`draw_beta_factor`)."""
    log_prior_det = jnp.sum(jnp.log(prior_band)) + jnp.sum(jnp.log(prior_dense))
    return _loglik_of_factor(b.rNr, b.logdet_noise, b.n, log_prior_det, f)


def marginal_loglik_banded(
    ne: NormalEquations, prior_var: Array, bands: np.ndarray, unroll: int = 4
) -> Array:
    r""":func:`marginal_loglik_normal` by block elimination (:func:`banded_factor`):

    .. math::
        \log|M| = 2\textstyle\sum\log\operatorname{diag}L_B + 2\sum\log\operatorname{diag}L_S,
        \quad g^\top M^{-1}g = \lVert y\rVert^2 + \lVert c\rVert^2,

    the same value as the dense factorisation in exact arithmetic (the dense Cholesky
    dominates an evaluation once Hk is a few hundred).
    """
    return marginal_loglik_blocks(blocks_of(ne, bands), *split_prior(prior_var, bands), unroll)


def solve_banded_transposed(f: BandedFactor, bands: np.ndarray, u: Array, unroll: int = 4) -> Array:
    """x = L⁻ᵀu for the factor of :func:`banded_factor`, ``u`` in the order [banded; dense],
    the result in the original variable order: x_D = L_S⁻ᵀu_D, then backwards over the
    blocks x_i = L_iiᵀ⁻¹(u_i − Y_i x_D − L_{i+1,i}ᵀ x_{i+1})."""
    bands = np.asarray(bands)
    H, k = bands.shape
    nb = H * k
    x_d = jsl.solve_triangular(f.L_S.T, u[nb:], lower=False)
    r = (u[:nb] - f.Y @ x_d).reshape(H, k)
    sub_next = jnp.concatenate([f.sub[1:], jnp.zeros((1, k, k))])  # L_{i+1,i}

    def step(x_next, blocks):
        L_ii, L_ni, r_i = blocks
        rhs = r_i - L_ni.T @ x_next
        x_i = _small_backward(L_ii, rhs)
        return x_i, x_i

    _, xb = jax.lax.scan(step, jnp.zeros(k), (f.diag, sub_next, r), reverse=True, unroll=unroll)
    p = nb + x_d.size
    dense_idx = _dense_index(p, bands)
    return jnp.zeros(p).at[bands.reshape(-1)].set(xb.reshape(-1)).at[dense_idx].set(x_d)


def _forward_banded(f: BandedFactor, bands: np.ndarray, U: Array, unroll: int) -> Array:
    """L⁻¹U for U (p, r) in the original variable order, the result in the order [banded;
    dense]: forwards over the blocks, x_i = L_ii⁻¹(u_i − L_{i,i−1}x_{i−1}), then
    x_D = L_S⁻¹(u_D − Yᵀx_B)."""
    bands = np.asarray(bands)
    H, k = bands.shape
    dense_idx = _dense_index(U.shape[0], bands)

    def step(x_prev, blocks):
        L_ii, L_io, u_i = blocks
        x_i = _small_forward(L_ii, u_i - L_io @ x_prev)
        return x_i, x_i

    first = jnp.zeros((k, U.shape[1]))
    _, xb = jax.lax.scan(step, first, (f.diag, f.sub, U[bands]), unroll=unroll)
    xb = xb.reshape(H * k, -1)
    xd = jsl.solve_triangular(f.L_S, U[dense_idx] - f.Y.T @ xb, lower=True)
    return jnp.concatenate([xb, xd])


def solve_banded(f: BandedFactor, bands: np.ndarray, U: Array, unroll: int = 4) -> Array:
    """M⁻¹U for U (p, r) in the original variable order, with the factor of
    :func:`banded_factor`: L⁻¹U forwards over the blocks (:func:`_forward_banded`), then
    :func:`solve_banded_transposed` per column."""
    back = jax.vmap(lambda u: solve_banded_transposed(f, bands, u, unroll), 1, 1)
    return back(_forward_banded(f, bands, U, unroll))


def inverse_banded(f: BandedFactor, bands: np.ndarray, unroll: int = 4) -> Array:
    """M⁻¹ (p × p, the original variable order) from the factor of :func:`banded_factor`:
    with X = L⁻¹P (P the permutation to [banded; dense], one forward pass over the blocks),
    M⁻¹ = Pᵀ L⁻ᵀ L⁻¹ P = XᵀX (symmetric by construction)."""
    p = f.Y.shape[0] + f.L_S.shape[0]
    X = _forward_banded(f, bands, jnp.eye(p), unroll)
    return X.T @ X


def implicit_stationary_point_banded(
    x: Array, f: BandedFactor, bands: np.ndarray, gradient: Callable[[Array], Array], unroll=4
) -> Array:
    """:func:`implicit_stationary_point` with M given by its block factor ``f``
    (:func:`banded_factor_blocks`, variables ``bands``): one block solve
    (:func:`solve_banded`) per tangent."""
    f = jax.lax.stop_gradient(f)
    return _stationary(x, lambda u: solve_banded(f, bands, u[:, None], unroll)[:, 0], gradient)


def draw_beta_banded(key: Array, ne: NormalEquations, prior_var: Array, bands: np.ndarray) -> Array:
    """One draw of β | y ~ N(M⁻¹g, M⁻¹) by block elimination: L⁻ᵀ(L⁻¹g + ξ), ξ ~ N(0, I),
    with L the factor of :func:`banded_factor` (the same distribution as
    :func:`draw_beta_normal`; not the same draw for a key, the factor differs)."""
    return draw_beta_blocks(key, blocks_of(ne, bands), *split_prior(prior_var, bands), bands)


def draw_beta_blocks(
    key: Array,
    b: BlockNormalEquations,
    prior_band: Array,
    prior_dense: Array,
    bands: np.ndarray,
    order: Array | None = None,
) -> Array:
    """:func:`draw_beta_banded` from the blocks (β in the order that ``bands`` and the dense
    variables, ascending, take in it). ``order``: the index of the standard normal that
    each of those takes (None: the i-th; a padded problem's real variables keep theirs)."""
    f = banded_factor_blocks(b, prior_band, prior_dense)
    return draw_beta_factor(key, f, bands, order)


def draw_beta_factor(
    key: Array, f: BandedFactor, bands: np.ndarray, order: Array | None = None
) -> Array:
    """:func:`draw_beta_blocks` with the factor ``f`` already formed (shared with
    :func:`marginal_loglik_factor`: a point weighed and its β drawn in one evaluation)."""
    u = jnp.concatenate([f.y, f.c])
    xi = jax.random.normal(key, u.shape, dtype=u.dtype)
    if order is not None:
        xi = xi[order]
    return solve_banded_transposed(f, bands, u + xi)
