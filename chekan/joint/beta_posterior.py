r"""β given θ and the hyperparameters, from the hold blocks: β̂(θ) with its derivative in θ
(the MAP's projected residual), M⁻¹, the EM's E-step moments, and β's design by the support
of its rows.

The normal equations are :func:`chekan.joint.hold_blocks.normal_equations_at`'s; M is
factored by block elimination of the holds' (o₁, o₂, δ)
(:func:`inference.normal_eq.banded_factor_blocks`), never formed. A bin's row of the design
touches only the (o₁, o₂, δ) of its hold and of the hold before and the dense variables
(:class:`BinRows`), so every product with A (or with its derivative in θ) is
O(N·(6 + m)), and the leverages come from the entries of M⁻¹ on M's pattern
(:func:`inference.selected_inverse.selected_inverse`).

Values: those of the dense solve (the tests' oracle, ``tests/dense_oracle.py``) to round-off.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import chekan.jaxconfig  # noqa: F401
from chekan.joint.hold_blocks import (
    BinDesign,
    BinTerms,
    apply_blocks,
    bin_design,
    normal_equations_at,
)
from chekan.joint.layout import ModelStructure, RecordData
from chekan.joint.likelihood import beta_prior_var
from inference.normal_eq import (
    BandedFactor,
    banded_factor_blocks,
    implicit_stationary_point_banded,
    inverse_banded,
    solve_banded_transposed,
    split_prior,
)
from inference.selected_inverse import selected_inverse

UNROLL = 1  # the block scans' unrolling (the E-step's; docs/tuning.md)


class BinRows(NamedTuple):
    """β's design A by the support of its rows (:func:`bin_rows`): bin i of hold kᵢ touches
    only the (o₁, o₂, δ) of hold kᵢ, those of hold kᵢ − 1 and the m dense variables."""

    values: jax.Array  # (N, 2, 6 + m, …) the entries at ``columns``
    columns: jax.Array  # (N, 6 + m) int: their β indices


def _dense_columns(structure: ModelStructure) -> np.ndarray:
    """β's indices outside the hold bands, ascending (the dense block's order)."""
    return np.setdiff1d(np.arange(structure.n_beta), structure.hold_bands.reshape(-1))


def row_columns(structure: ModelStructure, data: RecordData) -> jax.Array:
    """(N, 6 + m) each bin's support in β's order: its hold's band (o₁, o₂, δ), the band
    of the hold before (the first hold's bins repeat their own there, with weight bᵢ = 0),
    the dense variables."""
    dense_ix = _dense_columns(structure)
    k = data.bin_hold
    band_ix = jnp.asarray(structure.hold_bands)
    dense = jnp.broadcast_to(jnp.asarray(dense_ix), (k.shape[0], dense_ix.size))
    return jnp.concatenate([band_ix[k], band_ix[jnp.maximum(k - 1, 0)], dense], axis=1)


def bin_rows(t: BinDesign | BinTerms, structure: ModelStructure, data: RecordData) -> BinRows:
    """β's design A by its rows' support, from the per-bin terms (as :func:`apply_blocks`
    applies it): system j's row has aᵢ·(oⱼ, sⱼₖδ) at hold kᵢ, bᵢ·(oⱼ, sⱼₖ₋₁δ) at kᵢ − 1, Q at
    qⱼ, and aᵢsⱼₖEₖ + bᵢsⱼₖ₋₁Eₖ₋₁ + cᵢUₖⱼ at the shared angle terms (e, ζ)."""
    k = t.hold
    kp = jnp.maximum(k - 1, 0)
    E = data.angle_basis
    zero_b, zero_q = jnp.zeros_like(t.a), jnp.zeros_like(t.Q)
    rows = []
    for j in range(2):
        own = [t.a if j == 0 else zero_b, t.a if j == 1 else zero_b, t.a * t.s[k, j]]
        prev = [t.b if j == 0 else zero_b, t.b if j == 1 else zero_b, t.b * t.s[kp, j]]
        angle = (t.a * t.s[k, j])[:, None] * E[k] + (t.b * t.s[kp, j])[:, None] * E[kp]
        if t.U is not None and structure.n_systematic:
            angle = angle + t.c[:, None] * t.U[k, :, j]
        q = [t.Q, zero_q] if j == 0 else [zero_q, t.Q]
        rows.append(jnp.concatenate([jnp.stack(own + prev, axis=1), *q, angle], axis=1))
    return BinRows(jnp.stack(rows, axis=1), row_columns(structure, data))


def rows_times(R: BinRows, X: jax.Array) -> jax.Array:
    """A X (N, 2, …) for X (p, …) from the rows' support."""
    return jnp.einsum("nje...,ne...->nj...", R.values, X[R.columns])


def rows_t_times(R: BinRows, U: jax.Array, n_beta: int) -> jax.Array:
    """Σᵢⱼ Aᵢⱼᵀ Uᵢⱼ (p, …) for U (N, 2, …) (with ``R.values`` (N, 2, E): Aᵀ U; with a
    trailing axis q on ``R.values`` and U (N, 2): the derivative (∂A)ᵀ U per q)."""
    per = jnp.einsum("nje...,nj...->ne...", R.values, U)
    return jax.ops.segment_sum(
        per.reshape(-1, *per.shape[2:]), R.columns.reshape(-1), num_segments=n_beta
    )


def dense_rows(R: BinRows, n_beta: int) -> jax.Array:
    """A (N, 2, p) scattered from its rows' support (what a dense consumer of the design
    reads, e.g. the Type A rows of :mod:`chekan.fit.typea`)."""
    N = R.columns.shape[0]
    per = (
        jnp.zeros((N, n_beta, 2))
        .at[jnp.arange(N)[:, None], R.columns]
        .add(jnp.swapaxes(R.values, 1, 2))
    )
    return jnp.swapaxes(per, 1, 2)


class BetaSolution(NamedTuple):
    """β̂ | θ, h from the hold blocks (:func:`solve_beta`)."""

    rw: jax.Array  # (2N,) whitened residuals √w (y − f − Aβ̂), (bin, system) order
    beta: jax.Array  # (p,) β̂ = M⁻¹g, its derivative in θ from its stationarity
    factor: BandedFactor  # M's factor in the order [hold bands; dense]
    terms: BinTerms


def beta_mean(
    v: dict, h: dict, structure: ModelStructure, data: RecordData, design: BinDesign | None = None
) -> BetaSolution:
    """β̂ = M⁻¹g at θ (values ``v``) and h by block elimination of M = AᵀN⁻¹A + Λ⁻¹, with
    the whitened residuals (``design``: :func:`~chekan.joint.hold_blocks.bin_design` at
    ``v`` if already computed); its derivatives go through the elimination (for a
    derivative in θ take :func:`solve_beta`)."""
    design = bin_design(v, structure, data) if design is None else design
    blocks, t = normal_equations_at(design, h, structure, data)
    bands = structure.hold_bands
    prior_var = beta_prior_var(h, structure, data)
    f = banded_factor_blocks(blocks, *split_prior(prior_var, bands), unroll=UNROLL)
    beta = solve_banded_transposed(f, bands, jnp.concatenate([f.y, f.c]), unroll=UNROLL)
    return BetaSolution(_whitened(beta, t, structure, data), beta, f, t)


def _whitened(beta, t: BinTerms, structure: ModelStructure, data: RecordData) -> jax.Array:
    """√w (y − f − Aβ) (2N,); not √W: its derivative is infinite where W = 0 (masked bins),
    giving 0·∞ = NaN."""
    sqrt_w = jnp.where(data.mask, 1.0 / jnp.sqrt(t.nv), 0.0)
    return (sqrt_w * (t.r - apply_blocks(beta, t, structure, data))).reshape(-1)


def solve_beta(
    v: dict, h: dict, structure: ModelStructure, data: RecordData, design: BinDesign | None = None
) -> BetaSolution:
    """:func:`beta_mean`, β̂(θ) = argmin ‖N^{-1/2}(y − f − Aβ)‖² + ‖Λ^{-1/2}β‖², with its
    derivatives in θ from its stationarity ∇Φ(β̂) = 0 (Φ the log-posterior of β, −∇²Φ = M):
    one block solve per tangent through A·β
    (:func:`inference.normal_eq.implicit_stationary_point_banded`), not through the assembly
    of the blocks and their elimination (the MAP's residual and its Jacobian)."""
    sol = beta_mean(v, h, structure, data, design)
    t = sol.terms
    beta, f = jax.lax.optimization_barrier((sol.beta, sol.factor))
    prior_var = beta_prior_var(h, structure, data)

    def log_posterior(b):  # Φ(β) up to a constant
        e = _whitened(b, t, structure, data)
        return -0.5 * (jnp.sum(e * e) + jnp.sum(b * b / prior_var))

    bands = structure.hold_bands
    beta = implicit_stationary_point_banded(beta, f, bands, jax.grad(log_posterior), UNROLL)
    return BetaSolution(_whitened(beta, t, structure, data), beta, f, t)


def posterior_cov(f: BandedFactor, structure: ModelStructure) -> jax.Array:
    """M⁻¹ (p × p) from the block factor (:func:`inference.normal_eq.inverse_banded`)."""
    return inverse_banded(f, structure.hold_bands, unroll=UNROLL)


class BlockMoments(NamedTuple):
    """β | θ, h and the bins' moments from the hold blocks (:func:`block_moments`)."""

    factor: BandedFactor  # M's factor in the order [hold bands; dense]
    beta: jax.Array  # (p,) β̂ = M⁻¹g
    var: jax.Array  # (p,) diag(M⁻¹)
    sw: jax.Array  # (N, 2) √w (0 for masked bins)
    rows: BinRows  # the whitened design √w A by its rows' support
    rw: jax.Array  # (N, 2) whitened residuals √w (y − f − Aβ̂)
    lev: jax.Array  # (N, 2) leverages (Ã M⁻¹ Ãᵀ)ᵢᵢ
    terms: BinTerms


def block_moments(
    v: dict, h: dict, structure: ModelStructure, data: RecordData, design: BinDesign | None = None
) -> BlockMoments:
    """β̂, diag(M⁻¹), the whitened rows, residuals and leverages at θ (values ``v``) and h,
    from the hold blocks and the entries of M⁻¹ on M's pattern
    (:func:`inference.selected_inverse.selected_inverse`): a bin's row touches only the (o₁, o₂, δ)
    of its hold and of the hold before and the dense variables, so neither M nor M⁻¹
    (p × p) is formed. ``design``: :func:`~chekan.joint.hold_blocks.bin_design` at ``v`` if
    already computed. Values: those of the dense solve to round-off (tests)."""
    design = bin_design(v, structure, data) if design is None else design
    blocks, t = normal_equations_at(design, h, structure, data)
    bands, dense_ix = structure.hold_bands, _dense_columns(structure)
    pv = split_prior(beta_prior_var(h, structure, data), bands)
    f = banded_factor_blocks(blocks, *pv, unroll=UNROLL)
    beta = solve_banded_transposed(f, bands, jnp.concatenate([f.y, f.c]), unroll=UNROLL)
    Z = selected_inverse(f, unroll=UNROLL)
    var = (
        jnp.zeros(structure.n_beta)
        .at[bands.reshape(-1)]
        .set(jnp.diagonal(Z.diag, axis1=1, axis2=2).reshape(-1))
        .at[dense_ix]
        .set(jnp.diagonal(Z.dense))
    )
    sw = jnp.where(data.mask, 1.0 / jnp.sqrt(t.nv), 0.0)
    A = bin_rows(t, structure, data)
    At = BinRows(A.values * sw[:, :, None], A.columns)
    rw = sw * t.r - rows_times(At, beta)
    k = t.hold
    kp = jnp.maximum(k - 1, 0)
    own, prev, dense = At.values[:, :, :3], At.values[:, :, 3:6], At.values[:, :, 6:]
    cross = 2.0 * (
        jnp.einsum("nja,nab,njb->nj", own, Z.sub[k], prev)
        + jnp.einsum("nja,nam,njm->nj", own, Z.cross[k], dense)
        + jnp.einsum("nja,nam,njm->nj", prev, Z.cross[kp], dense)
    )
    lev = (
        jnp.einsum("nja,nab,njb->nj", own, Z.diag[k], own)
        + jnp.einsum("nja,nab,njb->nj", prev, Z.diag[kp], prev)
        + jnp.einsum("njm,ml,njl->nj", dense, Z.dense, dense)
        + cross
    )
    return BlockMoments(f, beta, var, sw, At, rw, lev, t)
