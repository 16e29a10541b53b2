"""How reliable the MAP's uncertainties are: the hyperparameters are estimated (GUM Type A).

The MAP's sd is the Laplace sd at the hyperparameters' EM values h = (s₁, s₂, κ, σ_θ, σ_o).
They rest on a finite record (σ_θ on a few dozen holds: its estimate scatters by ~25 % on
the paper's program), which has two consequences (:mod:`inference.dof`, with the
algebra):

- the estimate moves with ĥ: var(q̂) gains uₕ² = dᵀ V d (d = ∂q̂/∂log h², V the
  covariance of log ĥ²), added to the reported sd;
- u² is itself an estimate, with ν_eff effective degrees of freedom (Welch–Satterthwaite,
  GUM G.4.1, the correlations of the components' estimates kept): the expanded
  uncertainty is U = k·u with k = t₉₅.₄₅(ν_eff) (GUM G.6.4), not 2.

The stacked rows are those of the MAP's last pass, R = [r_w (bins × 2), β̂/√Λ, θ's prior
rows], with the columns J (the MAP's Jacobian in θ, β projected out) and
∂R/∂β = [−Ã; Λ^{-1/2}; 0] (r_w = √w (r − Aβ): the data rows carry −Ã, the prior rows
+Λ^{-1/2}). J is orthogonal to ∂R/∂β (β̂ is stationary given θ; 2e-6 relative on a 9 h
record), and the hat matrix of the joint (θ, β) problem is the projector onto their span
(:func:`inference.dof.projection_basis`). (With K = [Ã; Λ^{-1/2}; 0], whose data rows have
the other sign, J is not orthogonal to K: H_β + J C_θ Jᵀ was no projection, eigenvalues up
to 1.9, and on a six-hold record the information came out indefinite.) The
shares of each row's variance: sⱼ: (sⱼσⱼ)²/n / vᵢ of system j's bins, κ: (κ tᵢ)²/vᵢ, σ_θ
and σ_o: 1 on the prior rows of the angle errors and of the hold offsets of real holds.
The noise M-step uses the priors of log s and log κ (:mod:`chekan.joint.em`), so their
information is added; σ_θ's and σ_o's M-steps use none.

A derived quantity g(θ, β) (a, b₀, the drift slopes) has the row influence
∂g/∂θ C_θ Jᵀ + ∂g/∂β M⁻¹ (∂R/∂β)ᵀ (the change of ĝ with each row's residual, up to a common
sign; the two parts are orthogonal, so Σ hᵣ² is the delta method's var g).
"""

from __future__ import annotations

import numpy as np

from chekan.fit.map import MapFit
from chekan.joint.layout import ModelStructure
from chekan.joint.problem import hyper_params
from inference.dof import (
    TypeAReliability,
    basis_information,
    cov_of_information,
    projection_basis,
    type_a_reliability,
)

_PRIOR = {p.name: p for p in hyper_params()}
#: the information of a prior on log σ² (sd of log σ² = 2·sd of log σ) that the EM uses
PRIOR_INFO = np.diag(
    [
        1.0 / (2.0 * _PRIOR["noise_scale"].scale) ** 2,
        1.0 / (2.0 * _PRIOR["noise_scale"].scale) ** 2,
        1.0 / (2.0 * _PRIOR["slew_error"].scale) ** 2,
        0.0,
        0.0,
    ]
)
COMPONENTS = ("noise_scale_1", "noise_scale_2", "slew_error", "sigma_theta", "sigma_hold")


def row_shares(fit: MapFit, base: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """(5, rows) shares Dₐᵣ of the components ``COMPONENTS`` in each stacked row's
    variance (module docstring); ``base``, ``trans`` (N, 2) from the MAP's derived pass."""
    structure: ModelStructure = fit.model.structure
    data = fit.model.data
    n_rows = np.asarray(fit.result.jacobian).shape[0]
    N = structure.n_bins
    mask = np.asarray(data.mask)
    t2 = (float(fit.hyper["slew_error"]) * np.asarray(trans)) ** 2
    nv = np.asarray(base) + t2
    with np.errstate(invalid="ignore", divide="ignore"):
        s_share = np.where(mask, np.asarray(base) / nv, 0.0)
        k_share = np.where(mask, t2 / nv, 0.0)
    D = np.zeros((5, n_rows))
    D[0, : 2 * N] = (s_share * [1.0, 0.0]).reshape(-1)  # bins' rows in (bin, system) order
    D[1, : 2 * N] = (s_share * [0.0, 1.0]).reshape(-1)
    D[2, : 2 * N] = k_share.reshape(-1)
    blocks = structure.beta_blocks
    hold = np.asarray(data.hold_mask, dtype=float)
    D[3, 2 * N + blocks["angle_error"]] = hold
    D[4, 2 * N + blocks["hold_offset"]] = np.tile(hold, 2)
    return D


def beta_columns(fit: MapFit, A_w: np.ndarray, prior_var: np.ndarray) -> np.ndarray:
    """∂R/∂β (rows, p): β's columns in the stacked rows, [−Ã; Λ^{-1/2}; 0] (module
    docstring)."""
    N, p = fit.model.structure.n_bins, fit.model.structure.n_beta
    K = np.zeros((np.asarray(fit.result.jacobian).shape[0], p))
    K[: 2 * N] = -np.asarray(A_w).reshape(2 * N, p)
    K[2 * N + np.arange(p), np.arange(p)] = 1.0 / np.sqrt(np.asarray(prior_var))
    return K


def stacked_basis(fit: MapFit, dR_dbeta: np.ndarray) -> np.ndarray:
    """U with orthonormal columns spanning [J, ∂R/∂β]: the joint (θ, β) problem's hat matrix
    of the stacked rows is U Uᵀ, the projector onto that span (module docstring)."""
    return projection_basis(np.concatenate([np.asarray(fit.result.jacobian), dR_dbeta], axis=1))


def reliabilities(
    fit: MapFit,
    Jz: np.ndarray,
    Jb: np.ndarray,
    Minv: np.ndarray,
    A_w: np.ndarray,
    base: np.ndarray,
    trans: np.ndarray,
    prior_var: np.ndarray,
) -> list[TypeAReliability]:
    """One :class:`inference.dof.TypeAReliability` per derived quantity (rows of ``Jz`` (q, z)
    and ``Jb`` (q, p), their derivatives in θ (total) and β), from the pieces of
    :func:`chekan.joint.derived.map_derived_fn` (M⁻¹, Ã, base, transient, Λ)."""
    res = fit.result
    J = np.asarray(res.jacobian)
    cov = np.asarray(res.cov_z)
    C = np.where(np.isfinite(cov), cov, 0.0)
    K = beta_columns(fit, A_w, prior_var)  # ∂R/∂β
    KM = K @ Minv
    U = stacked_basis(fit, K)
    D = row_shares(fit, base, trans)
    # rows that no component touches (θ's and β's fixed priors) drop out of the traces
    used = np.any(D != 0, axis=0)
    V, clipped = cov_of_information(basis_information(U[used], D[:, used]) + PRIOR_INFO)
    infl = np.asarray(Jz) @ C @ J.T + np.asarray(Jb) @ KM.T  # (q, rows)
    R = np.asarray(res.residuals)
    return [type_a_reliability(h, R, None, D, cov_log_var=V, clipped=clipped) for h in infl]
