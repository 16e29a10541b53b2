r"""The joint model's normal equations assembled densely: the tests' oracle.

Production assembles the normal equations by hold only (:mod:`chekan.joint.hold_blocks`,
β | θ: :mod:`chekan.joint.beta_posterior`); this module keeps the dense assembly of the same
equations (the design A (N, 2, p), M = AᵀWA + Λ⁻¹ (p × p) and its Cholesky factor), written
from the model's definition (:mod:`chekan.joint.likelihood`'s docstring) independently of
the hold blocks, so the tests can hold the blocks to it (β̂, log|M|, the residuals, the
quadratic form, the log-density, the E-step's moments, the derived quantities' inputs).
No production code imports it (``tests/test_hold_blocks.py`` checks).

**Blocks of AᵀWA.** β = (q₁, q₂, o₁, o₂, δ, e) with qⱼ = (cⱼ, dⱼ, νⱼ); with Qⱼ-weighted
products QQ = QᵀWⱼQ, QG = QᵀWⱼG, GG = GᵀWⱼG and s = sⱼ the blocks are QQ, QG, QG·diag(s),
GG, GG·diag(s), diag(s)·GG·diag(s) (summed over systems for δ) and their products with E.

**The slews' share of the angle columns** (:func:`slew_angle_terms`): the slews are read by
the same angle sensor, so its error is in the measured slew path too: the lag state after
slew k, Mvₖ = Σₘ wₖₘ E(θₖₘ), becomes Σₘ wₖₘ E(θₖₘ − Σ_q B_q(θₖₘ) ζ_q), whose ζ-derivative
∂Mvₖ/∂ζ enters the bins as Pᵢ = wᵢ · U_{k(i)}.

The model's shared pieces (sensor parameters, lag weights, slews, β's prior, the noise) are
re-exported from :mod:`chekan.joint.likelihood`, so a test reads both from here.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import chekan.jaxconfig  # noqa: F401
from chekan.joint.layout import ModelStructure, RecordData
from chekan.joint.likelihood import (
    SlewPath,
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
    NormalEquations,
    implicit_stationary_point,
    posterior_beta_normal,
)

__all__ = [
    "SlewPath",
    "apply_A",
    "beta_prior_var",
    "dense_design",
    "lag_weights",
    "linear_terms",
    "noise_var",
    "normal_equations",
    "predict",
    "sensor_params",
    "slew_angle_columns",
    "slew_angle_terms",
    "slew_path",
    "solve_beta",
    "transient_amplitude",
]


def linear_terms(v: dict, data: RecordData, slews: SlewPath | None = None):
    """The pieces of ȳ = f + Aβ: ``f`` (N, 2), lag mixing ``G`` (N, H) and the angle
    sensitivity per arcsec ``s`` (H, 2) = −∂E/∂θ / 206265.

    For system j the columns of A are [1, P, G, G·diag(sⱼ), G·diag(sⱼ)·E_enc] acting on
    (cⱼ, dⱼ, oⱼ, δ, e): everything factors through G (see the module docstring).
    ``slews``: :func:`slew_path` at ``v`` if already computed.
    """
    p = sensor_params(v, data)
    tx, ty = data.hold_tx, data.hold_ty
    dx, dy = data.hold_dir[:, 0], data.hold_dir[:, 1]  # each hold about its own axis

    def eq(h):
        return fm.equilibrium_readings(p, tx + h * dx, ty + h * dy)

    E, S = fusion_barrier(jax.jvp(eq, (jnp.zeros_like(tx),), (jnp.ones_like(tx),)))  # (H, 2)
    tau = v["tau_s"]
    # lag state at the end of each slew: previous hold's equilibrium + the slew's equilibria
    wm, Em, _ = slew_path(v, data) if slews is None else slews  # (H, M), (2, H, M)
    wprev = 1.0 - wm.sum(axis=1)  # (H,)
    Mv = jnp.einsum("hm,jhm->hj", wm, Em)  # (H, 2)
    w = lag_weights(tau, data)  # (N,) weight of the state at the end of the slew
    G = (1.0 - w)[:, None] * data.own + (w * (data.own @ wprev))[:, None] * data.prev
    R = _unsettled_carry(E, Mv, wprev, jnp.exp(-data.hold_T / tau))
    f = G @ E + w[:, None] * (data.own @ (Mv + R))
    jump = transient_amplitude(E, wprev, wm, Em, R)  # (H, 2)
    trans = w[:, None] * (data.own @ jump)  # (N, 2) transient left in each bin
    # computed once: left to itself XLA re-derives the equilibrium solve and its tangent
    # inside every consumer fusion, elementwise over (H, p) blocks (≈ 220 operations each)
    return fusion_barrier((f, G, -S / ARCSEC_PER_RAD, trans))


class SlewColumns(NamedTuple):
    """The slews' share of the systematic angle-error columns, factored by hold:
    Pᵢ = cᵢ · Uₖ₍ᵢ₎ for bin i in hold k(i) (:func:`slew_angle_terms`)."""

    weight: jax.Array
    """cᵢ (N,): the bin's lag weight wᵢ (0 for padding)."""
    per_hold: jax.Array
    """Uₖ = ∂Mvₖ/∂ζ (H, Q, 2): how ζ moves the lag state after slew k, pixels per unit ζ."""
    own: jax.Array
    """k(i) (N,) int: the bin's hold."""
    x_per_hold: jax.Array
    """Σₘ wₖₘ Φ(θₖₘ) (H, X): the X-response terms in the lag state after slew k."""

    def dense(self) -> jax.Array:
        """P (N, Q, 2) (reference and dense design)."""
        return self.weight[:, None, None] * self.per_hold[self.own]

    def times(self, zeta) -> jax.Array:
        """P ζ as (N, 2): one product per hold, then gathered."""
        return self.weight[:, None] * jnp.einsum("hqj,q->hj", self.per_hold, zeta)[self.own]


