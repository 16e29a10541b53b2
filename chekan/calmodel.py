"""The joint calibration model of a record: both systems, all rounds, one likelihood.

**Data.** Bin means of the raw 1 Hz samples inside every hold: short bins across the
settling transient (edges 0, 15, 40, 90, 180 s, then ``settle_s``) and one long bin
after it. Modelling the damping lag lets us keep the settling samples (they carry τ),
while binning keeps the likelihood small (≈ 6 bins × 36 holds × 2 systems instead of
66 000 samples), so the sampler is fast. A bin mean of n samples has noise variance
(sⱼ σⱼ)²/n, σⱼ estimated from the first differences of the settled samples
(robust: 1.4826·MAD/√2) and sⱼ a sampled scale factor.

**Prediction** of bin i in hold k for system j:

    ȳᵢⱼ = (1 − wᵢ) Eₖⱼ + wᵢ Eₖ₋₁,ⱼ + cⱼ + Σₗ dⱼₗ Pₗ(sᵢ)
          + (1 − wᵢ)(oₖⱼ − Sₖⱼ δₖ) + wᵢ (oₖ₋₁,ⱼ − Sₖ₋₁,ⱼ δₖ₋₁),

where Eₖⱼ is the exact torsion equilibrium (:func:`chekan.model.equilibrium_readings`)
at the *reported* attitude of hold k, Sₖⱼ = ∂Eₖⱼ/∂θ, δₖ the angle-readout error of
hold k (reported − true, shared by both systems; prior N(0, σ_θ²), the paper's platform
error ≤ 3″ → σ_θ ≈ 2″), oₖⱼ a per-hold offset of each system (elastic after-effect;
prior N(0, σ_o²)), cⱼ the level-reading offset from the classical m_h, dⱼₗ drift
coefficients on sᵢ = time scaled to [−1, 1] (polynomial, no constant), and
wᵢ = mean over the bin's samples of exp(−(t − t_last)/τ) the first-order lag weight
from the state at the end of the slew into the hold. That state is the exact
discrete lag filter of the equilibrium along the slew's *measured* attitude (a slew
from +θ to −θ passes through level, so the reading overshoots towards m_h), started
from the lagged reading at the end of the previous hold (which need not have settled:
a scan over holds carries the remainder), written above as Eₖ₋₁ for brevity.
With ``encoder=True`` the angle error has a smooth systematic part repeated in every
round, δₖ += Σₗ eₗ Pₗ(θₖ/θ_max) (Legendre, l = 1…3; prior eₗ ~ N(0, 2″)).

The readings are linear in β = (c, d, o, δ, e), so β is marginalised in closed form
(:mod:`inference.linear`): the sampler sees only θ = (b₁, b₂, log K, ε₁, ε₂, Δγ, log τ)
and the hyperparameters (log s₁, log s₂, log σ_θ, log σ_o, log κ), 12 dimensions.

**Priors** (values in the units of the parameter):

======================  =================================  ===================================
parameter               prior                              source
======================  =================================  ===================================
b₁, b₂ (mGal/pix)       N(6.9, 0.5)                        paper's range of b, wide (fixed, so
                                                           the problem is shared by records)
K (pix/rad)             log K ~ N(log 60428, 0.25)         optics F = 150 mm, δ = 7 µm, n = 1.4
                                                           (eq. 4); a = g/2K² (eq. 10) ± 50 %
ε₁, ε₂ (arcmin)         N(0, 10)                           "ε … can reach 10′"
Δγ (arcmin)             N(0, 10)                           "Δγ … does not exceed 20′"
τ (s)                   log τ ~ N(log 30, 1)               damping liquid, weak
s₁, s₂                  log s ~ N(0, 0.5)                  noise estimated from the data
σ_θ (arcsec)            log σ_θ ~ N(log 2, 0.5)            platform readout error ≤ 3″
σ_o (pix)               log σ_o ~ N(log 0.05, 1)           weak
c (pix)                 N(0, 1)                            around m_ref (classical m_h, then
                                                           the estimate: bayes.recentre_level)
d (pix)                 N(0, 2²) per coefficient           drift over a session ≲ a few pixels
======================  =================================  ===================================
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

import chekan.jaxconfig  # noqa: F401
from chekan import model as fm
from chekan.holds import HoldTable
from chekan.units import ARCMIN_PER_RAD, ARCSEC_PER_RAD
from inference.params import Param, ParamSpace
from inference.problem import LeastSquaresProblem

K_DESIGN = 60428.0
BIN_EDGES_S = (0.0, 15.0, 40.0, 90.0, 180.0)


def nonlinear_params(b_loc=(6.9, 6.9)) -> list[Param]:
    """θ: the physical parameters that enter the readings nonlinearly."""
    return [
        Param("b1", loc=float(b_loc[0]), scale=0.5, typical=1e-3, unit="mGal/pix"),
        Param("b2", loc=float(b_loc[1]), scale=0.5, typical=1e-3, unit="mGal/pix"),
        Param(
            "K", loc=math.log(K_DESIGN), scale=0.25, transform="log", typical=0.01, unit="pix/rad"
        ),
        Param("eps1_arcmin", scale=10.0, typical=0.1, unit="arcmin"),
        Param("eps2_arcmin", scale=10.0, typical=0.1, unit="arcmin"),
        Param("dgamma_arcmin", scale=10.0, typical=1.0, unit="arcmin"),
        Param("tau_s", loc=math.log(30.0), scale=1.0, transform="log", typical=0.1, unit="s"),
    ]


def hyper_params() -> list[Param]:
    return [
        Param("noise_scale", scale=0.5, transform="log", shape=(2,), typical=0.05),
        Param("sigma_theta_arcsec", loc=math.log(2.0), scale=0.5, transform="log", typical=0.2),
        Param("sigma_hold_pix", loc=math.log(0.05), scale=1.0, transform="log", typical=0.2),
        Param("slew_error", loc=math.log(0.003), scale=1.5, transform="log", typical=0.3),
    ]


@dataclass
class RecordModel:
    """Arrays of one record laid out for the model, plus the names of β's blocks."""

    data: dict  # pytree of jnp arrays: the ``data`` argument of every model function
    n_holds: int
    n_bins: int
    drift_degree: int
    encoder_degree: int
    hold_steps: np.ndarray
    bin_t_s: np.ndarray
    t_span_s: tuple[float, float]
    beta_blocks: dict[str, np.ndarray] = field(default_factory=dict)  # β index arrays

    @property
    def n_beta(self) -> int:
        return int(sum(len(ix) for ix in self.beta_blocks.values()))


