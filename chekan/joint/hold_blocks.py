r"""The normal equations of the joint model assembled straight into the hold blocks.

The only assembly of the model's normal equations in production (the MAP's residual and
its Jacobian, the EM, the derived quantities, the log-density and the β draws); a dense
assembly of the same equations is kept as the tests' oracle (``tests/dense_oracle.py``,
which has the dense maths), and they agree to round-off. The blocks take the form that the
block elimination takes (:class:`inference.normal_eq.BlockNormalEquations`): for every
hold k the 3 × 3 block of its (o₁ₖ, o₂ₖ, δₖ), the block coupling it to hold k − 1, its rows
against the dense variables (c, d, ν of each system and the shared angle terms ζ), and the
dense block. Neither M (p × p) nor the lag-mixing matrix G (N × H) is formed.

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
(:func:`unsettled_carry`, a linear recurrence over the holds) is one associative scan over
all their columns.

What depends on θ alone (the equilibria, the slews' paths, the lag weights: :func:`bin_design`)
is computed apart from what the hyperparameters weigh (:func:`normal_equations_at`), so
the EM, whose updates change h only, computes it once per stage.

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
    lag_weights,
    noise_var,
    sensor_params,
    slew_path,
    transient_amplitude,
)
from chekan.physics import sensor as fm
from chekan.physics.units import ARCSEC_PER_RAD
from inference.barrier import fusion_barrier
from inference.normal_eq import BlockNormalEquations


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
    r"""Rₖ for columns E, Mv (H, J): the part of the lag state after slew k left over from
    holds that had not settled (deterministic part only; the β terms keep the one-hold
    carry, the rest is second order, ρ·σ_o). With y₀,ₖ = wₚᵣₑᵥ,ₖ yₑₙd,ₖ₋₁ + Mvₖ,
    yₑₙd,ₖ₋₁ = Eₖ₋₁ + (y₀,ₖ₋₁ − Eₖ₋₁) ρₖ₋₁, ρ = e^{−T/τ} (T: slew end to hold end) and
    dₖ = y₀,ₖ − Eₖ (d₀ = 0, hold 0 settled), aₖ = wₚᵣₑᵥ,ₖ ρₖ₋₁ and
    cₖ = wₚᵣₑᵥ,ₖ Eₖ₋₁ + Mvₖ − Eₖ, the
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


class BinDesign(NamedTuple):
    """The bins' prediction ȳ = f + Aβ at θ by its per-bin terms (:func:`bin_design`): what
    does not depend on the hyperparameters (the equilibrium solves, the slews' paths, the
    lag weights), computed once where h alone changes (the EM's updates)."""

    hold: jax.Array  # (N,) int: the bin's hold
    a: jax.Array  # (N,) G's entry at the bin's hold
    b: jax.Array  # (N,) G's entry at the hold before (0 in the first hold)
    c: jax.Array  # (N,) the weight of the lag state after the slew
    Q: jax.Array  # (N, nq) the columns of (cⱼ, dⱼ, νⱼ)
    s: jax.Array  # (H, 2) the holds' angle sensitivity per arcsec
    U: jax.Array | None  # (H, L, 2) the slews' share of the angle columns, per hold
    r: jax.Array  # (N, 2) residual y − f (0 where masked)
    trans: jax.Array  # (N, 2) the transient left in each bin (what κ scales)
    x_hold: jax.Array | None  # (H, 3, X) what the X-response columns of hold k's bins mix


def bin_design(v: dict, structure: ModelStructure, data: RecordData) -> BinDesign:
    """:class:`BinDesign` at θ (values ``v``): aᵢ = 1 − wᵢ, bᵢ = wᵢ·wₚᵣₑᵥ,ₖᵢ (0 in the first
    hold), cᵢ = wᵢ and fᵢ = aᵢEₖᵢ + bᵢEₖᵢ₋₁ + cᵢ(Mv + R)ₖᵢ (module docstring). The
    X-response columns mix per-hold terms the same way, Φᵢ = aᵢΦₖᵢ + bᵢΦₖᵢ₋₁ + cᵢΦ⁺ₖᵢ (Φ⁺:
    their share of the lag state after the slew); ``x_hold`` keeps (Φₖ, Φₖ₋₁, Φ⁺ₖ)."""
    (E, s, state, jump, wprev), U, x_state = _hold_terms(v, structure, data)
    k = data.bin_hold
    kp = jnp.maximum(k - 1, 0)
    w = lag_weights(v["tau_s"], data)
    a = 1.0 - w
    b = jnp.where(k > 0, w * wprev[k], 0.0)
    f = a[:, None] * E[k] + b[:, None] * E[kp] + w[:, None] * state[k]
    r = jnp.where(data.mask, data.y - f, 0.0)
    cols = [jnp.ones((k.shape[0], 1)), data.drift_basis]
    x_hold = None
    if structure.n_x_response:
        xb = data.x_basis
        cols.append(a[:, None] * xb[k] + b[:, None] * xb[kp] + w[:, None] * x_state[k])
        x_hold = jnp.stack([xb, _prev(xb), x_state], axis=1)
    slew_U = U if (structure.n_systematic or structure.n_x_response) else None
    trans = w[:, None] * jump[k]
    Q = jnp.concatenate(cols, axis=1)
    # materialised: fused into the segment sums' products, XLA recomputed them per column
    return fusion_barrier(BinDesign(k, a, b, w, Q, s, slew_U, r, trans, x_hold))