def slew_angle_terms(v: dict, data: RecordData, s, slews: SlewPath | None = None) -> SlewColumns:
    """How the shared terms (angle errors ζ, X response ν) move each bin through the lag
    state after every slew (factored by hold).

    The slews are read by the same angle sensor, so its error is in the measured slew path
    too: the lag state after slew k, Mvₖ = Σₘ wₖₘ E(θₖₘ), becomes
    Σₘ wₖₘ E(θₖₘ − Σ_q B_q(θₖₘ) ζ_q), whose ζ-derivative ∂Mvₖ/∂ζ enters the bins as
    Pᵢ = wᵢ · U_{k(i)}; B along the path is ``data.mv_angle_basis`` (the scale term θ/θ_max
    and the slews' own terms, :mod:`chekan.joint.angles`). Uₖ also holds ∂Rₖ/∂ζ, the
    unsettled carry (:func:`_unsettled_carry`) of the holds' shifts sₖ·Bₖ ζ and the slews':
    the hold-mixing G carries a hold's terms one hold on, as if it had settled, while the
    equilibria in f are carried exactly; a term shared by all rounds must move the
    prediction exactly as the equilibria it shifts, or where holds do not settle the data
    would seem to tell it apart from b (a scale error of the angle sensor looked measured
    at τ = 90 s). ``s`` (H, 2): the holds' angle sensitivity per arcsec (:func:`linear_terms`).
    """
    wm, _, dEm = slew_path(v, data) if slews is None else slews  # dEm (2, H, M) per rad
    tau = v["tau_s"]
    dMv = jnp.einsum("hm,jhm,hmq->hqj", wm, -dEm / ARCSEC_PER_RAD, data.mv_angle_basis)
    wprev, rho = 1.0 - wm.sum(axis=1), jnp.exp(-data.hold_T / tau)
    H, Q = dMv.shape[:2]
    dE = s[:, None, :] * data.angle_basis[:, :, None]  # (H, Q, 2) the holds' shifts
    carry = _unsettled_carry(dE.reshape(H, -1), dMv.reshape(H, -1), wprev, rho)
    w = lag_weights(tau, data)
    own = jnp.argmax(data.own, axis=1)  # the bin's hold (a row of zeros: padding)
    x_mv = jnp.einsum("hm,hmx->hx", wm, data.mv_x_basis)
    x_carry = _unsettled_carry(data.x_basis, x_mv, wprev, rho)
    return SlewColumns(
        w * jnp.sum(data.own, axis=1), dMv + carry.reshape(H, Q, 2), own, x_mv + x_carry
    )


def slew_angle_columns(v: dict, data: RecordData, slews: SlewPath | None = None) -> jax.Array:
    """P (N, Q, 2), dense (:func:`slew_angle_terms`; reference and tests)."""
    slews = slew_path(v, data) if slews is None else slews
    _, _, s, _ = linear_terms(v, data, slews)
    return slew_angle_terms(v, data, s, slews).dense()