def _robust_sigma(record, holds: HoldTable) -> np.ndarray:
    """Per-sample noise of each system from first differences of settled samples."""
    m = np.stack([record.m1_pix, record.m2_pix], axis=1)
    t = np.asarray(record.t_s, dtype=float)
    out = np.zeros(2)
    for j in range(2):
        diffs = []
        for a, b in zip(holds.start, holds.stop, strict=True):
            sel = np.arange(a, b)
            sel = sel[t[sel] - t[a] >= holds.settle_s]
            d = np.diff(m[sel, j])
            diffs.append(d[np.isfinite(d)])
        d = np.concatenate(diffs) if diffs else np.zeros(0)
        mad = np.median(np.abs(d - np.median(d))) if d.size else np.nan
        out[j] = 1.4826 * mad / math.sqrt(2.0) if d.size > 10 and mad > 0 else 0.1
    return out


def _moves(record, holds: HoldTable, dt_s: float):
    """Samples of the slew into each hold (reported attitude) and their lag exponents.

    Returns per hold k (padded to the longest slew, M): tx, ty (H, M) rad, ``lag`` (H, M)
    = t_last − tᵢ (s) with t_last the last sample before the hold, ``mask`` (H, M), and
    t_last (H,). The lag state at t_last is exactly
    y = (1 − Σᵢwᵢ) Eₖ₋₁ + Σᵢ wᵢ E(θᵢ), wᵢ = (1 − e^{−Δt/τ}) e^{−lagᵢ/τ}.
    """
    t = np.asarray(record.t_s, dtype=float)
    tx = np.asarray(record.tilt_x_arcsec, dtype=float) / ARCSEC_PER_RAD
    ty = np.asarray(record.tilt_y_arcsec, dtype=float) / ARCSEC_PER_RAD
    H = holds.n
    idx = [
        np.arange(holds.stop[k - 1], holds.start[k]) if k else np.zeros(0, int) for k in range(H)
    ]
    idx = [i[np.isfinite(tx[i]) & np.isfinite(ty[i])] for i in idx]
    M = max(1, max(i.size for i in idx))
    mx, my, lag = np.zeros((H, M)), np.zeros((H, M)), np.zeros((H, M))
    mask = np.zeros((H, M), bool)
    t_last = np.array(
        [t[holds.start[k] - 1] if holds.start[k] > 0 else t[0] - 1e9 for k in range(H)]
    )
    for k, i in enumerate(idx):
        n = i.size
        mx[k, :n], my[k, :n] = tx[i], ty[i]
        lag[k, :n] = t_last[k] - t[i]
        mask[k, :n] = True
    return mx, my, lag, mask, t_last


