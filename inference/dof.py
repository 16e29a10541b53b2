r"""How reliable a standard uncertainty is that rests on estimated variance components: the
information of the components, their share in u², ν_eff and k (GUM G.4, G.6).

The setting is the Laplace (linearised) view of a least-squares problem with whitened
stacked rows R (data rows, and the prior rows of the coefficients that have priors), all
coefficients integrated (the fixed effects and the random ones alike), J = ∂R/∂z (the
sign of R is J's: the shift d below needs both from one convention),
C = (JᵀJ)⁻¹ and the hat matrix H = J C Jᵀ. The variance of row r is Σₐ Dₐᵣ σₐ² + (a fixed
part), with Dₐᵣ the share of component a (Dₐᵣ = 1 for the prior row of a random effect of
variance σₐ², bᵣ/vᵣ for a data row whose variance vᵣ has the part bᵣ ∝ σₐ²).

For a linear Gaussian model these are exact:

- information of (log σₐ²) in the restricted (REML) likelihood (Harville 1977):
  Iₐb = ½ tr[(I − H) Dₐ (I − H) D_b];
- the estimate q̂ = qᵀẑ with influence hᵣ = qᵀ C Jᵣᵀ of each row (u² = Σᵣ hᵣ²):
  ∂u²/∂log σₐ² = Σᵣ hᵣ² Dₐᵣ (rows of a component are whitened by σₐ) and
  ∂q̂/∂log σₐ² = Σᵣ hᵣ Rᵣ Dₐᵣ (its weights change with σₐ).

With the components estimated, log σ̂² ~ N(log σ², V), V = I⁻¹, the estimate moves by
dᵀ(log σ̂² − log σ²), a variance uₕ² = dᵀ V d that belongs in q's budget, and u² itself is
uncertain, var(u²) = gᵀ V g: the effective degrees of freedom of u² as a scaled χ²,

    ν_eff = 2 u⁴ / (gᵀ V g),

which is the Welch–Satterthwaite formula (GUM G.4.1) when each component enters one line
of the budget and the components' estimates are uncorrelated (then νₐ = 1 / (2 Vₐₐ) with V
in log σ (GUM G.4.2: ν ≈ ½ (Δu/u)⁻²)); here their correlations are kept. For the mean of
n normal observations it gives ν = n − 1 exactly. The coverage factor is Student's
k = t_p(ν_eff) with ν_eff truncated to an integer (GUM G.4.1 note, G.6.4), p = 95.45 %
so that k = 2 for ν → ∞ (EA-4/02 M: 2022, appendix E).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "P_COVERAGE",
    "TypeAReliability",
    "basis_information",
    "component_information",
    "coverage_factor",
    "log_var_cov",
    "projection_basis",
    "projection_hat",
    "t_two_sided",
    "type_a_reliability",
    "welch_satterthwaite",
]

P_COVERAGE = 0.9545  # the coverage probability of k = 2 for a normal distribution
NU_CAP = 1e6  # ν_eff above this is reported as this (k = 2.000 to four decimals)


def projection_basis(basis: ArrayLike, rcond: float = 1e-8) -> np.ndarray:
    """U (n, r) with orthonormal columns spanning the columns of ``basis`` (n, k): the hat
    matrix of least squares on them is H = U Uᵀ. From a column-pivoted QR (half the cost of
    an SVD at n ≈ 2 000, k ≈ 570); a column whose |Rᵢᵢ| is at most ``rcond``·|R₀₀| adds
    nothing to the span (a rank-deficient basis projects onto its span)."""
    import scipy.linalg

    B = np.asarray(basis, dtype=float)
    if B.size == 0 or not np.any(B):
        return np.zeros((B.shape[0], 0))
    Q, R, _ = scipy.linalg.qr(B, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    return Q[:, : int(np.count_nonzero(d > rcond * d[0]))]


def projection_hat(basis: ArrayLike, rcond: float = 1e-8) -> np.ndarray:
    """H = U Uᵀ (n, n): the hat matrix of least squares on the columns of ``basis`` (n, k),
    the orthogonal projector onto their span (:func:`projection_basis`). A projection by
    construction, which a sum of two hats is only when their spans are orthogonal."""
    U = projection_basis(basis, rcond)
    return U @ U.T


def basis_information(basis_u: ArrayLike, shares: ArrayLike) -> np.ndarray:
    """:func:`component_information` for H = U Uᵀ given by U (n, r) (:func:`projection_basis`),
    without forming the n × n hat: with P = I − H,

    Σᵣₛ Dₐᵣ Pᵣₛ² D_bₛ = Σᵣ Dₐᵣ D_bᵣ (1 − 2Hᵣᵣ) + ⟨Gₐ, G_b⟩,   Gₐ = Uᵀ diag(Dₐ) U (r × r),

    each Gₐ from the rows that component a touches only."""
    U = np.asarray(basis_u, dtype=float)
    D = np.asarray(shares, dtype=float)
    h = np.einsum("ri,ri->r", U, U)  # Hᵣᵣ
    first = (D * (1.0 - 2.0 * h)) @ D.T
    G = []
    for a in range(D.shape[0]):
        rows = np.flatnonzero(D[a])
        Ua = U[rows]
        G.append((Ua.T * D[a, rows]) @ Ua)
    second = np.array([[np.sum(Ga * Gb) for Gb in G] for Ga in G]).reshape(D.shape[0], -1)
    info = 0.5 * (first + second)
    return 0.5 * (info + info.T)


def component_information(hat: ArrayLike, shares: ArrayLike) -> np.ndarray:
    """Iₐb = ½ tr[(I − H) Dₐ (I − H) D_b] = ½ Σᵣₛ Dₐᵣ Pᵣₛ² D_bₛ (P = I − H symmetric), (m, m):
    the REML information of log σₐ² from the hat matrix ``hat`` (n, n) of the stacked rows
    and ``shares`` (m, n), the rows' Dₐᵣ. Rows that no component touches may be left out
    of both (their terms vanish)."""
    H = np.asarray(hat, dtype=float)
    D = np.asarray(shares, dtype=float)
    P = np.eye(H.shape[0]) - H
    info = 0.5 * D @ (P * P) @ D.T
    return 0.5 * (info + info.T)


@dataclass(frozen=True)
class TypeAReliability:
    """What the estimated variance components mean for one estimate q̂ (module docstring)."""

    u2: float
    """u² = Σᵣ hᵣ², the variance at the estimated components."""
    cov_log_var: np.ndarray
    """V (m, m): the covariance of log σ̂ₐ² (the information's inverse)."""
    gradient: np.ndarray
    """g (m,): ∂u²/∂log σₐ²."""
    shift: np.ndarray
    """d (m,): ∂q̂/∂log σₐ²."""
    u2_components: float
    """uₕ² = dᵀ V d: the variance of q̂ from the components' estimation."""
    nu_eff: float
    """2 (u² + uₕ²)² / gᵀ V g, at most ``NU_CAP``."""
    clipped: bool = False
    """Whether V came from the positive part of an indefinite information
    (:func:`log_var_cov`): uₕ² and ν_eff then rest on an approximation that failed."""


def type_a_reliability(
    influence: ArrayLike,
    residuals: ArrayLike,
    hat: ArrayLike | None,
    shares: ArrayLike,
    prior_information: ArrayLike | None = None,
    *,
    cov_log_var: ArrayLike | None = None,
    clipped: bool = False,
) -> TypeAReliability:
    """The components' information, uₕ² and ν_eff for an estimate with row influences
    ``influence`` (n,), at the rows' whitened ``residuals`` (n,), with the stacked rows'
    ``hat`` matrix (n, n) and the components' ``shares`` (m, n) of each row's variance.
    ``prior_information`` (m, m): of a prior on log σ² that the estimate of the components
    used (added to the data's). ``cov_log_var``: V when already known (:func:`log_var_cov`;
    then ``hat`` and ``prior_information`` are not used, and ``hat`` may be None;
    ``clipped``: whether that V came from an indefinite information, carried into the
    result)."""
    if hat is None and cov_log_var is None:
        raise ValueError("type_a_reliability needs the hat matrix or cov_log_var")
    h = np.asarray(influence, dtype=float)
    r = np.asarray(residuals, dtype=float)
    D = np.asarray(shares, dtype=float)
    V = (
        np.asarray(cov_log_var, dtype=float)
        if cov_log_var is not None
        else log_var_cov(np.asarray(hat, dtype=float), D, prior_information)
    )
    g = D @ h**2
    d = D @ (h * r)
    u2 = float(np.sum(h**2))
    uh2 = float(d @ V @ d)
    nu = welch_satterthwaite(u2 + uh2, float(g @ V @ g))
    return TypeAReliability(u2, V, g, d, uh2, nu, clipped)


def welch_satterthwaite(u2: float, var_u2: float) -> float:
    """ν_eff = 2 u⁴ / var(u²) (GUM G.4.1 with the components' correlations, module
    docstring), at most ``NU_CAP``."""
    return NU_CAP if var_u2 <= 2 * u2**2 / NU_CAP else float(2 * u2**2 / var_u2)


def log_var_cov(
    hat: ArrayLike, shares: ArrayLike, prior_information: ArrayLike | None = None
) -> np.ndarray:
    """V = I⁻¹ (m, m), the covariance of log σ̂ₐ² (:func:`component_information`, plus the
    information of a prior on log σ² where the estimate used one); a component the rows do
    not inform gets V from the pseudo-inverse (0: it adds nothing). An information with
    negative eigenvalues (a ``hat`` that is not a projection: eigenvalues above 1 on a
    record that barely determines its parameters) is taken at its positive part first: its
    inverse would be no covariance, and uₕ² = dᵀVd came out negative (a stated sd of 0)."""
    return cov_of_information(total_information(hat, shares, prior_information))[0]


def cov_of_information(info: ArrayLike) -> tuple[np.ndarray, bool]:
    """(V, clipped): the pseudo-inverse of the information ``info`` (m, m), taken at its
    positive part where it is :func:`indefinite` (``clipped``; :func:`log_var_cov`)."""
    a = np.asarray(info, dtype=float)
    w, U = np.linalg.eigh(a)
    clipped = indefinite(w)
    if clipped:
        a = (U * np.clip(w, 0.0, None)) @ U.T
    return np.linalg.pinv(a, hermitian=True), clipped


def total_information(
    hat: ArrayLike, shares: ArrayLike, prior_information: ArrayLike | None = None
) -> np.ndarray:
    """The components' information from the rows plus that of a prior on log σ²."""
    info = component_information(hat, shares)
    if prior_information is not None:
        info = info + np.asarray(prior_information, dtype=float)
    return info


def indefinite(eigenvalues: ArrayLike) -> bool:
    """Whether an information's ascending ``eigenvalues`` go below zero beyond round-off
    (:func:`log_var_cov` then takes its positive part)."""
    w = np.asarray(eigenvalues, dtype=float)
    return bool(w.size and w[0] < -1e-12 * max(abs(w[-1]), np.finfo(float).tiny))


def coverage_factor(nu_eff: float, p: float = P_COVERAGE) -> float:
    """k = t_p(ν) of Student's t, ν truncated to an integer (GUM G.4.1), two-sided
    probability ``p``; ν ≥ ``NU_CAP`` (or inf) gives the normal quantile; 0 < ν < 1
    truncates to no degree of freedom at all: no finite k (``inf``; the caller says why)."""
    if not (0.0 < p < 1.0):
        raise ValueError(f"the coverage probability must lie in (0, 1): {p}")
    if not nu_eff > 0.0:  # also NaN
        raise ValueError(f"the effective degrees of freedom must be positive: {nu_eff}")
    if nu_eff < 1.0:
        return math.inf
    if nu_eff >= NU_CAP or math.isinf(nu_eff):
        return NormalDist().inv_cdf(0.5 + p / 2.0)
    return t_two_sided(math.floor(nu_eff), p)


SERIES_MAX_NU = 2000  # exact series below, the Cornish–Fisher expansion above (error < 1e-9)


def t_two_sided(nu: int, p: float) -> float:
    """t with P(|T| < t) = p for Student's T with ``nu`` (integer) degrees of freedom.

    Exact for ν ≤ ``SERIES_MAX_NU``: bisection on the finite series of the distribution
    function (Abramowitz & Stegun 26.7.3–4, θ = atan(t/√ν)); above it the Cornish–Fisher
    expansion in 1/ν to the fourth order (A&S 26.7.5). No ``scipy.special``: a new MAP
    process does not import it (0.2–0.7 s)."""
    if nu < 1:
        raise ValueError(f"degrees of freedom must be a positive integer: {nu}")
    z = NormalDist().inv_cdf(0.5 + p / 2.0)
    if nu > SERIES_MAX_NU:
        return (
            z
            + (z**3 + z) / (4 * nu)
            + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * nu**2)
            + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * nu**3)
            + (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / (92160 * nu**4)
        )
    lo, hi = 0.0, max(2.0 * z, 1.0)
    while _t_inside(hi, nu) < p:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _t_inside(mid, nu) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-12 * hi:
            break
    return 0.5 * (lo + hi)


def _t_inside(t: float, nu: int) -> float:
    """P(|T| < t) for integer ν (A&S 26.7.3–4)."""
    th = math.atan(t / math.sqrt(nu))
    c2, s = math.cos(th) ** 2, math.sin(th)
    if nu == 1:
        return 2.0 * th / math.pi
    if nu % 2 == 0:  # sin θ (1 + ½cos²θ + (1·3)/(2·4)cos⁴θ + … up to cos^(ν−2)θ)
        j = np.arange(1, nu // 2)
        terms = np.cumprod((2 * j - 1) / (2 * j) * c2)
        return float(s * (1.0 + terms.sum()))
    # odd: (2/π)(θ + sinθ cosθ (1 + (2/3)cos²θ + … up to cos^(ν−3)θ))
    j = np.arange(1, (nu - 1) // 2)
    terms = np.cumprod((2 * j) / (2 * j + 1) * c2)
    return float(2.0 / math.pi * (th + s * math.cos(th) * (1.0 + terms.sum())))