def _unsettled_carry(E, Mv, wprev, rho):
    """Rₖ: the part of the lag state after slew k left over from holds that had not settled.

    y₀,ₖ = wₚᵣₑᵥ,ₖ yₑₙd,ₖ₋₁ + Mvₖ with yₑₙd,ₖ₋₁ = Eₖ₋₁ + (y₀,ₖ₋₁ − Eₖ₋₁) ρₖ₋₁,
    ρ = e^{−T/τ} (T: slew end to hold end); Rₖ = y₀,ₖ − wₚᵣₑᵥ,ₖ Eₖ₋₁ − Mvₖ (R₀ = 0, hold 0
    settled). Deterministic part only: the β terms keep the one-hold carry (the rest is
    second order, ρ·σ_o).

    In dₖ = y₀,ₖ − Eₖ the recurrence is linear, dₖ = aₖ dₖ₋₁ + cₖ (d₀ = 0) with
    aₖ = wₚᵣₑᵥ,ₖ ρₖ₋₁ and cₖ = wₚᵣₑᵥ,ₖ Eₖ₋₁ + Mvₖ − Eₖ, so dₖ = Σ_{i≤k} (Π_{i<l≤k} aₗ) cᵢ
    and Rₖ = aₖ dₖ₋₁: a product matrix times c, not a loop over holds (a loop costs a few
    kernel launches per hold in every evaluation).
    """
    H, J = E.shape
    zero = jnp.zeros((1, J))
    a = jnp.concatenate([jnp.zeros(1), wprev[1:] * rho[:-1]])  # a₀ unused (d₀ = 0)
    c = jnp.concatenate([zero, wprev[1:, None] * E[:-1] + Mv[1:] - E[1:]])
    after = np.triu(np.ones((H, H), dtype=bool), 1)  # [i, l]: l > i
    # T[i, k] = Π_{i<l≤k} aₗ for k ≥ i, 0 for k < i
    T = np.triu(np.ones((H, H))) * jnp.cumprod(jnp.where(after, a[None, :], 1.0), axis=1)
    d = T.T @ c
    return a[:, None] * jnp.concatenate([zero, d[:-1]])


def q_columns(G, data: RecordData, P: SlewColumns | None = None) -> jax.Array:
    """The columns shared by both systems that do not go through the hold terms:
    [1, P, G·Φ + w·Φ_slew] for (cⱼ, dⱼ, νⱼ) (Φ: the X-response terms at the holds and
    along the slews, which settle in with the lag like any equilibrium change;
    :mod:`chekan.joint.xresponse`; ``P`` carries the slews' share)."""
    cols = [jnp.ones((G.shape[0], 1)), data.drift_basis]
    if data.x_basis.shape[1]:
        x = G @ data.x_basis
        if P is not None:
            x = x + P.weight[:, None] * P.x_per_hold[P.own]
        cols.append(x)
    return jnp.concatenate(cols, axis=1)


def _local_columns(G, s_j, Q, enc, P_j=None):
    """System j's columns [Q, G, G·diag(sⱼ), G·diag(sⱼ)·E (+ Pⱼ)] (for A·β products)."""
    Gs = G * s_j[None, :]
    X = Gs @ enc if P_j is None else Gs @ enc + P_j
    return jnp.concatenate([Q, G, Gs, X], axis=1)


def apply_A(beta, G, s, structure: ModelStructure, data: RecordData, P: SlewColumns | None = None):
    """A·β as (N, 2), without forming A (``P``: :func:`slew_angle_terms` or None):
    system j's share is Q qⱼ + G (oⱼ + sⱼ∘(δ + E ζ)) + Pⱼ ζ (:func:`_local_columns`),
    both systems at once (on the trailing axis)."""
    Q = q_columns(G, data, P)
    sp = _hold_sparse(G, data)
    b = structure.beta_blocks
    nq, H = Q.shape[1], G.shape[1]
    shared = np.concatenate([b["encoder"], b["angle_systematic"]])
    zeta = beta[shared]
    angle = beta[b["angle_error"]] + data.angle_basis @ zeta  # (H,) arcsec
    q = beta[: 2 * nq].reshape(2, nq).T  # (nq, 2)
    o = beta[b["hold_offset"]].reshape(2, H).T  # (H, 2)
    y = Q @ q + sp.times(o + s * angle[:, None])
    if P is not None:
        y = y + P.times(zeta)
    return y