def prepare_record(
    record,
    holds: HoldTable,
    m_level_ref: np.ndarray,
    *,
    drift_degree: int = 3,
    encoder: bool = False,
    bin_edges_s=BIN_EDGES_S,
) -> RecordModel:
    """Bin the samples of every hold and build the model's data pytree."""
    t = np.asarray(record.t_s, dtype=float)
    m = np.stack([record.m1_pix, record.m2_pix], axis=1).astype(float)
    H = holds.n
    dt_s = 1.0 / float(record.sample_rate_hz)
    mv_tx, mv_ty, mv_lag, mv_mask, t_last = _moves(record, holds, dt_s)
    # time from the end of the slew into hold k to the hold's last sample (lag carried on)
    hold_T = np.array([t[holds.stop[k] - 1] - t_last[k] if k else 0.0 for k in range(H)])
    rows = []  # (hold, mean(2), count(2), d0, dstep, n_t, t_mid)
    for k in range(H):
        a, b = holds.start[k], holds.stop[k]
        tt = t[a:b]
        rel = tt - tt[0]
        edges = sorted({e for e in bin_edges_s if e < holds.settle_s} | {holds.settle_s})
        edges = [e for e in edges if e <= rel[-1]] + [np.inf]
        for lo, hi in itertools.pairwise(edges):
            sel = (rel >= lo) & (rel < hi)
            if not sel.any():
                continue
            mm = m[a:b][sel]
            cnt = np.sum(np.isfinite(mm), axis=0)
            with np.errstate(invalid="ignore"):
                mean = np.where(cnt > 0, np.nansum(mm, axis=0) / np.maximum(cnt, 1), 0.0)
            ts = tt[sel]
            d0 = ts[0] - t_last[k]
            dstep = (ts[-1] - ts[0]) / (ts.size - 1) if ts.size > 1 else 1.0
            rows.append((k, mean, cnt, d0, dstep, ts.size, ts.mean()))
    N = len(rows)
    hold_of = np.array([r[0] for r in rows])
    own = np.zeros((N, H))
    own[np.arange(N), hold_of] = 1.0
    prev = np.zeros((N, H))
    has_prev = hold_of > 0
    prev[np.flatnonzero(has_prev), hold_of[has_prev] - 1] = 1.0
    y = np.stack([r[1] for r in rows])
    cnt = np.stack([r[2] for r in rows]).astype(float)
    d0 = np.array([r[3] for r in rows])
    d0 = np.where(hold_of > 0, d0, 1e9)  # first hold: settled from the start
    t_mid = np.array([r[6] for r in rows])
    t0, t1 = float(t.min()), float(t.max())
    s = 2.0 * (t_mid - t0) / max(t1 - t0, 1.0) - 1.0
    P = np.polynomial.legendre.legvander(s, drift_degree)[:, 1:]  # no constant
    theta = holds.theta_rad
    tmax = max(np.max(np.abs(theta)), 1e-9)
    L = 3 if encoder else 0
    enc = np.polynomial.legendre.legvander(theta / tmax, L)[:, 1:] if L else np.zeros((H, 0))
    direction = np.array([0.0, 1.0]) if holds.axis == "y" else np.array([1.0, 0.0])
    data = {
        "g": jnp.asarray(record.g_local_mgal, dtype=jnp.float64),
        "m0": jnp.asarray(record.ccd_center_pix, dtype=jnp.float64),
        "m_ref": jnp.asarray(m_level_ref, dtype=jnp.float64),
        "hold_tx": jnp.asarray(holds.tilt_x_rad),
        "hold_ty": jnp.asarray(holds.tilt_y_rad),
        "direction": jnp.asarray(direction),
        "own": jnp.asarray(own),
        "prev": jnp.asarray(prev),
        "d0": jnp.asarray(d0),
        "dstep": jnp.asarray(np.array([r[4] for r in rows])),
        "n_t": jnp.asarray(np.array([r[5] for r in rows], dtype=float)),
        "y": jnp.asarray(y),
        "cnt": jnp.asarray(cnt),
        "mask": jnp.asarray(cnt > 0),
        "mv_tx": jnp.asarray(mv_tx),
        "mv_ty": jnp.asarray(mv_ty),
        "mv_lag": jnp.asarray(mv_lag),
        "mv_mask": jnp.asarray(mv_mask),
        "dt": jnp.asarray(dt_s),
        "hold_T": jnp.asarray(hold_T),
        "drift_basis": jnp.asarray(P),
        "enc_basis": jnp.asarray(enc),
        "sigma_base": jnp.asarray(_robust_sigma(record, holds)),
        "hold_mask": jnp.ones(H, dtype=bool),  # False for padding (see pad_model)
    }
    return RecordModel(
        data=data,
        n_holds=H,
        n_bins=N,
        drift_degree=drift_degree,
        encoder_degree=L,
        hold_steps=holds.step,
        bin_t_s=t_mid,
        t_span_s=(t0, t1),
        beta_blocks=_beta_blocks(H, drift_degree, L),
    )


