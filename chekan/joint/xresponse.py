r"""The X rounds' response beyond eq. (6): a nuisance per quartz system.

A tilt about the platform X axis turns the pendulums in their own plane. Eq. (6) with
the attitude of the system (:mod:`chekan.physics.sensor`) gives the reading's response to it:
to first order the same g(1 − cos θ) as a tilt about Y (the *even* part), plus
g·sin θ·sin φ (the *odd* part, the paper's d·θ·(m − m_h) of eq. 11–12, which depends on
φ = (m − m₀)/K and so on K). The paper warns that eq. (11) leaves effects out (fibre sag
among them), which is why the stand method calibrates in several azimuths. So that b
and a do not rest on the ideal model's X response alone, every system j carries two
terms **per distinct angle magnitude** a of the X holds (β, marginalised like the drift;
no shape in θ assumed, as for the angle sensors' systematic error; along the slews about
X, which the lag carries into the holds, each slew type has its own two terms with the
same priors, :func:`x_response_path`), with θₖ the hold's tilt about X and θ_r the
largest one:

    Δmₖⱼ = νⱼ,odd,a · sin θₖ / sin θ_r  +  νⱼ,even,a · (1 − cos θₖ)/(1 − cos θ_r)   [pix].

- **odd**: the pendulum's horizontal is the CCD centre m₀ only to the instrument's
  mounting tolerance (``M0_TOLERANCE_PIX``); an offset Δm₀ moves the odd part by
  (g/(bK))·sin θ·Δm₀. With that tolerance the prior is far wider than what the data
  measure: the X rounds' odd part does not inform K (nor a) — it is fitted, not trusted.
- **even**: what eq. (6) lacks in the X response relative to the Y response. The paper
  bounds the terms that eq. (21) leaves out at ``EVEN_BOUND_MGAL`` (eq. 20: δg ≤ 0.2 mGal);
  read as a bound (rectangular, u = U/√3, GUM 4.3.7) in mGal and converted with the
  nominal b. The X rounds then inform b through their even part up to that uncertainty;
  the Y rounds carry b on their own when it is larger (validation: ``docs/figures/``).

The same tolerance reaches the **even** part too: eq. (6) turns the pendulum in its own
plane by the odd part, and the stiffness g·sin θ·δ it meets there adds to the even part
≈ −(g/bK)²·sin²θ·Δm₀ pixels (0.05 pix per pix of Δm₀ at 5°10′, three times the even
term's prior sd of 0.017 pix): the X rounds' even part is exact only if the pendulum's
horizontal is known to a fraction of a pixel. So every system also carries its **level
angle** term, one coefficient Δm₀ⱼ (pix, prior sd ``M0_TOLERANCE_PIX``) on the column
∂E_even/∂m₀ of eq. (6) (:func:`level_angle_column`) at the X holds and along the slews
about X (its odd part is the odd terms'). The same term
holds the level reading that φ_h belongs to: a drift whose course the model holds moves
the record's mean level reading away from the reading of the pendulum's own level by its
run over the record (a read-out drift leaves φ_h, a creeping fibre moves it). The Y
response changes by 1.6·10⁻⁵ of itself per 100 pix (b by 16 ppm): left out, so that
records about Y alone keep their results.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from chekan.joint.slews import type_indicator
from chekan.physics.sensor import NEWTON_STEPS, newton_deflection
from chekan.physics.units import ARCSEC_PER_RAD

K_NOMINAL_PIX_PER_RAD = 60428.0  # eq. (4): the design K
B_NOMINAL_MGAL_PER_PIX = 6.9  # the paper's single-system b (eq. 9), for unit conversion only
M0_TOLERANCE_PIX = 100.0  # the CCD centre vs the pendulum's horizontal (5 % of the CCD)
M0_SOURCE = "the model's assumption: 5 % of the CCD, no vendor figure known"
EVEN_BOUND_MGAL = 0.2  # eq. (20): what eq. (21) may leave out at the largest angle
GROUP_ARCSEC = 30.0  # X angles closer than this are one angle (as the angle sensors')
LEVEL_RAD = float(np.deg2rad(0.1))  # below this a hold is level (:mod:`chekan.records.holds`)


def horizontal_prior(u_pix: float | None) -> tuple[float, str]:
    """The pendulums' horizontal about the CCD centre: its standard uncertainty (pix) and
    where that comes from — the instrument's figure given as ``--horizontal-u-pix``, or
    (None) the model's own assumption ``M0_TOLERANCE_PIX``."""
    if u_pix is None:
        return M0_TOLERANCE_PIX, M0_SOURCE
    return float(u_pix), "--horizontal-u-pix"