def normal_equations(v: dict, h: dict, structure: ModelStructure, data: RecordData):
    """rᵀWr, AᵀWr, AᵀWA assembled blockwise through G (W = mask/noise variance).

    β = (q₁, q₂, o₁, o₂, δ, e) with qⱼ = (cⱼ, dⱼ); with Qⱼ-weighted products
    QQ = QᵀWⱼQ, QG = QᵀWⱼG, GG = GᵀWⱼG and s = sⱼ the blocks are QQ, QG, QG·diag(s), GG,
    GG·diag(s), diag(s)·GG·diag(s) (summed over systems for δ) and their products with E.
    Row i of G has two entries, aᵢ at its own hold and bᵢ at the hold before
    (:func:`_hold_sparse`): the products with G are sums over bins by hold, O(N), not
    dense O(N·H²) products (most of the work of an evaluation before). Both systems are
    computed together, on a trailing axis j: one kernel for both, not one each (an
    evaluation is bound by the number of kernels it launches, not by arithmetic).
    """
    slews = slew_path(v, data)
    f, G, s, trans = linear_terms(v, data, slews)
    mask = data.mask
    nv = noise_var(h, data, trans)
    W = jnp.where(mask, 1.0 / nv, 0.0)  # (N, 2)
    r = jnp.where(mask, data.y - f, 0.0)
    P = _slew_terms(v, structure, data, slews, s)
    Q = q_columns(G, data, P)
    E = data.angle_basis
    nq, H, L = Q.shape[1], G.shape[1], E.shape[1]
    sp = _hold_sparse(G, data)
    Wr = W * r
    WQ = Q[:, :, None] * W[:, None, :]  # (N, nq, 2)
    QQ = jnp.einsum("nq,nrj->jqr", Q, WQ)  # (2, nq, nq)
    QG = jnp.transpose(sp.t_times(WQ), (2, 1, 0))  # (2, nq, H)
    QGs = QG * s.T[:, None, :]
    GG = jnp.moveaxis(sp.gram(W), 2, 0)  # (2, H, H)
    GGs = GG * s.T[:, None, :]
    Sd = jnp.einsum("jh,jhk->hk", s.T, GGs)  # Σⱼ diag(sⱼ)·GGⱼ·diag(sⱼ)
    bq = Q.T @ Wr  # (nq, 2)
    bo = sp.t_times(Wr)  # (H, 2)
    bdt = jnp.sum(s * bo, axis=1)
    QGsE = QGs @ E  # (2, nq, L)
    GGsE = GGs @ E  # (2, H, L)
    SdE = Sd @ E
    Zqq, Zqh, Zhh = jnp.zeros((nq, nq)), jnp.zeros((nq, H)), jnp.zeros((H, H))
    rows = [
        [QQ[0], Zqq, QG[0], Zqh, QGs[0], QGsE[0]],
        [Zqq, QQ[1], Zqh, QG[1], QGs[1], QGsE[1]],
        [QG[0].T, Zqh.T, GG[0], Zhh, GGs[0], GGsE[0]],
        [Zqh.T, QG[1].T, Zhh, GG[1], GGs[1], GGsE[1]],
        [QGs[0].T, QGs[1].T, GGs[0].T, GGs[1].T, Sd, SdE],
    ]
    gx = E.T @ bdt
    if P is not None and structure.n_systematic:  # the slews' share (see slew_angle_terms)
        QWP, GtWP, sGtWP, ee, gP = _slew_systematic_blocks(P, W, Q, r, s, E, sp, H)
        rows[0][5] = rows[0][5] + QWP[0]
        rows[1][5] = rows[1][5] + QWP[1]
        rows[2][5] = rows[2][5] + GtWP[..., 0]
        rows[3][5] = rows[3][5] + GtWP[..., 1]
        rows[4][5] = rows[4][5] + sGtWP
        gx = gx + gP
    else:
        ee = jnp.zeros((L, L))
    if L:
        rows.append([rows[i][5].T for i in range(5)] + [E.T @ SdE + ee])
    else:
        rows = [row[:-1] for row in rows]
    Mg = jnp.block(rows)
    g = jnp.concatenate([bq[:, 0], bq[:, 1], bo[:, 0], bo[:, 1], bdt] + ([gx] if L else []))
    rWr = jnp.sum(Wr * r)
    logdet_n = jnp.sum(jnp.where(mask, jnp.log(nv), 0.0))
    pieces = (f, G, s, r, W, nv, trans, P)
    return NormalEquations(rWr, g, Mg, logdet_n, jnp.sum(mask)), pieces


