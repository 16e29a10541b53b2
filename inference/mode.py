r"""Mode and Laplace covariance of a black-box, vectorised log-density (finite differences).

For a sampler's proposal we need :math:`\hat z = \arg\max \log p(z)` and
:math:`\Sigma = (-\nabla^2 \log p(\hat z))^{-1}` of the *marginal* posterior (hyper-
parameters included), using only the batched log-density the sampler already compiled
(no new traces). In whitened coordinates :math:`u = L^{-1}(z - z_k)`, :math:`LL^\top = \Sigma_k`,
central differences with step :math:`h` give

.. math::
    g_i = \frac{f(he_i) - f(-he_i)}{2h},\quad
    H_{ii} = \frac{f(he_i) - 2f(0) + f(-he_i)}{h^2},\quad
    H_{ij} = \frac{f(h e_i + h e_j) - f(he_i - he_j) - f(-he_i + he_j) + f(-he_i - he_j)}{4h^2},

all :math:`2d^2 + 1` points in one batch. A trust-region Newton step
:math:`u = (A + \mu I)^{-1} g`, :math:`A = -H` (shifted if not positive definite, μ the
smallest keeping ‖u‖ within the radius; the radius grows on success and shrinks until
:math:`f` increases) and, where A is positive definite,
:math:`\Sigma_{k+1} = L A^{-1} L^\top` are iterated.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["refine_mode"]


def _fd_points(d: int, h: float) -> np.ndarray:
    """Whitened offsets: 0, ±h eᵢ, then (±h eᵢ ± h eⱼ) for i < j in the order ++, +−, −+, −−."""
    eye = np.eye(d) * h
    pts = [np.zeros((1, d)), eye, -eye]
    i, j = np.triu_indices(d, 1)
    for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        pts.append(si * eye[i] + sj * eye[j])
    return np.concatenate(pts)


def _fd_derivatives(f: np.ndarray, d: int, h: float) -> tuple[np.ndarray, np.ndarray]:
    f0, fp, fm = f[0], f[1 : 1 + d], f[1 + d : 1 + 2 * d]
    g = (fp - fm) / (2 * h)
    H = np.diag((fp - 2 * f0 + fm) / h**2)
    m = d * (d - 1) // 2
    pp, pm, mp, mm = (f[1 + 2 * d + k * m : 1 + 2 * d + (k + 1) * m] for k in range(4))
    i, j = np.triu_indices(d, 1)
    H[i, j] = H[j, i] = (pp - pm - mp + mm) / (4 * h**2)
    return g, H


def refine_mode(
    log_density: Callable[[np.ndarray], np.ndarray],
    z0: np.ndarray,
    cov0: np.ndarray,
    *,
    iterations: int = 12,
    h: float = 0.05,
    radius: float = 1.0,
    gtol: float = 0.05,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Trust-region Newton from ``z0`` in the metric of ``cov0`` (module docstring).

    ``log_density``: (n, d) → (n,) NumPy, −inf outside the support. Each iteration: the
    finite-difference gradient g and Hessian H in whitened units; A = −H shifted to be
    positive definite if it is not; step (A + μI)⁻¹g with μ ≥ 0 the smallest that keeps
    the step within the trust radius; accepted if the log density rises (radius doubled),
    else the radius is quartered. Where A is positive definite the metric is updated to
    the Laplace covariance L A⁻¹ Lᵀ. Stops when ‖g‖ < ``gtol`` with A positive definite.
    Returns ``(mode, cov, info)``; ``info["laplace"]`` says whether ``cov`` is the
    Laplace covariance at the returned point (negative-definite curvature there).
    """
    z = np.asarray(z0, float).copy()
    cov = np.asarray(cov0, float)
    d = z.size
    pts = _fd_points(d, h)
    info = {"iterations": 0, "grad_norm": np.inf, "laplace": False}
    for it in range(iterations):
        L = np.linalg.cholesky(cov)
        f = np.asarray(log_density(z + pts @ L.T), float)
        if not np.all(np.isfinite(f)):
            break  # at the edge of the support: keep what we have
        g, H = _fd_derivatives(f, d, h)
        w, V = np.linalg.eigh(-0.5 * (H + H.T))
        gn = float(np.linalg.norm(g))
        pd = bool(w.min() > 1e-8 * max(w.max(), 1e-300))
        info.update(iterations=it + 1, grad_norm=gn, laplace=pd)
        if pd:
            cov_new = (L @ V / w) @ (L @ V).T
            cov_new = 0.5 * (cov_new + cov_new.T)
        if pd and gn < gtol:
            return z, cov_new, info
        shift = 0.0 if pd else abs(float(w.min())) + 1e-3 * max(abs(float(w.max())), 1.0)
        gv = V.T @ g
        improved = False
        for _ in range(10):
            mu = _shift_for_radius(w + shift, gv, radius)
            step = V @ (gv / (w + shift + mu))
            z_try = z + L @ step
            f_try = float(np.asarray(log_density(z_try[None, :]), float)[0])
            if np.isfinite(f_try) and f_try > f[0]:
                z, improved = z_try, True
                radius = min(2.0 * radius, 8.0)
                break
            radius *= 0.25
        if pd:
            cov = cov_new
        if not improved:
            break
    return z, cov, info


def _shift_for_radius(w: np.ndarray, gv: np.ndarray, radius: float) -> float:
    """Smallest μ ≥ 0 with ‖gv/(w + μ)‖ ≤ radius (w > 0), by bisection on log μ."""

    def norm(mu: float) -> float:
        return float(np.linalg.norm(gv / (w + mu)))

    if norm(0.0) <= radius:
        return 0.0
    lo, hi = 0.0, max(float(np.linalg.norm(gv)) / radius, 1e-12)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if norm(mid) > radius:
            lo = mid
        else:
            hi = mid
    return hi
