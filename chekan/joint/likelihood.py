r"""The joint likelihood of a record: both systems, all rounds, β linear.

**Prediction** of bin i in hold k for system j:

    ȳᵢⱼ = (1 − wᵢ) Eₖⱼ + wᵢ Eₖ₋₁,ⱼ + cⱼ + Σₗ dⱼₗ Pₗ(sᵢ)
          + (1 − wᵢ)(oₖⱼ + Φₖνⱼ − Sₖⱼ δₖ) + wᵢ (oₖ₋₁,ⱼ + Φₖ₋₁νⱼ − Sₖ₋₁,ⱼ δₖ₋₁),

where Eₖⱼ is the exact torsion equilibrium (:func:`chekan.physics.sensor.equilibrium_readings`,
eq. 6) at the *reported* attitude of hold k, Sₖⱼ = ∂Eₖⱼ/∂θ, δₖ the angle-readout error of
hold k (reported − true, shared by both systems; prior N(0, σ_θ²)), oₖⱼ a per-hold offset
of each system (prior N(0, σ_o²)), Φₖνⱼ the X rounds' response beyond eq. (6) (zero at
holds about Y; :mod:`chekan.joint.xresponse`), Sₖⱼ along the hold's own tilt axis, cⱼ the
level-reading offset from m_ref, dⱼₗ drift
coefficients on sᵢ = time scaled to [−1, 1] (Legendre, no constant), and wᵢ the mean
over the bin's samples of exp(−(t − t_last)/τ), the first-order lag weight from the
state at the end of the slew into the hold. That state is the exact discrete lag filter
of the equilibrium along the slew's *measured* attitude, started from the lagged reading
at the end of the previous hold (a scan over holds carries what had not settled).
The angle error of hold k is δₖ + Σ_q Bₖq ζ_q: a random part δₖ of every hold and a
**systematic part shared by all rounds**, the basis B (``data.angle_basis``, arcsec per
unit ζ) holding one indicator column per commanded angle (the sensor's error at that
angle, no shape assumed) and the angle-scale error (θₖ/θ_max), with priors from the
platform's specification (:mod:`chekan.joint.angles`); the legacy ``--encoder-error``
adds a smooth part, Σₗ eₗ Pₗ(θₖ/θ_max) (l = 1…3; prior eₗ ~ N(0, 2″)). The systematic
part is not identified by the data (it repeats in every round): its uncertainty reaches b
through the prior, as a GUM Type B component.

The readings are linear in β = (c, d, o, δ, e): ȳ = f(θ) + A(θ)β, so β is marginalised
in closed form through the normal equations (:mod:`inference.normal_eq`), assembled by hold
(:mod:`chekan.joint.hold_blocks`; β | θ: :mod:`chekan.joint.beta_posterior`). This module
holds the model's pieces that both take: the sensor parameters, the lag weights, the slews'
equilibria, the transient's scale, β's prior and the bins' noise.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import chekan.jaxconfig  # noqa: F401
from chekan.joint.layout import ModelStructure, RecordData
from chekan.physics import sensor as fm
from chekan.physics.units import ARCMIN_PER_RAD
from inference.barrier import fusion_barrier


def sensor_params(v: dict, data: RecordData, c=None) -> fm.SensorParams:
    """Forward-model parameters from named values (level readings m_ref + c)."""
    m_level = data.m_ref if c is None else data.m_ref + c
    return fm.SensorParams(
        g_mgal=data.g,
        K_pix_per_rad=v["K"],
        m0_pix=data.m0,
        b_mgal_per_pix=jnp.stack([v["b1"], v["b2"]]),
        m_level_pix=m_level,
        eps_rad=jnp.stack([v["eps1_arcmin"], v["eps2_arcmin"]]) / ARCMIN_PER_RAD,
        gamma_rad=v["dgamma_arcmin"] / ARCMIN_PER_RAD,
    )


def lag_weights(tau_s, data: RecordData):
    """wᵢ = mean over the bin's n samples of exp(−(d₀ + kΔ)/τ), k = 0…n−1 (closed form)."""
    n, step, d0 = data.n_t, data.dstep, data.d0
    q_num = -jnp.expm1(-n * step / tau_s)
    q_den = -jnp.expm1(-step / tau_s)
    return jnp.exp(-d0 / tau_s) * jnp.where(n > 1, q_num / (n * q_den), 1.0)