def _slew_systematic_blocks(P, W, Q, r, s, E, sp, H: int):
    """The slews' share of the systematic columns in the normal equations: Qᵀ W P,
    Gᵀ W P, Σⱼ diag(sⱼ) Gᵀ Wⱼ Pⱼ, the (E, P) block and Pᵀ W r.

    Pᵢ = cᵢ U_{k(i)}: every product with P is a sum over bins by hold, then one small
    product per hold with U (H, L, 2); P itself (N, L, 2) is never formed.
    """
    nq = Q.shape[1]
    U, own = P.per_hold, P.own
    Wc = W * P.weight[:, None]  # (N, 2)
    per_bin = jnp.concatenate(
        [
            jnp.broadcast_to(x[:, :, None], (x.shape[0], x.shape[1], 2))
            for x in (Q, jnp.stack([sp.a, sp.b, P.weight], axis=1))
        ]
        + [r[:, None, :]],
        axis=1,
    )  # (N, nq + 4, 2): Q, a, b, c, r
    by_hold = jax.ops.segment_sum(Wc[:, None, :] * per_bin, own, num_segments=H)
    QWc, aWc, bWc = by_hold[:, :nq], by_hold[:, nq], by_hold[:, nq + 1]
    c2W, rWc = by_hold[:, nq + 2], by_hold[:, nq + 3]
    # Gᵀ diag(W c) P: own-hold entries aᵢ, previous-hold entries bᵢ (every bin of hold k has
    # the same previous hold, ``prev_of``)
    prev_of = jax.ops.segment_max(sp.prev, own, num_segments=H)
    prev_of = jnp.clip(prev_of, 0, H - 1)  # holds without bins: their sums are 0
    GtWP = aWc[:, None, :] * U + jax.ops.segment_sum(
        bWc[:, None, :] * U, prev_of, num_segments=H
    )  # (H, L, 2)
    QWP = jnp.einsum("hqj,hlj->jql", QWc, U)
    sGtWP = jnp.einsum("hj,hlj->hl", s, GtWP)
    cross = E.T @ sGtWP  # Σⱼ (G diag(sⱼ) E)ᵀ Wⱼ Pⱼ
    ee = cross + cross.T + jnp.einsum("hj,hlj,hmj->lm", c2W, U, U)
    return QWP, GtWP, sGtWP, ee, jnp.einsum("hlj,hj->l", U, rWc)


class _HoldSparse(NamedTuple):
    """G (N, H) by its two entries per row: aᵢ at hold kᵢ (own) and bᵢ at pᵢ (the hold
    before; bᵢ = 0 for the first hold's bins and for padding)."""

    a: jax.Array
    b: jax.Array
    own: jax.Array  # (N,) int
    prev: jax.Array  # (N,) int
    n_holds: int

    def times(self, X):
        """G·X for X (H, …): rows gathered, aᵢ X[kᵢ] + bᵢ X[pᵢ]."""
        shape = (-1,) + (1,) * (X.ndim - 1)
        return self.a.reshape(shape) * X[self.own] + self.b.reshape(shape) * X[self.prev]

    def t_times(self, Y):
        """Gᵀ·Y for Y (N, …): sums over bins by hold."""
        shape = (-1,) + (1,) * (Y.ndim - 1)
        seg = functools.partial(jax.ops.segment_sum, num_segments=self.n_holds)
        return seg(self.a.reshape(shape) * Y, self.own) + seg(self.b.reshape(shape) * Y, self.prev)

    def gram(self, w):
        """Gᵀ diag(w) G (H, H, …) for weights w (N, …): the diagonal from a² and b², the
        hold-to-previous entries from ab."""
        H = self.n_holds
        shape = (-1,) + (1,) * (w.ndim - 1)
        a, b = self.a.reshape(shape), self.b.reshape(shape)
        seg = functools.partial(jax.ops.segment_sum, num_segments=H)
        diag = seg(w * a**2, self.own) + seg(w * b**2, self.prev)  # (H, …)
        cross = jnp.zeros((H, H, *w.shape[1:])).at[self.own, self.prev].add(w * a * b)
        eye = jnp.eye(H).reshape((H, H) + (1,) * (w.ndim - 1))
        return eye * diag[None] + cross + jnp.swapaxes(cross, 0, 1)


