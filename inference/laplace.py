r"""Laplace (Gauss–Newton) covariance from the Jacobian of the stacked whitened residuals.

With :math:`J = \partial r / \partial z` at the MAP (priors appended as rows),
:math:`\Sigma_z = (J^\top J)^{-1}`. It is computed from the thin SVD :math:`J = U S V^\top`
(never by forming :math:`J^\top J`, which squares the condition number):

.. math::  \Sigma_z = V\,\mathrm{diag}(s_i^{-2})\,V^\top .

Directions with :math:`s_i \le \text{rcond}\cdot s_\max` are *not identified* by data and
prior. Instead of failing, they get infinite variance: :math:`\Sigma_z = (J^\top J)^+ +
\infty\cdot P_0` with :math:`P_0` the projector onto those directions (the limit of a vanishing
prior along them). Coordinates outside their support keep their exact finite variances.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["DEFAULT_RCOND", "LaplaceCovariance", "laplace_covariance", "laplace_from_svd"]

DEFAULT_RCOND = 1e-8
"""Singular values below ``rcond * s_max`` are treated as zero: cond(JᵀJ) would exceed 1e16."""

_SUPPORT_TOL = 1e-8  # |P0_ij| below this is round-off, not participation


@dataclass(frozen=True)
class LaplaceCovariance:
    """Result of :func:`laplace_covariance`; unpacks as ``(cov, cond, degenerate_directions)``."""

    cov: np.ndarray
    """(p, p) covariance in z; ±inf where not identified."""
    cond: float
    """s_max / s_min of J (inf if rank deficient)."""
    degenerate_directions: np.ndarray
    """(k, p) orthonormal rows spanning the unidentified subspace (k = 0 when all is well)."""
    degenerate_mask: np.ndarray
    """(p,) bool: coordinates touched by an unidentified direction (their variance is inf)."""

    def __iter__(self):
        return iter((self.cov, self.cond, self.degenerate_directions))


def laplace_from_svd(
    s: ArrayLike, vt: ArrayLike, *, rcond: float = DEFAULT_RCOND
) -> LaplaceCovariance:
    """Laplace covariance from the singular values ``s`` (p,) and right vectors ``vt`` (p, p)."""
    s = np.asarray(s, dtype=float)
    vt = np.asarray(vt, dtype=float)
    p = vt.shape[-1]
    if s.shape != (p,) or vt.shape != (p, p):
        raise ValueError(
            f"need s of shape (p,) and vt of shape (p, p) (thin SVD of an n×p Jacobian with "
            f"n ≥ p); got {s.shape} and {vt.shape}. Fewer residuals than parameters means the "
            "problem is under-determined: add priors."
        )
    if not np.all(np.isfinite(s)):
        nan = np.full((p, p), np.nan)
        return LaplaceCovariance(nan, np.nan, np.zeros((0, p)), np.zeros(p, bool))
    s_max = float(s.max()) if p else 0.0
    good = s > rcond * s_max if s_max > 0 else np.zeros(p, bool)
    s_min = float(s.min()) if p else 0.0
    cond = s_max / s_min if s_min > 0 else np.inf
    vg = vt[good]
    cov = (vg.T / s[good] ** 2) @ vg
    dirs = vt[~good]
    mask = np.zeros(p, bool)
    if dirs.shape[0]:
        proj = dirs.T @ dirs
        support = np.abs(proj) > _SUPPORT_TOL
        with np.errstate(invalid="ignore"):
            cov = np.where(support, np.sign(proj) * np.inf, cov)
        mask = np.diag(support).copy()
    return LaplaceCovariance(0.5 * (cov + cov.T), cond, dirs, mask)


def laplace_covariance(jac: ArrayLike, *, rcond: float = DEFAULT_RCOND) -> LaplaceCovariance:
    """``(cov, cond, degenerate_directions)`` of the Gauss–Newton posterior from ``J`` (n, p)."""
    jac = np.asarray(jac, dtype=float)
    if jac.ndim != 2:
        raise ValueError(f"Jacobian must be 2-D (n residuals, p parameters), got {jac.shape}")
    n, p = jac.shape
    if n < p:  # pad with zero rows: the thin SVD then has p singular values (some 0)
        jac = np.vstack([jac, np.zeros((p - n, p))])
    if not np.all(np.isfinite(jac)):
        return laplace_from_svd(np.full(p, np.nan), np.eye(p), rcond=rcond)
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    return laplace_from_svd(s, vt, rcond=rcond)