class _HoldSums(NamedTuple):
    """Per hold and system, the weighted sums over the hold's bins (:func:`_hold_sums`)."""

    d: jax.Array  # (H, 2) the diagonal of GᵀWⱼG
    e: jax.Array  # (H, 2) its entry (k, k − 1)
    bo: jax.Array  # (H, 2) GᵀWⱼr
    QG: jax.Array  # (H, nq, 2) (QᵀWⱼG)ᵀ
    Sca: jax.Array  # (H, 2) Σ W c a
    Scb: jax.Array  # (H, 2) Σ W c b
    Scc: jax.Array  # (H, 2) Σ W c²
    Scr: jax.Array  # (H, 2) Σ W c r
    ScQ: jax.Array  # (H, nq, 2) Σ W c Q


def _hold_sums(t: BinDesign, W, Wr, H: int) -> _HoldSums:
    """One segment sum over the bins of each hold of the weighted per-bin products
    (module docstring), and GᵀWG's tridiagonal from them. The X-response columns' sums
    come from the holds' 3 × 3 sums of (a, b, c) and ``x_hold``:
    Σₖ W a Φ = Σₖ W a² Φₖ + Σₖ W a b Φₖ₋₁ + Σₖ W a c Φ⁺ₖ, likewise for b and c (a segment sum
    of 3 + D columns per system instead of 3 + D + X)."""
    a, b, c = t.a, t.b, t.c
    X = 0 if t.x_hold is None else t.x_hold.shape[-1]
    Q = t.Q[:, : t.Q.shape[1] - X]  # the columns that are the bin's own: c and d
    nq = Q.shape[1]
    abc = jnp.stack([a, b, c], axis=1)  # (N, 3)
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
    S = jax.ops.segment_sum(per_bin, t.hold, num_segments=H)  # (H, 9 + 3nq, 2)
    Sa2, Sb2, Sab, Sca, Scb, Scc, Sar, Sbr, Scr = (S[:, i] for i in range(9))
    SaQ, SbQ, ScQ = (S[:, 9 + i * nq : 9 + (i + 1) * nq] for i in range(3))
    if t.x_hold is not None:  # (H, 3, 3, 2): Σ W (a, b, c)(a, b, c)ᵀ per hold and system
        M3 = jnp.stack(
            [jnp.stack(r, axis=1) for r in ((Sa2, Sab, Sca), (Sab, Sb2, Scb), (Sca, Scb, Scc))],
            axis=1,
        )
        SxQ = jnp.einsum("hrsj,hsx->hrxj", M3, t.x_hold)  # (H, 3, X, 2)
        SaQ, SbQ, ScQ = (
            jnp.concatenate([q, SxQ[:, i]], axis=1) for i, q in enumerate((SaQ, SbQ, ScQ))
        )
    d = Sa2 + _next(Sb2)
    return _HoldSums(d, Sab, Sar + _next(Sbr), SaQ + _next(SbQ), Sca, Scb, Scc, Scr, ScQ)


def _band_blocks(d, e, s):
    """The holds' 3 × 3 blocks of (o₁ₖ, o₂ₖ, δₖ): the diagonal and the block (k, k − 1), from
    GᵀWⱼG's tridiagonal (``d``, ``e``, (H, 2)) and the angle sensitivities ``s`` (H, 2)."""
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
    return diag, sub