class SlewPath(NamedTuple):
    """The equilibrium along every slew's measured path and what the lag keeps of it."""

    weight: jax.Array
    """wₖₘ (H, M): the share of path point m in the lag state at the end of slew k."""
    readings: jax.Array
    """E(θₖₘ) (2, H, M), pixels (systems first: see
    :func:`chekan.physics.sensor.equilibrium_by_system`)."""
    per_rad: jax.Array
    """∂E/∂θ (2, H, M) along the tilt direction, pixels per radian."""


def slew_path(v: dict, data: RecordData) -> SlewPath:
    """E and ∂E/∂θ along the slews in one forward-mode pass (their Newton solves are the
    largest elementwise work of an evaluation: computed once, shared by the prediction and
    the slews' share of the angle columns, :func:`chekan.joint.hold_blocks.bin_design`)."""
    p = sensor_params(v, data)
    dx, dy = data.mv_dir[:, :1], data.mv_dir[:, 1:]  # (H, 1): the slew's own axis

    def path(h):
        return fm.equilibrium_by_system(p, data.mv_tx + h * dx, data.mv_ty + h * dy)

    zero = jnp.zeros_like(data.mv_tx)
    # materialised in this layout: left to itself XLA fuses the last Newton step into a
    # transposing copy for the consumers' contractions, which runs scalar
    Em, dEm = fusion_barrier(jax.jvp(path, (zero,), (jnp.ones_like(zero),)))
    tau = v["tau_s"]
    wm = jnp.where(data.mv_mask, -jnp.expm1(-data.dt / tau) * jnp.exp(-data.mv_lag / tau), 0.0)
    return SlewPath(wm, Em, dEm)


def transient_amplitude(E, wprev, wm, Em, R):
    r"""(H, 2) the slew error's scale: the sum of the parts of the lag state after slew k
    that a late angle can misplace, each by its distance from the hold's equilibrium,

        Tₖ = w_prev,ₖ |Eₖ₋₁ − Eₖ| + Σₘ wₘ |E(θₘ) − Eₖ| + |Rₖ|   (≥ |y₀,ₖ − Eₖ|).

    On a monotone slew it is the net transient |y₀,ₖ − Eₖ|. On a slew from +θ to −θ
    through level the previous hold's part and the path's part can lie on either side of
    Eₖ and cancel in the net, while a path that the streams' jitter warps in time (a row
    carries the *latest* angles) misplaces each of them (the built-in emulator's record:
    README, "The slew error's scale"). ``E``, ``R`` (H, 2), ``wprev`` (H,), ``wm`` (H, M),
    ``Em`` (2, H, M); Eₖ₋₁ of hold 0 is its own (no slew before it)."""
    E_prev = jnp.concatenate([E[:1], E[:-1]], axis=0)
    along = jnp.einsum("hm,jhm->hj", wm, jnp.abs(Em - jnp.transpose(E)[:, :, None]))
    return wprev[:, None] * jnp.abs(E_prev - E) + along + jnp.abs(R)


def beta_prior_var(h: dict, structure: ModelStructure, data: RecordData) -> jax.Array:
    """Prior variances of β given the hyperparameters, in β's layout: c 1 pix², d 4 pix²,
    ν from ``data.x_prior_var``, o σ_o², δ σ_θ², and the shared angle-error terms (e, ζ)
    from ``data.angle_prior_var``
    (legacy encoder: 4 arcsec²; systematic terms: the platform specification, Type B)."""
    pv = jnp.zeros(structure.n_beta)
    b = structure.beta_blocks
    shared = np.concatenate([b["encoder"], b["angle_systematic"]])
    pv = pv.at[b["c"]].set(1.0).at[b["drift"]].set(4.0).at[shared].set(data.angle_prior_var)
    pv = pv.at[b["x_response"]].set(jnp.tile(data.x_prior_var, 2))
    pv = pv.at[b["hold_offset"]].set(h["sigma_hold_pix"] ** 2)
    return pv.at[b["angle_error"]].set(h["sigma_theta_arcsec"] ** 2)


def noise_var(h: dict, data: RecordData, trans=None) -> jax.Array:
    """(N, 2) variance of each bin mean: (sⱼσⱼ)²/n + (κ·transient)².

    The second term is the slew error: a row carries the *latest* platform angles, so
    during a slew the recorded attitude may lag the true one by up to a sample; the lag
    state after the slew is then uncertain in proportion to the transient still present
    in the bin (κ = ``slew_error``, a hyperparameter; zero once the hold has settled; the
    transient's scale: :func:`transient_amplitude`).
    """
    s = h["noise_scale"] * data.sigma_base
    base = s[None, :] ** 2 / jnp.maximum(data.cnt, 1.0)
    if trans is None:
        return base
    return base + (h["slew_error"] * trans) ** 2
