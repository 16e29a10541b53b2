r"""The normal equations of the joint model assembled straight into the hold blocks.

The same equations as :func:`chekan.joint.likelihood.normal_equations` (its docstring has the
maths), in the form that the block elimination of the marginal log-density and of the β
draws takes (:class:`inference.normal_eq.BlockNormalEquations`): for every hold k the
3 × 3 block of its (o₁ₖ, o₂ₖ, δₖ), the block coupling it to hold k − 1, its rows against
the dense variables (c, d, ν of each system and the shared angle terms ζ), and the dense
block. Neither M (p × p) nor the lag-mixing matrix G (N × H) is formed.

Row i of G has two entries: aᵢ = 1 − wᵢ at the bin's own hold kᵢ and bᵢ = wᵢ·wₚᵣₑᵥ,ₖᵢ at
the hold before (``data.prev`` is the hold before ``data.own``, as
:func:`chekan.joint.binning.prepare_record` lays bins out; that is what makes the holds'
part block-tridiagonal, :attr:`~chekan.joint.layout.ModelStructure.hold_bands`); cᵢ = wᵢ
weighs the lag state after the slew (the slews' share of the shared columns). Every product
with G is then a sum over the bins of a hold: one segment sum of the weighted per-bin
products gives, per hold and system,

    Σ W a², Σ W b², Σ W a b, Σ W c·(a, b, c), Σ W (a, b, c)·r, Σ W (a, b, c)·Q,

and Gᵀ W G is tridiagonal: its diagonal at k is Σₖ W a² + Σₖ₊₁ W b², its entry (k, k − 1)
is Σₖ W a b (Σₖ: over the bins of hold k). Products with the angle basis E (H × L) through
that tridiagonal matrix are three shifted row products. The unsettled carry of the hold
equilibria, of the holds' angle shifts and of the X-response terms
(:func:`chekan.joint.likelihood._unsettled_carry`, a linear recurrence over the holds) is
one associative scan over all their columns.

The EM's E-step reads the same blocks (:func:`block_moments`): β̂ and diag(M⁻¹) from M's
block factor and the entries of M⁻¹ on M's pattern, the design A by the support of its rows
(:class:`BinRows`: a bin touches its hold's and the previous hold's (o₁, o₂, δ) and the
dense variables) and the bins' leverages from both.

Values: the blocks equal those gathered from the dense M to round-off (tests).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import chekan.jaxconfig  # noqa: F401
from chekan.joint.layout import ModelStructure, RecordData
from chekan.joint.likelihood import (
    beta_prior_var,
    lag_weights,
    noise_var,
    sensor_params,
    slew_path,
    transient_amplitude,
)
from chekan.physics import sensor as fm
from chekan.physics.units import ARCSEC_PER_RAD
from inference.barrier import fusion_barrier
from inference.normal_eq import (
    BandedFactor,
    BlockNormalEquations,
    banded_factor_blocks,
    selected_inverse,
    solve_banded_transposed,
    split_prior,
)


class BinTerms(NamedTuple):
    """What :func:`apply_blocks` and the draws need besides the blocks."""

    hold: jax.Array  # (N,) int: the bin's hold
    a: jax.Array  # (N,) G's entry at the bin's hold
    b: jax.Array  # (N,) G's entry at the hold before (0 in the first hold)
    c: jax.Array  # (N,) the weight of the lag state after the slew
    Q: jax.Array  # (N, nq) the columns of (cⱼ, dⱼ, νⱼ)
    s: jax.Array  # (H, 2) the holds' angle sensitivity per arcsec
    U: jax.Array | None  # (H, L, 2) the slews' share of the angle columns, per hold
    r: jax.Array  # (N, 2) residual y − f (0 where masked)
    nv: jax.Array  # (N, 2) variance of each bin mean
    trans: jax.Array  # (N, 2) the transient left in each bin (what κ scales)


def _next(x):
    """x[k + 1] along the first axis (zero after the last hold)."""
    return jnp.concatenate([x[1:], jnp.zeros_like(x[:1])])


def _prev(x):
    """x[k − 1] along the first axis (zero before the first hold)."""
    return jnp.concatenate([jnp.zeros_like(x[:1]), x[:-1]])


def unsettled_carry(E, Mv, wprev, rho):
    """Rₖ of :func:`chekan.joint.likelihood._unsettled_carry` for columns E, Mv (H, J): the
    recurrence dₖ = aₖdₖ₋₁ + cₖ (d₀ = 0) as an associative scan of the affine maps
    x ↦ aₖx + cₖ (log₂ H elementwise passes over (H, J) instead of an H × H product matrix
    built by a cumulative product); Rₖ = aₖdₖ₋₁."""
    zero = jnp.zeros_like(E[:1])
    a = jnp.concatenate([jnp.zeros(1), wprev[1:] * rho[:-1]])[:, None]
    c = jnp.concatenate([zero, wprev[1:, None] * E[:-1] + Mv[1:] - E[1:]])

    def compose(first, then):  # x ↦ a₂(a₁x + c₁) + c₂
        (a1, c1), (a2, c2) = first, then
        return a1 * a2, a2 * c1 + c2

    _, d = jax.lax.associative_scan(compose, (a, c))
    return a * _prev(d)


def _hold_terms(v: dict, structure: ModelStructure, data: RecordData):
    """Per hold: E (H, 2), s (H, 2), the lag state after each slew (Mv + R, H × 2), the
    transient amplitude, and where the model has them the slews' share of the angle columns
    U (H, L, 2) and of the X-response terms (H, X)."""
    p = sensor_params(v, data)
    tx, ty = data.hold_tx, data.hold_ty
    dx, dy = data.hold_dir[:, 0], data.hold_dir[:, 1]

    def eq(h):
        return fm.equilibrium_readings(p, tx + h * dx, ty + h * dy)

    E, S = fusion_barrier(jax.jvp(eq, (jnp.zeros_like(tx),), (jnp.ones_like(tx),)))
    s = -S / ARCSEC_PER_RAD
    tau = v["tau_s"]
    wm, Em, dEm = slew_path(v, data)
    wprev = 1.0 - wm.sum(axis=1)
    Mv = jnp.einsum("hm,jhm->hj", wm, Em)
    rho = jnp.exp(-data.hold_T / tau)
    H = E.shape[0]
    slews = bool(structure.n_systematic or structure.n_x_response)
    if not slews:
        R = unsettled_carry(E, Mv, wprev, rho)
        x_state, U = None, None
    else:  # the holds' equilibria, angle shifts and X terms carried in one scan
        dMv = jnp.einsum("hm,jhm,hmq->hqj", wm, -dEm / ARCSEC_PER_RAD, data.mv_angle_basis)
        dE = s[:, None, :] * data.angle_basis[:, :, None]
        x_mv = jnp.einsum("hm,hmx->hx", wm, data.mv_x_basis)
        L = dMv.shape[1]
        carry = unsettled_carry(
            jnp.concatenate([E, dE.reshape(H, -1), data.x_basis], axis=1),
            jnp.concatenate([Mv, dMv.reshape(H, -1), x_mv], axis=1),
            wprev,
            rho,
        )
        R = carry[:, :2]
        U = dMv + carry[:, 2 : 2 + 2 * L].reshape(H, L, 2)
        x_state = x_mv + carry[:, 2 + 2 * L :]
    jump = transient_amplitude(E, wprev, wm, Em, R)
    return fusion_barrier((E, s, Mv + R, jump, wprev)), U, x_state


def _shifted_rows(d, e, sE):
    """(GᵀWG diag(s) E) for one system by rows: the tridiagonal GᵀWG (diagonal d, entries
    (k, k − 1) e) times sE = diag(s) E (H, L)."""
    return d[:, None] * sE + e[:, None] * _prev(sE) + _next(e[:, None] * sE)


def block_normal_equations(
    v: dict, h: dict, structure: ModelStructure, data: RecordData
) -> tuple[BlockNormalEquations, BinTerms]:
    """rᵀWr, the hold blocks and the dense block of AᵀWA, and AᵀWr (module docstring), with
    the per-bin terms (:class:`BinTerms`). The variables' order is that of
    :attr:`ModelStructure.hold_bands` (o₁ₖ, o₂ₖ, δₖ) and, for the dense block, β's order
    without them: (q₁, q₂, e, ζ) with qⱼ = (cⱼ, dⱼ, νⱼ)."""
    (E, s, state, jump, wprev), U, x_state = _hold_terms(v, structure, data)
    k = data.bin_hold
    kp = jnp.maximum(k - 1, 0)
    w = lag_weights(v["tau_s"], data)
    a = 1.0 - w
    b = jnp.where(k > 0, w * wprev[k], 0.0)
    c = w
    f = a[:, None] * E[k] + b[:, None] * E[kp] + w[:, None] * state[k]
    trans = w[:, None] * jump[k]
    mask = data.mask
    nv = noise_var(h, data, trans)
    W = jnp.where(mask, 1.0 / nv, 0.0)
    r = jnp.where(mask, data.y - f, 0.0)
    cols = [jnp.ones((k.shape[0], 1)), data.drift_basis]
    if structure.n_x_response:
        xb = data.x_basis
        cols.append(a[:, None] * xb[k] + b[:, None] * xb[kp] + c[:, None] * x_state[k])
    Q = jnp.concatenate(cols, axis=1)
    nq, H, L = Q.shape[1], structure.n_holds, structure.n_angle_cols
    abc = jnp.stack([a, b, c], axis=1)  # (N, 3)
    Wr = W * r
    per_bin = jnp.concatenate(
        [
            jnp.stack([a * a, b * b, a * b, c * a, c * b, c * c], axis=1)[:, :, None] * W[:, None],
            abc[:, :, None] * Wr[:, None, :],
            (abc[:, :, None, None] * Q[:, None, :, None] * W[:, None, None, :]).reshape(
                -1, 3 * nq, 2
            ),
        ],
        axis=1,
    )
    S = jax.ops.segment_sum(per_bin, k, num_segments=H)  # (H, 9 + 3nq, 2)
    Sa2, Sb2, Sab, Sca, Scb, Scc, Sar, Sbr, Scr = (S[:, i] for i in range(9))
    SaQ, SbQ, ScQ = (S[:, 9 + i * nq : 9 + (i + 1) * nq] for i in range(3))
    d = Sa2 + _next(Sb2)  # (H, 2) diagonal of GᵀWⱼG
    e = Sab  # (H, 2) its entry (k, k − 1)
    bo = Sar + _next(Sbr)  # (H, 2) GᵀWⱼr
    QG = SaQ + _next(SbQ)  # (H, nq, 2) (QᵀWⱼG)ᵀ
    sp = _prev(s)
    d1, d2, e1, e2 = d[:, 0], d[:, 1], e[:, 0], e[:, 1]
    s1, s2, p1, p2 = s[:, 0], s[:, 1], sp[:, 0], sp[:, 1]
    zero = jnp.zeros_like(d1)
    diag = jnp.stack(
        [
            jnp.stack([d1, zero, d1 * s1], axis=1),
            jnp.stack([zero, d2, d2 * s2], axis=1),
            jnp.stack([d1 * s1, d2 * s2, d1 * s1 * s1 + d2 * s2 * s2], axis=1),
        ],
        axis=1,
    )
    sub = jnp.stack(
        [
            jnp.stack([e1, zero, e1 * p1], axis=1),
            jnp.stack([zero, e2, e2 * p2], axis=1),
            jnp.stack([e1 * s1, e2 * s2, e1 * s1 * p1 + e2 * s2 * p2], axis=1),
        ],
        axis=1,
    )
    Zq = jnp.zeros((H, nq))
    rows = [
        [QG[..., 0], Zq],
        [Zq, QG[..., 1]],
        [QG[..., 0] * s1[:, None], QG[..., 1] * s2[:, None]],
    ]
    QQ = jnp.einsum("nq,nj,nr->jqr", Q, W, Q)
    bq = Q.T @ Wr  # (nq, 2)
    bdt = s1 * bo[:, 0] + s2 * bo[:, 1]
    if L:
        Eb = data.angle_basis
        GsE = [_shifted_rows(d[:, j], e[:, j], s[:, j, None] * Eb) for j in range(2)]
        SdE = s1[:, None] * GsE[0] + s2[:, None] * GsE[1]
        EE = Eb.T @ SdE
        QGsE = [jnp.einsum("hq,hl->ql", QG[..., j] * s[:, j, None], Eb) for j in range(2)]
        gx = Eb.T @ bdt
        ee = jnp.zeros((L, L))
        if structure.n_systematic:  # the slews' share (chekan.joint.likelihood.slew_angle_terms)
            GtWP = Sca[:, None, :] * U + _next(Scb[:, None, :] * U)  # (H, L, 2)
            sGtWP = jnp.einsum("hj,hlj->hl", s, GtWP)
            GsE = [GsE[j] + GtWP[..., j] for j in range(2)]
            SdE = SdE + sGtWP
            QWP = jnp.einsum("hqj,hlj->jql", ScQ, U)
            QGsE = [QGsE[j] + QWP[j] for j in range(2)]
            cross = Eb.T @ sGtWP
            ee = cross + cross.T + jnp.einsum("hj,hlj,hmj->lm", Scc, U, U)
            gx = gx + jnp.einsum("hlj,hj->l", U, Scr)
        for row, extra in zip(rows, (GsE[0], GsE[1], SdE), strict=True):
            row.append(extra)
        Zqq = jnp.zeros((nq, nq))
        dense = jnp.block(
            [
                [QQ[0], Zqq, QGsE[0]],
                [Zqq, QQ[1], QGsE[1]],
                [QGsE[0].T, QGsE[1].T, EE + ee],
            ]
        )
        g_dense = jnp.concatenate([bq[:, 0], bq[:, 1], gx])
    else:
        dense = jnp.block([[QQ[0], jnp.zeros((nq, nq))], [jnp.zeros((nq, nq)), QQ[1]]])
        g_dense = jnp.concatenate([bq[:, 0], bq[:, 1]])
    cross_rows = jnp.stack([jnp.concatenate(row, axis=1) for row in rows], axis=1)
    g_band = jnp.stack([bo[:, 0], bo[:, 1], bdt], axis=1)
    ne = BlockNormalEquations(
        jnp.sum(Wr * r),
        diag,
        sub,
        cross_rows,
        dense,
        g_band,
        g_dense,
        jnp.sum(jnp.where(mask, jnp.log(nv), 0.0)),
        jnp.sum(mask),
    )
    slew_U = U if (structure.n_systematic or structure.n_x_response) else None
    return ne, BinTerms(k, a, b, c, Q, s, slew_U, r, nv, trans)


def apply_blocks(beta, t: BinTerms, structure: ModelStructure, data: RecordData):
    """A·β as (N, 2) from the per-bin terms (:func:`chekan.joint.likelihood.apply_A`):
    system j's share is Q qⱼ + aᵢuⱼ[kᵢ] + bᵢuⱼ[kᵢ − 1] + cᵢ(Uⱼζ)[kᵢ] with
    uⱼ = oⱼ + sⱼ∘(δ + Eζ). Rows of padding bins (no data, zero weight) are not zero, as
    they are in :func:`~chekan.joint.likelihood.apply_A`: read them through ``data.mask``."""
    blocks = structure.beta_blocks
    nq, H = structure.n_q, structure.n_holds
    shared = np.concatenate([blocks["encoder"], blocks["angle_systematic"]])
    zeta = beta[shared]
    angle = beta[blocks["angle_error"]] + data.angle_basis @ zeta
    q = beta[: 2 * nq].reshape(2, nq).T
    u = beta[blocks["hold_offset"]].reshape(2, H).T + t.s * angle[:, None]
    kp = jnp.maximum(t.hold - 1, 0)
    y = t.Q @ q + t.a[:, None] * u[t.hold] + t.b[:, None] * u[kp]
    if t.U is not None:
        y = y + t.c[:, None] * jnp.einsum("hqj,q->hj", t.U, zeta)[t.hold]
    return y


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


def bin_rows(t: BinTerms, structure: ModelStructure, data: RecordData) -> BinRows:
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


def block_moments(v: dict, h: dict, structure: ModelStructure, data: RecordData) -> BlockMoments:
    """β̂, diag(M⁻¹), the whitened rows, residuals and leverages at θ (values ``v``) and h,
    from the hold blocks and the entries of M⁻¹ on M's pattern
    (:func:`inference.normal_eq.selected_inverse`): a bin's row touches only the (o₁, o₂, δ)
    of its hold and of the hold before and the dense variables, so neither M nor M⁻¹
    (p × p) is formed. Values: those of the dense solve to round-off (tests)."""
    blocks, t = block_normal_equations(v, h, structure, data)
    bands, dense_ix = structure.hold_bands, _dense_columns(structure)
    pv = split_prior(beta_prior_var(h, structure, data), bands)
    f = banded_factor_blocks(blocks, *pv, unroll=1)
    beta = solve_banded_transposed(f, bands, jnp.concatenate([f.y, f.c]), unroll=1)
    Z = selected_inverse(f, unroll=1)
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