def _angle_blocks(t: BinDesign, sums: _HoldSums, structure: ModelStructure, data: RecordData):
    """The shared angle terms' (e, ζ) parts: the holds' rows against them (o₁, o₂, δ),
    (c, d, ν)ⱼ's (QGsE, per system), their own block and right-hand side."""
    s, U, Eb, QG, bo = t.s, t.U, data.angle_basis, sums.QG, sums.bo
    s1, s2 = s[:, 0], s[:, 1]
    bdt = s1 * bo[:, 0] + s2 * bo[:, 1]
    GsE = [_shifted_rows(sums.d[:, j], sums.e[:, j], s[:, j, None] * Eb) for j in range(2)]
    SdE = s1[:, None] * GsE[0] + s2[:, None] * GsE[1]
    EE = Eb.T @ SdE
    QGsE = [jnp.einsum("hq,hl->ql", QG[..., j] * s[:, j, None], Eb) for j in range(2)]
    gx = Eb.T @ bdt
    L = structure.n_angle_cols
    ee = jnp.zeros((L, L))
    if structure.n_systematic:  # the slews' share (tests/dense_oracle.py slew_angle_terms)
        assert U is not None
        GtWP = sums.Sca[:, None, :] * U + _next(sums.Scb[:, None, :] * U)  # (H, L, 2)
        sGtWP = jnp.einsum("hj,hlj->hl", s, GtWP)
        GsE = [GsE[j] + GtWP[..., j] for j in range(2)]
        SdE = SdE + sGtWP
        QWP = jnp.einsum("hqj,hlj->jql", sums.ScQ, U)
        QGsE = [QGsE[j] + QWP[j] for j in range(2)]
        cross = Eb.T @ sGtWP
        ee = cross + cross.T + jnp.einsum("hj,hlj,hmj->lm", sums.Scc, U, U)
        gx = gx + jnp.einsum("hlj,hj->l", U, sums.Scr)
    return (GsE[0], GsE[1], SdE), QGsE, EE + ee, gx


def normal_equations_at(
    t: BinDesign, h: dict, structure: ModelStructure, data: RecordData
) -> tuple[BlockNormalEquations, BinTerms]:
    """rᵀWr, the hold blocks and the dense block of AᵀWA, and AᵀWr (module docstring) at the
    hyperparameters ``h`` from the bins' terms at θ (:func:`bin_design`), with the per-bin
    terms (:class:`BinTerms`). The variables' order is that of
    :attr:`ModelStructure.hold_bands` (o₁ₖ, o₂ₖ, δₖ) and, for the dense block, β's order
    without them: (q₁, q₂, e, ζ) with qⱼ = (cⱼ, dⱼ, νⱼ)."""
    mask = data.mask
    nv = noise_var(h, data, t.trans)
    W = jnp.where(mask, 1.0 / nv, 0.0)
    Wr = W * t.r
    Q, s = t.Q, t.s
    nq, H, L = Q.shape[1], structure.n_holds, structure.n_angle_cols
    sums = _hold_sums(t, W, Wr, H)
    diag, sub = _band_blocks(sums.d, sums.e, s)
    QG, bo = sums.QG, sums.bo
    Zq = jnp.zeros((H, nq))
    rows = [
        [QG[..., 0], Zq],
        [Zq, QG[..., 1]],
        [QG[..., 0] * s[:, 0, None], QG[..., 1] * s[:, 1, None]],
    ]
    QQ = jnp.einsum("nq,nj,nr->jqr", Q, W, Q)
    bq = Q.T @ Wr  # (nq, 2)
    bdt = s[:, 0] * bo[:, 0] + s[:, 1] * bo[:, 1]
    Zqq = jnp.zeros((nq, nq))
    if L:
        extras, QGsE, EE, gx = _angle_blocks(t, sums, structure, data)
        for row, extra in zip(rows, extras, strict=True):
            row.append(extra)
        dense = jnp.block(
            [[QQ[0], Zqq, QGsE[0]], [Zqq, QQ[1], QGsE[1]], [QGsE[0].T, QGsE[1].T, EE]]
        )
        g_dense = jnp.concatenate([bq[:, 0], bq[:, 1], gx])
    else:
        dense = jnp.block([[QQ[0], Zqq], [Zqq, QQ[1]]])
        g_dense = jnp.concatenate([bq[:, 0], bq[:, 1]])
    cross_rows = jnp.stack([jnp.concatenate(row, axis=1) for row in rows], axis=1)
    g_band = jnp.stack([bo[:, 0], bo[:, 1], bdt], axis=1)
    logdet_n = jnp.sum(jnp.where(mask, jnp.log(nv), 0.0))
    ne = BlockNormalEquations(
        jnp.sum(Wr * t.r), diag, sub, cross_rows, dense, g_band, g_dense, logdet_n, jnp.sum(mask)
    )
    terms = BinTerms(t.hold, t.a, t.b, t.c, Q, s, t.U, t.r, nv, t.trans)
    return ne, terms


def block_normal_equations(
    v: dict, h: dict, structure: ModelStructure, data: RecordData
) -> tuple[BlockNormalEquations, BinTerms]:
    """:func:`normal_equations_at` of :func:`bin_design` at θ (values ``v``) and ``h``."""
    return normal_equations_at(bin_design(v, structure, data), h, structure, data)


def apply_blocks(beta, t: BinTerms, structure: ModelStructure, data: RecordData):
    """A·β as (N, 2) from the per-bin terms:
    system j's share is Q qⱼ + aᵢuⱼ[kᵢ] + bᵢuⱼ[kᵢ − 1] + cᵢ(Uⱼζ)[kᵢ] with
    uⱼ = oⱼ + sⱼ∘(δ + Eζ). Rows of padding bins (no data, zero weight) are not zero (as they
    are in the dense oracle's): read them through ``data.mask``."""
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
