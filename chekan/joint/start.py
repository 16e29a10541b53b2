"""Where the MAP starts: θ from the classical fit, and a τ read off the settling transients.

The first Gauss–Newton pass starts from the classical b₁, b₂, a (K = √(g/2a), eq. 10) and
ε, with τ₀ = 30 s. Where that pass fails or lands in the prior's tails, it is redone first
from the record's own τ (:func:`tau_from_transients`, the ``tau_hint_s`` of
:func:`chekan.joint.map.fit_map_em`) and only then from the fixed restarts
(:data:`chekan.joint.map.TAU_RESTARTS_S`). The first start stays at 30 s so that every
record it served keeps its numbers to the last digit.
"""

from __future__ import annotations

import math

import numpy as np

from chekan.joint.problem import K_DESIGN

#: τ (s) where no record tells it (legacy protocols have no samples): the prior's median
TAU_START_S = 30.0
#: τ (s) searched by :func:`tau_from_transients`: a coarse grid (neighbours 58 % apart), then
#: a fine one across the best coarse point's neighbours (8 % apart), then a parabola
TAU_COARSE_S = np.geomspace(1.0, 1000.0, 16)
_FINE_POINTS = 13
#: seconds of each hold, from its start, that the transient fit uses
TRANSIENT_WINDOW_S = 600.0
_MIN_SAMPLES = 8


def initial_values(classical, g: float, tau_s: float = TAU_START_S) -> dict[str, float]:
    """θ to start the MAP from: the classical fit (a = g/2K², eq. 10; the design K where
    the classical fit is of rounds about X alone, whose a is about 5× eq. 10's) and
    ``tau_s``."""
    a = classical.a
    about_x = getattr(classical, "axis", "y") == "x"  # X rounds alone: their a is not eq. 10's
    K = float(np.sqrt(g / (2 * a))) if a > 0 and not about_x else K_DESIGN
    eps = classical.eps_arcmin if classical.eps_arcmin is not None else np.zeros(2)
    return {
        "b1": float(classical.b_mean[0]),
        "b2": float(classical.b_mean[1]),
        "K": K,
        "eps1_arcmin": float(eps[0]),
        "eps2_arcmin": float(eps[1]),
        "dgamma_arcmin": 0.0,
        "tau_s": float(tau_s),
    }


def tau_from_transients(record, holds) -> float:
    """The lag τ (s) that best fits first-order settling in every hold, or ``TAU_START_S``.

    A hold starts where its slew ends; from then on the platform is still and the reading
    relaxes to its equilibrium, m(t) = cₖⱼ + Aₖⱼ e^{−t/τ} (t from the hold's start; the lag
    of the model's reading, the same in both systems). For each τ, cₖⱼ and Aₖⱼ are linear and
    projected out (least squares per hold k and system j over the first
    ``TRANSIENT_WINDOW_S`` of each hold), and the summed residual sum of squares S(τ) is
    minimised: on ``TAU_COARSE_S``, then on a fine grid between the best point's neighbours,
    then by a parabola in log τ. Holds with large transients weigh most. This is a start,
    not an estimate: drift and noise are ignored, and the MAP estimates τ with the full
    model. Host NumPy, ≈ 5 ms for a one-round session and 25–35 ms for a 3 h or 9 h record.
    """
    t = np.asarray(record.t_s, dtype=float)
    m = np.stack([record.m1_pix, record.m2_pix], axis=1).astype(float)
    pieces = []  # (t from the hold's start, centred reading) per hold and system
    for a, b in zip(holds.start, holds.stop, strict=True):
        tt = t[a:b] - t[a]
        inside = (tt <= TRANSIENT_WINDOW_S) & np.isfinite(tt)
        for j in range(2):
            ok = inside & np.isfinite(m[a:b, j])
            if ok.sum() >= _MIN_SAMPLES:
                y = m[a:b, j][ok]
                pieces.append((tt[ok], y - y.mean()))
    if not pieces:
        return TAU_START_S

    def ssr(grid: np.ndarray) -> np.ndarray:
        """S(τ) on ``grid``: the residual sum of squares left by c + A e^{−t/τ}."""
        out = np.zeros(grid.size)
        for tt, yc in pieces:
            e = np.exp(-tt[None, :] / grid[:, None])  # (G, n)
            e -= e.mean(axis=1, keepdims=True)
            num = e @ yc
            den = np.einsum("gn,gn->g", e, e)
            out += yc @ yc - np.divide(num * num, den, out=np.zeros_like(num), where=den > 1e-300)
        return out

    coarse = ssr(TAU_COARSE_S)
    if not np.all(np.isfinite(coarse)):
        return TAU_START_S
    k = int(np.argmin(coarse))
    lo, hi = TAU_COARSE_S[max(k - 1, 0)], TAU_COARSE_S[min(k + 1, TAU_COARSE_S.size - 1)]
    grid = np.geomspace(lo, hi, _FINE_POINTS)
    s = ssr(grid)
    k = int(np.argmin(s))
    if 0 < k < grid.size - 1:  # vertex of the parabola through three neighbours, in log τ
        curv = s[k - 1] - 2 * s[k] + s[k + 1]
        if curv > 0:
            step = math.log(grid[k + 1] / grid[k])
            return float(grid[k] * math.exp(0.5 * step * (s[k - 1] - s[k + 1]) / curv))
    return float(grid[k])
