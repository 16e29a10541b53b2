r"""The EM's E-step moments (:mod:`chekan.joint.em`): β's given θ from the hold blocks, and
what θ's uncertainty adds to them.

With β̂(θ) ≈ β̂ + B(θ − θ̂), B = ∂β̂/∂θ, and θ ~ N(θ̂, C_θ),

    E[ββᵀ] = β̂β̂ᵀ + M⁻¹ + B C_θ Bᵀ,    E[rᵢ²] = r̂ᵢ² + (Ã M⁻¹ Ãᵀ)ᵢᵢ + (J_r C_θ J_rᵀ)ᵢᵢ

(:func:`theta_part`), from the derivatives of f, A and the transient in θ (:class:`Design`),
which do not depend on h: formed once per EM stage, as are the bins' terms at θ
(:func:`chekan.joint.hold_blocks.bin_design`). Every moment comes from M's hold blocks
(:func:`chekan.joint.beta_posterior.block_moments`), never O(p³).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from chekan.joint.beta_posterior import (
    BinRows,
    bin_rows,
    block_moments,
    row_columns,
    rows_t_times,
    rows_times,
)
from chekan.joint.hold_blocks import BinDesign, bin_design
from chekan.joint.layout import ModelStructure, RecordData
from chekan.joint.likelihood import beta_prior_var, noise_var
from chekan.joint.problem import Hyper
from inference.normal_eq import BandedFactor, solve_banded


class Moments(NamedTuple):
    """β's posterior given θ and what the E-step needs, at θ and h (:func:`moments`)."""

    rw: jax.Array  # (N, 2) whitened residuals
    beta: jax.Array  # (p,) β̂
    factor: BandedFactor  # M's factor by the hold blocks
    var: jax.Array  # (p,) diag(M⁻¹)
    At: BinRows  # (N, 2, 6 + m) the whitened design √w A by its rows' support
    sw: jax.Array  # (N, 2) √w (0 for masked bins)
    nv: jax.Array  # (N, 2) the bins' noise variance
    base: jax.Array  # (N, 2) its part (sⱼσⱼ)²/n
    trans: jax.Array  # (N, 2) the transient amplitude
    lev: jax.Array  # (N, 2) (Ã M⁻¹ Ãᵀ)ᵢᵢ


def moments(
    v: dict, h: Hyper, structure: ModelStructure, data: RecordData, at: BinDesign | None = None
) -> Moments:
    """The E-step's moments from the hold blocks (:func:`block_moments`; ``at``: the bins'
    terms at θ, :func:`~chekan.joint.hold_blocks.bin_design`, if already computed); padding
    bins 0."""
    m = block_moments(v, h, structure, data, at)
    t = m.terms
    trans = jnp.where(data.mask, t.trans, 0.0)
    return Moments(
        m.rw, m.beta, m.factor, m.var, m.rows, m.sw, t.nv, noise_var(h, data), trans, m.lev
    )


class Design(NamedTuple):
    """The derivatives in θ (working units, q of them) of what the bins' prediction is
    made of, at θ̂: they do not depend on the hyperparameters, so one forward Jacobian per
    EM stage serves every update (:func:`design_derivatives`)."""

    df: jax.Array
    """∂f/∂z (N, 2, q): the prediction without β."""
    dA: BinRows
    """∂A/∂z (N, 2, 6 + m, q) by the rows' support: β's design."""
    dt: jax.Array
    """∂t/∂z (N, 2, q): the transient amplitude that κ scales."""
    dprior: jax.Array
    """∂(θ's prior rows)/∂z."""


def design_derivatives(z, structure: ModelStructure, data: RecordData, space) -> Design:
    """:class:`Design` at θ = z, traceable (what it holds depends on θ alone)."""

    def pieces(zz):  # ∂f = −∂r on the real bins (r = y − f); padding bins have no weight
        t = bin_design(space.to_values(zz), structure, data)
        return -t.r, bin_rows(t, structure, data).values, t.trans

    df, dA, dt = jax.jacfwd(pieces)(z)
    rows = BinRows(dA, row_columns(structure, data))
    return Design(df, rows, dt, jax.jacfwd(space.prior_residuals)(z))


def theta_part(d: Design, m: Moments, h: Hyper, structure: ModelStructure, data):
    """What θ's uncertainty adds to the E-step's moments, ``(var_β (p,), lev_θ (N, 2))``:
    var_β = diag(B C_θ Bᵀ), lev_θ = diag(J_r C_θ J_rᵀ) (module docstring), traceable.

    With r_w = √w (y − f − Aβ), w = 1/v, v the bins' noise variance (κ's part moves with θ
    through the transient t): ∂r_w/∂θ at fixed β is J₀ = −√w (∂f + ∂A β̂) − ½ r_w ∂log v;
    β̂'s stationarity (Ãᵀ r_w = Λ⁻¹β̂, Ã = √w A) gives B = M⁻¹ [(∂Ã)ᵀ r_w + Ãᵀ J₀] and the
    bins' rows of the MAP's (projected) Jacobian J_r = J₀ − Ã B; its β̂ rows are B/√Λ and
    C_θ = (JᵀJ)⁺ with θ's prior rows (a direction that nothing identifies adds nothing).
    All O(N·(6 + m)·q) from :class:`Design` and the rows' support: no derivative of the solve."""
    kappa2 = h["slew_error"] ** 2
    dlogv = jnp.where(data.mask[..., None], 2 * kappa2 * m.trans[..., None] * d.dt, 0.0)
    dlogv = dlogv / m.nv[..., None]
    At, p = m.At, structure.n_beta
    J0 = -m.sw[..., None] * (d.df + rows_times(d.dA, m.beta))
    J0 = J0 - 0.5 * m.rw[..., None] * dlogv
    g = rows_t_times(d.dA, m.sw * m.rw, p)
    g = g - 0.5 * rows_t_times(At, m.rw[..., None] * dlogv, p)
    g = g + rows_t_times(At, J0, p)
    B = solve_banded(m.factor, structure.hold_bands, g, unroll=1)  # (p, q) M⁻¹g
    Jr = J0 - rows_times(At, B)
    Jb = B / jnp.sqrt(beta_prior_var(h, structure, data))[:, None]
    JtJ = jnp.einsum("njq,njr->qr", Jr, Jr) + Jb.T @ Jb + d.dprior.T @ d.dprior
    C = jnp.linalg.pinv(JtJ, hermitian=True)
    return jnp.einsum("pq,qr,pr->p", B, C, B), jnp.einsum("njq,qr,njr->nj", Jr, C, Jr)


def theta_terms(z, h: Hyper, structure: ModelStructure, data: RecordData, space):
    """``(var_β (p,), lev_θ (N, 2))`` at θ = z and ``h`` (:func:`theta_part`), traceable."""
    d = design_derivatives(z, structure, data, space)
    return theta_part(d, moments(space.to_values(z), h, structure, data), h, structure, data)