class _XAngles(NamedTuple):
    """The X holds of a record: which they are, each angle's group key, the groups' keys
    (sorted) and the largest X angle θ_r."""

    on: np.ndarray
    key: np.ndarray
    groups: np.ndarray
    theta_r: float


def _x_angles(theta: np.ndarray, hold_axis: np.ndarray) -> _XAngles | None:
    """The X holds of ``theta`` (signed tilts about each hold's axis), or None."""
    on = (np.asarray(hold_axis) == "x") & (np.abs(theta) > LEVEL_RAD)
    if not np.any(on):
        return None
    key = np.round(np.abs(theta) * ARCSEC_PER_RAD / GROUP_ARCSEC).astype(np.int64)
    return _XAngles(on, key, np.unique(key[on]), float(np.max(np.abs(theta[on]))))


def x_response_path(
    theta_rad: np.ndarray,
    hold_axis: np.ndarray,
    path_rad: np.ndarray,
    path_on: np.ndarray,
    kinds: np.ndarray,
    n_types: int,
) -> np.ndarray:
    """The X-response columns along the slews (H, M, 2T): for each type t of the slews
    about X (:mod:`chekan.joint.slews`) its own odd and even terms, sin θ / sin θ_r and
    (1 − cos θ)/(1 − cos θ_r) on that type's samples (``path_on``; θ_r the largest X
    angle of the holds). What eq. (6) lacks is not known between the commanded angles, so
    the holds' terms are not continued along the slews (a response of another shape, such
    as sin³ θ, was misread through them); each slew type's share of it is its own unknown,
    with the holds' priors, shared by all rounds."""
    x = _x_angles(np.asarray(theta_rad, dtype=float), hold_axis)
    path = np.asarray(path_rad, dtype=float)
    if x is None or n_types == 0:
        return np.zeros((*path.shape, 0))
    hit = type_indicator(kinds, path_on, n_types)
    odd = np.sin(path) / math.sin(x.theta_r)
    even = (1.0 - np.cos(path)) / (1.0 - math.cos(x.theta_r))
    cols = np.stack([np.where(hit, odd[..., None], 0.0), np.where(hit, even[..., None], 0.0)], -1)
    return cols.reshape(*path.shape, 2 * n_types)