def _beta_blocks(H: int, D: int, L: int) -> dict[str, np.ndarray]:
    """β's layout: (c₁, d₁, c₂, d₂, o₁, o₂, δ, e)."""
    q = 1 + D  # per system: level offset cⱼ then drift dⱼ
    o0, a0, e0 = 2 * q, 2 * q + 2 * H, 2 * q + 3 * H
    return {
        "c": np.array([0, q]),
        "drift": np.concatenate([np.arange(1, q), q + np.arange(1, q)]),
        "hold_offset": np.arange(o0, o0 + 2 * H),  # system 1's holds, then system 2's
        "angle_error": np.arange(a0, a0 + H),
        "encoder": np.arange(e0, e0 + L),
    }


# padding values per data key: the axes that are padded and the fill value
_PAD = {
    "hold_tx": ("H", 0.0),
    "hold_ty": ("H", 0.0),
    "hold_T": ("H", 0.0),
    "hold_mask": ("H", False),
    "enc_basis": ("H", 0.0),
    "own": ("NH", 0.0),
    "prev": ("NH", 0.0),
    "d0": ("N", 1e9),
    "dstep": ("N", 1.0),
    "n_t": ("N", 1.0),
    "y": ("N", 0.0),
    "cnt": ("N", 0.0),
    "mask": ("N", False),
    "drift_basis": ("N", 0.0),
    "mv_tx": ("HM", 0.0),
    "mv_ty": ("HM", 0.0),
    "mv_lag": ("HM", 0.0),
    "mv_mask": ("HM", False),
}