def _hold_sparse(G, data: RecordData) -> _HoldSparse:
    """G's two entries per row, read at the holds of ``data.own`` and ``data.prev``."""
    own = jnp.argmax(data.own, axis=1)
    prev = jnp.argmax(data.prev, axis=1)
    has_own = jnp.sum(data.own, axis=1)
    has_prev = jnp.sum(data.prev, axis=1)
    a = jnp.take_along_axis(G, own[:, None], axis=1)[:, 0] * has_own
    b = jnp.take_along_axis(G, prev[:, None], axis=1)[:, 0] * has_prev
    return _HoldSparse(a, b, own, prev, G.shape[1])


def predict(v: dict, structure: ModelStructure, data: RecordData):
    """``f`` (N, 2) and the dense design ``A`` (N, 2, p) (reference implementation, tests)."""
    slews = slew_path(v, data)
    f, G, s, _ = linear_terms(v, data, slews)
    return f, dense_design(G, s, structure, data, _slew_terms(v, structure, data, slews, s))


def _slew_terms(v: dict, structure: ModelStructure, data: RecordData, slews: SlewPath, s):
    """The slews' and the unsettled carry's share of the systematic and X-response
    columns, where the model has either (:func:`slew_angle_terms`)."""
    if structure.n_systematic or structure.n_x_response:
        return slew_angle_terms(v, data, s, slews)
    return None


def dense_design(
    G, s, structure: ModelStructure, data: RecordData, P: SlewColumns | None = None
) -> jax.Array:
    """The design ``A`` (N, 2, p) formed from the pieces of :func:`linear_terms` (``P``:
    :func:`slew_angle_terms` or None)."""
    Q = q_columns(G, data, P)
    N = G.shape[0]
    Pd = None if P is None or not structure.n_systematic else P.dense()
    cols = []
    for j in range(2):
        X = _local_columns(G, s[:, j], Q, data.angle_basis, None if Pd is None else Pd[..., j])
        A = jnp.zeros((N, structure.n_beta)).at[:, structure.beta_index(j)].add(X)
        cols.append(A)
    return jnp.stack(cols, axis=1)


def solve_beta(v: dict, h: dict, structure: ModelStructure, data: RecordData, extras: bool = False):
    """β̂(θ) = argmin ‖N^{-1/2}(y − f − Aβ)‖² + ‖Λ^{-1/2}β‖² and the whitened residuals.

    Returns ``(r_w (2N,), beta_hat (p,), L)`` with LLᵀ = M = AᵀN⁻¹A + Λ⁻¹, and with
    ``extras`` also the pieces ``(f, G, s, r, W, nv, trans, P)`` of :func:`normal_equations`.
    """
    ne, pieces = normal_equations(v, h, structure, data)
    _, G, s, r, _, nv, _, P = pieces
    prior_var = beta_prior_var(h, structure, data)
    beta, L = jax.lax.optimization_barrier(posterior_beta_normal(ne, prior_var))
    # not sqrt(W): its derivative is infinite where W = 0 (masked bins), giving 0·∞ = NaN
    sqrt_w = jnp.where(data.mask, 1.0 / jnp.sqrt(nv), 0.0)

    def log_posterior(b):  # Φ(β) up to a constant; ∇Φ(β̂) = 0, −∇²Φ = M
        e = sqrt_w * (r - apply_A(b, G, s, structure, data, P))
        return -0.5 * (jnp.sum(e * e) + jnp.sum(b * b / prior_var))

    # derivatives of β̂ from ∇Φ(β̂) = 0 (O(N) per tangent through A·β and Aᵀ·u), not through
    # M's assembly and Cholesky: the MAP Jacobian 3.5× cheaper on a 9 h record, same values
    beta = implicit_stationary_point(beta, L, jax.grad(log_posterior))
    rw = sqrt_w * (r - apply_A(beta, G, s, structure, data, P))
    if extras:
        return rw.reshape(-1), beta, L, pieces
    return rw.reshape(-1), beta, L