def x_response_terms(
    theta_rad: np.ndarray,
    hold_axis: np.ndarray,
    g_mgal: float,
    path_rad: np.ndarray,
    path_on: np.ndarray,
    kinds: np.ndarray,
    n_types: int,
    *,
    m_level_pix: float,
    m0_pix: float,
    m0_u_pix: float = M0_TOLERANCE_PIX,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All X-response terms of a record: at the holds (H, C), along the slews (H, M, C) and
    their prior variances (C,) — the holds' 2A terms (:func:`x_response_basis`), then the
    slews' 2T (:func:`x_response_path`), each zero where the other acts, then the level
    angle's one column at both (:func:`level_angle_column`, at the level reading
    ``m_level_pix`` and the CCD centre ``m0_pix``; prior sd ``m0_u_pix``, the horizontal's
    standard uncertainty about the centre). The odd terms keep the default tolerance's
    width whatever ``m0_u_pix`` is: a known horizontal does not make the odd part of what
    eq. (6) lacks known."""
    theta = np.asarray(theta_rad, dtype=float)
    hold, var = x_response_basis(theta, hold_axis, g_mgal)
    x = _x_angles(theta, hold_axis)
    if x is None:
        return hold, np.zeros((*np.shape(path_rad), 0)), var
    path = x_response_path(theta, hold_axis, path_rad, path_on, kinds, n_types)
    n_hold, n_path = hold.shape[1], path.shape[-1]
    per_type = var[:2]  # a slew's odd and even terms: the priors of the holds' terms
    level = level_angle_column(np.where(x.on, theta, 0.0), g_mgal, m_level_pix, m0_pix)
    level_path = level_angle_column(
        np.where(path_on, np.asarray(path_rad, dtype=float), 0.0), g_mgal, m_level_pix, m0_pix
    )
    return (
        np.concatenate([hold, np.zeros((hold.shape[0], n_path)), level[:, None]], axis=1),
        np.concatenate(
            [np.zeros((*path.shape[:-1], n_hold)), path, level_path[..., None]], axis=-1
        ),
        np.concatenate([var, np.tile(per_type, n_path // 2), [m0_u_pix**2]]),
    )


def level_angle_column(
    theta_rad: np.ndarray, g_mgal: float, m_level_pix: float, m0_pix: float
) -> np.ndarray:
    """∂/∂m₀ of the even part of eq. (6)'s reading at tilts θ about X, pix per pix, at the
    nominal b and K (it changes by 0.5 % over the tolerance of Δm₀, and
    by 2·δb/b + 2·δK/K, a few per cent at most, with the parameters):

        λδ = g[−(1 − cos θ) cos φ + (cos φ − cos φ_h) + sin θ sin φ],  φ = φ_h + δ,
        φ_h = (m_h − m₀)/K,  λ = bK cos φ_h − g sin φ_h,  E_even = K(δ(θ) + δ(−θ))/2;

    δ by the forward model's own Newton steps (:func:`chekan.physics.sensor.newton_deflection`), a
    central difference of ±1 pix (exact for a function this close to linear)."""
    theta = np.asarray(theta_rad, dtype=float)
    K, b = K_NOMINAL_PIX_PER_RAD, B_NOMINAL_MGAL_PER_PIX

    def even(m0: float) -> np.ndarray:
        phi_h = (m_level_pix - m0) / K
        lam = b * K * math.cos(phi_h) - g_mgal * math.sin(phi_h)
        out = np.zeros_like(theta)
        for t in (theta, -theta):  # about X: Δu_z = −(1 − cos θ), u_y = sin θ, u_zh = 1
            du_z = -2.0 * np.sin(0.5 * t) ** 2
            delta = newton_deflection(du_z, np.sin(t), 1.0, phi_h, lam, g_mgal, NEWTON_STEPS + 1)
            out = out + 0.5 * K * delta
        return out

    return 0.5 * (even(m0_pix + 1.0) - even(m0_pix - 1.0))


def x_response_basis(
    theta_rad: np.ndarray, hold_axis: np.ndarray, g_mgal: float
) -> tuple[np.ndarray, np.ndarray]:
    """The columns (H, 2A) at the holds, odd then even for each of the A angle magnitudes
    of the X holds (zero at Y and level holds), and their prior variances (2A,) in pix²;
    (H, 0) and (0,) when no hold tilts about X."""
    theta = np.asarray(theta_rad, dtype=float)
    x = _x_angles(theta, hold_axis)
    if x is None:
        return np.zeros((theta.size, 0)), np.zeros(0)
    odd = np.sin(theta) / math.sin(x.theta_r)
    even = (1.0 - np.cos(theta)) / (1.0 - math.cos(x.theta_r))
    cols = []
    for a in x.groups:
        member = x.on & (x.key == a)
        cols += [np.where(member, odd, 0.0), np.where(member, even, 0.0)]
    sd_odd = g_mgal * math.sin(x.theta_r) * M0_TOLERANCE_PIX
    sd_odd /= B_NOMINAL_MGAL_PER_PIX * K_NOMINAL_PIX_PER_RAD
    sd_even = EVEN_BOUND_MGAL / math.sqrt(3.0) / B_NOMINAL_MGAL_PER_PIX
    return np.stack(cols, axis=1), np.tile([sd_odd**2, sd_even**2], x.groups.size)
