"""Where the MAP starts: θ from the classical fit, and a τ read off the settling transients.

The first Gauss–Newton pass starts from the classical b₁, b₂, a (K = √(g/2a), eq. 10) and
ε, with τ₀ = 30 s. Where that pass fails or lands in the prior's tails, it is redone first
from the record's own τ (:func:`chekan.classical.settling.tau_from_transients`, the
``tau_hint_s`` of
:func:`chekan.fit.map.fit_map_em`) and only then from the fixed restarts
(:data:`chekan.fit.map.TAU_RESTARTS_S`). The first start stays at 30 s so that every
record it served keeps its numbers to the last digit.
"""

from __future__ import annotations

import numpy as np

from chekan.classical.settling import TAU_START_S
from chekan.joint.problem import K_DESIGN


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