def padded_shape(models: list[RecordModel]) -> tuple[int, int, int]:
    """(H, N, M) that holds every model, rounded up (H to 4, N and M to 16) so that
    chunks of similar records share one compiled solver."""

    def up(x: int, m: int) -> int:
        return -(-x // m) * m

    H = max(m.n_holds for m in models)
    N = max(m.n_bins for m in models)
    M = max(int(m.data["mv_tx"].shape[1]) for m in models)
    return up(H, 4), up(N, 16), up(M, 16)


def pad_model(model: RecordModel, H: int, N: int, M: int) -> RecordModel:
    """The same record laid out for H holds, N bins and M slew samples.

    Exact: padded bins have ``mask`` False (zero weight), padded holds have no bins
    (``own``/``prev`` columns zero, so their β is its prior mean 0 and adds nothing to
    the residuals) and sit after the real ones (the unsettled-carry scan runs forwards),
    padded slew samples have ``mv_mask`` False. ``hold_mask`` marks the real holds.
    """
    h0, n0, m0 = model.n_holds, model.n_bins, int(model.data["mv_tx"].shape[1])
    if (H, N, M) == (h0, n0, m0):
        return model
    if H < h0 or N < n0 or M < m0:
        raise ValueError(f"cannot pad ({h0}, {n0}, {m0}) down to ({H}, {N}, {M})")
    extra = {"H": H - h0, "N": N - n0, "M": M - m0}
    data = dict(model.data)
    for key, (axes, fill) in _PAD.items():
        x = np.asarray(data[key])
        widths = [(0, extra[a]) for a in axes] + [(0, 0)] * (x.ndim - len(axes))
        data[key] = jnp.asarray(np.pad(x, widths, constant_values=fill))
    return RecordModel(
        data=data,
        n_holds=H,
        n_bins=N,
        drift_degree=model.drift_degree,
        encoder_degree=model.encoder_degree,
        hold_steps=model.hold_steps,
        bin_t_s=model.bin_t_s,
        t_span_s=model.t_span_s,
        beta_blocks=_beta_blocks(H, model.drift_degree, model.encoder_degree),
    )


# ----------------------------------------------------------------------------- model


def sensor_params(v: dict, data: dict, c=None) -> fm.SensorParams:
    """Forward-model parameters from named values (level readings m_ref + c)."""
    m_level = data["m_ref"] if c is None else data["m_ref"] + c
    return fm.SensorParams(
        g_mgal=data["g"],
        K_pix_per_rad=v["K"],
        m0_pix=data["m0"],
        b_mgal_per_pix=jnp.stack([v["b1"], v["b2"]]),
        m_level_pix=m_level,
        eps_rad=jnp.stack([v["eps1_arcmin"], v["eps2_arcmin"]]) / ARCMIN_PER_RAD,
        gamma_rad=v["dgamma_arcmin"] / ARCMIN_PER_RAD,
    )


def lag_weights(tau_s, data):
    """wᵢ = mean over the bin's n samples of exp(−(d₀ + kΔ)/τ), k = 0…n−1 (closed form)."""
    n, step, d0 = data["n_t"], data["dstep"], data["d0"]
    q_num = -jnp.expm1(-n * step / tau_s)
    q_den = -jnp.expm1(-step / tau_s)
    return jnp.exp(-d0 / tau_s) * jnp.where(n > 1, q_num / (n * q_den), 1.0)


def linear_terms(v: dict, data: dict):
    """The pieces of ȳ = f + Aβ: ``f`` (N, 2), lag mixing ``G`` (N, H) and the angle
    sensitivity per arcsec ``s`` (H, 2) = −∂E/∂θ / 206265.

    For system j the columns of A are [1, P, G, G·diag(sⱼ), G·diag(sⱼ)·E_enc] acting on
    (cⱼ, dⱼ, oⱼ, δ, e): everything factors through G (see the module docstring).
    """
    p = sensor_params(v, data)
    tx, ty = data["hold_tx"], data["hold_ty"]
    dirn = data["direction"]

    def eq(h):
        return fm.equilibrium_readings(p, tx + h * dirn[0], ty + h * dirn[1])

    E, S = jax.jvp(eq, (jnp.zeros_like(tx),), (jnp.ones_like(tx),))  # (H, 2) each
    tau = v["tau_s"]
    # lag state at the end of each slew: previous hold's equilibrium + the slew's equilibria
    Em = fm.equilibrium_readings(p, data["mv_tx"], data["mv_ty"])  # (H, M, 2)
    wm = jnp.where(
        data["mv_mask"], -jnp.expm1(-data["dt"] / tau) * jnp.exp(-data["mv_lag"] / tau), 0.0
    )
    wprev = 1.0 - wm.sum(axis=1)  # (H,)
    Mv = jnp.einsum("hm,hmj->hj", wm, Em)  # (H, 2)
    w = lag_weights(tau, data)  # (N,) weight of the state at the end of the slew
    G = (1.0 - w)[:, None] * data["own"] + (w * (data["own"] @ wprev))[:, None] * data["prev"]
    R = _unsettled_carry(E, Mv, wprev, jnp.exp(-data["hold_T"] / tau))
    f = G @ E + w[:, None] * (data["own"] @ (Mv + R))
    E_prev = jnp.concatenate([E[:1], E[:-1]], axis=0)
    jump = jnp.abs(wprev[:, None] * E_prev + Mv + R - E)  # (H, 2) transient amplitude
    trans = w[:, None] * (data["own"] @ jump)  # (N, 2) transient left in each bin
    return f, G, -S / ARCSEC_PER_RAD, trans


def _unsettled_carry(E, Mv, wprev, rho):
    """Rₖ: the part of the lag state after slew k left over from holds that had not settled.

    y₀,ₖ = wₚᵣₑᵥ,ₖ yₑₙd,ₖ₋₁ + Mvₖ with yₑₙd,ₖ₋₁ = Eₖ₋₁ + (y₀,ₖ₋₁ − Eₖ₋₁) ρₖ₋₁,
    ρ = e^{−T/τ} (T: slew end to hold end); Rₖ = y₀,ₖ − wₚᵣₑᵥ,ₖ Eₖ₋₁ − Mvₖ (R₀ = 0, hold 0
    settled). Deterministic part only: the β terms keep the one-hold carry (the rest is
    second order, ρ·σ_o).
    """

    def step(y0_prev, k):
        y0 = wprev[k] * (E[k - 1] + (y0_prev - E[k - 1]) * rho[k - 1]) + Mv[k]
        return y0, y0 - wprev[k] * E[k - 1] - Mv[k]

    _, R = jax.lax.scan(step, E[0], jnp.arange(1, E.shape[0]))
    return jnp.concatenate([jnp.zeros((1, E.shape[1])), R], axis=0)


def _beta_index(model: RecordModel, j: int) -> np.ndarray:
    """Global β indices of system j's local columns [cⱼ, dⱼ, oⱼ, δ, e]."""
    b, D, H = model.beta_blocks, model.drift_degree, model.n_holds
    return np.concatenate(
        [
            j * (1 + D) + np.arange(1 + D),
            b["hold_offset"][j * H : (j + 1) * H],
            b["angle_error"],
            b["encoder"],
        ]
    )


def _local_columns(G, s_j, Q, enc):
    """System j's columns [Q, G, G·diag(sⱼ), G·diag(sⱼ)·E] (only used for A·β products)."""
    Gs = G * s_j[None, :]
    return jnp.concatenate([Q, G, Gs, Gs @ enc], axis=1)


def apply_A(beta, G, s, model: RecordModel, data: dict):
    """A·β as (N, 2), without forming A."""
    Q = jnp.concatenate([jnp.ones((G.shape[0], 1)), data["drift_basis"]], axis=1)
    out = []
    for j in range(2):
        bj = beta[_beta_index(model, j)]
        out.append(_local_columns(G, s[:, j], Q, data["enc_basis"]) @ bj)
    return jnp.stack(out, axis=1)


def normal_equations(v: dict, h: dict, model: RecordModel, data: dict):
    """rᵀWr, AᵀWr, AᵀWA assembled blockwise through G (W = mask/noise variance).

    β = (q₁, q₂, o₁, o₂, δ, e) with qⱼ = (cⱼ, dⱼ); with Qⱼ-weighted products
    QQ = QᵀWⱼQ, QG = QᵀWⱼG, GG = GᵀWⱼG and s = sⱼ the blocks are QQ, QG, QG·diag(s), GG,
    GG·diag(s), diag(s)·GG·diag(s) (summed over systems for δ) and their products with E.
    """
    from inference.normal_eq import NormalEquations

    f, G, s, trans = linear_terms(v, data)
    mask = data["mask"]
    nv = noise_var(h, data, trans)
    W = jnp.where(mask, 1.0 / nv, 0.0)
    r = jnp.where(mask, data["y"] - f, 0.0)
    Q = jnp.concatenate([jnp.ones((G.shape[0], 1)), data["drift_basis"]], axis=1)
    E = data["enc_basis"]
    nq, H, L = Q.shape[1], G.shape[1], E.shape[1]
    QQ, QG, QGs, GG, GGs, sGGs, bq, bo, bd = [], [], [], [], [], [], [], [], []
    for j in range(2):
        Wj, sj = W[:, j], s[:, j]
        WQ, WG = Q * Wj[:, None], G * Wj[:, None]
        QQ.append(Q.T @ WQ)
        QG.append(Q.T @ WG)
        QGs.append(QG[j] * sj[None, :])
        GG.append(G.T @ WG)
        GGs.append(GG[j] * sj[None, :])
        sGGs.append(sj[:, None] * GGs[j])
        bq.append(WQ.T @ r[:, j])
        bo.append(WG.T @ r[:, j])
        bd.append(sj * bo[j])
    Zqq, Zqh, Zhh = jnp.zeros((nq, nq)), jnp.zeros((nq, H)), jnp.zeros((H, H))
    Sd = sGGs[0] + sGGs[1]
    rows = [
        [QQ[0], Zqq, QG[0], Zqh, QGs[0], QGs[0] @ E],
        [Zqq, QQ[1], Zqh, QG[1], QGs[1], QGs[1] @ E],
        [QG[0].T, Zqh.T, GG[0], Zhh, GGs[0], GGs[0] @ E],
        [Zqh.T, QG[1].T, Zhh, GG[1], GGs[1], GGs[1] @ E],
        [QGs[0].T, QGs[1].T, GGs[0].T, GGs[1].T, Sd, Sd @ E],
    ]
    if L:
        rows.append(
            [(QGs[0] @ E).T, (QGs[1] @ E).T, (GGs[0] @ E).T, (GGs[1] @ E).T, E.T @ Sd, E.T @ Sd @ E]
        )
    else:
        rows = [row[:-1] for row in rows]
    Mg = jnp.block(rows)
    bdt = bd[0] + bd[1]
    g = jnp.concatenate([bq[0], bq[1], bo[0], bo[1], bdt] + ([E.T @ bdt] if L else []))
    rWr = jnp.sum(W * r * r)
    logdet_n = jnp.sum(jnp.where(mask, jnp.log(nv), 0.0))
    return NormalEquations(rWr, g, Mg, logdet_n, jnp.sum(mask)), (f, G, s, r, W, nv, trans)


def predict(v: dict, model: RecordModel, data: dict):
    """``f`` (N, 2) and the dense design ``A`` (N, 2, p) (reference implementation, tests)."""
    f, G, s, _ = linear_terms(v, data)
    return f, dense_design(G, s, model, data)


def dense_design(G, s, model: RecordModel, data: dict) -> jax.Array:
    """The design ``A`` (N, 2, p) formed from the pieces of :func:`linear_terms`."""
    Q = jnp.concatenate([jnp.ones((G.shape[0], 1)), data["drift_basis"]], axis=1)
    N = G.shape[0]
    cols = []
    for j in range(2):
        X = _local_columns(G, s[:, j], Q, data["enc_basis"])
        A = jnp.zeros((N, model.n_beta)).at[:, _beta_index(model, j)].add(X)
        cols.append(A)
    return jnp.stack(cols, axis=1)


def beta_prior_var(h: dict, model: RecordModel) -> jax.Array:
    """Prior variances of β given the hyperparameters (c: 1 pix², d: 4 pix², o: σ_o², δ: σ_θ²,
    e: 4 arcsec²), in β's layout."""
    pv = jnp.zeros(model.n_beta)
    b = model.beta_blocks
    pv = pv.at[b["c"]].set(1.0).at[b["drift"]].set(4.0).at[b["encoder"]].set(4.0)
    pv = pv.at[b["hold_offset"]].set(h["sigma_hold_pix"] ** 2)
    return pv.at[b["angle_error"]].set(h["sigma_theta_arcsec"] ** 2)


def noise_var(h: dict, data: dict, trans=None) -> jax.Array:
    """(N, 2) variance of each bin mean: (sⱼσⱼ)²/n + (κ·transient)².

    The second term is the slew error: a row carries the *latest* platform angles, so
    during a slew the recorded attitude may lag the true one by up to a sample; the lag
    state after the slew is then uncertain in proportion to the transient still present
    in the bin (κ = ``slew_error``, a hyperparameter; zero once the hold has settled).
    """
    s = h["noise_scale"] * data["sigma_base"]
    base = s[None, :] ** 2 / jnp.maximum(data["cnt"], 1.0)
    if trans is None:
        return base
    return base + (h["slew_error"] * trans) ** 2


# ----------------------------------------------------------------------------- problems


@dataclass
class CalibrationProblem:
    """The record model as a MAP least-squares problem and as a marginal log-density."""

    model: RecordModel
    theta_space: ParamSpace
    bayes_space: ParamSpace
    map_space: ParamSpace
    lsq: LeastSquaresProblem

    def log_density(self, z, data):
        """log p(θ, h | y) up to a constant, β marginalised (12-dim z)."""
        from inference.normal_eq import marginal_loglik_normal

        v = self.bayes_space.to_values(z)
        ne, _ = normal_equations(v, v, self.model, data)
        ll = marginal_loglik_normal(ne, beta_prior_var(v, self.model))
        lp = self.bayes_space.log_prior(z) + ll
        return jnp.where(jnp.isfinite(lp), lp, -jnp.inf)


def solve_beta(v: dict, h: dict, model: RecordModel, data: dict, extras: bool = False):
    """β̂(θ) = argmin ‖N^{-1/2}(y − f − Aβ)‖² + ‖Λ^{-1/2}β‖² and the whitened residuals.

    Returns ``(r_w (2N,), beta_hat (p,), L)`` with LLᵀ = M = AᵀN⁻¹A + Λ⁻¹, and with
    ``extras`` also the pieces ``(f, G, s, r, W, nv, trans)`` of :func:`normal_equations`.
    """
    from inference.normal_eq import posterior_beta_normal

    ne, pieces = normal_equations(v, h, model, data)
    _, G, s, r, _, nv, _ = pieces
    beta, L = posterior_beta_normal(ne, beta_prior_var(h, model))
    # not sqrt(W): its derivative is infinite where W = 0 (masked bins), giving 0·∞ = NaN
    sqrt_w = jnp.where(data["mask"], 1.0 / jnp.sqrt(nv), 0.0)
    rw = sqrt_w * (r - apply_A(beta, G, s, model, data))
    if extras:
        return rw.reshape(-1), beta, L, pieces
    return rw.reshape(-1), beta, L


def build_problem(model: RecordModel, b_loc=(6.9, 6.9)) -> CalibrationProblem:
    """Both views of the model: MAP by variable projection over θ, and the marginal density.

    MAP: LM over θ only; for each θ the linear block β is solved in closed form
    (:func:`solve_beta`), so the residual is the projected one and its Gauss–Newton
    covariance for θ equals the θ-block of the joint (θ, β) Laplace covariance.
    """
    theta = nonlinear_params(b_loc)
    theta_space = ParamSpace(theta)
    bayes_space = ParamSpace(theta + hyper_params())

    def residuals(v, data):
        """Projected whitened bin residuals and β̂'s prior rows (hyperparameters in data)."""
        h = data["hyper"]
        rw, beta, _ = solve_beta(v, h, model, data)
        return jnp.concatenate([rw, beta / jnp.sqrt(beta_prior_var(h, model))])

    return CalibrationProblem(
        model, theta_space, bayes_space, theta_space, LeastSquaresProblem(theta_space, residuals)
    )


def hyper_dict(
    noise_scale=(1.0, 1.0), sigma_theta_arcsec=2.0, sigma_hold_pix=0.05, slew_error=0.003
) -> dict:
    return {
        "noise_scale": jnp.asarray(noise_scale, dtype=jnp.float64),
        "sigma_theta_arcsec": jnp.asarray(sigma_theta_arcsec, dtype=jnp.float64),
        "sigma_hold_pix": jnp.asarray(sigma_hold_pix, dtype=jnp.float64),
        "slew_error": jnp.asarray(slew_error, dtype=jnp.float64),
    }
