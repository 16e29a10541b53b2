r"""Gauss–Newton that stops when its next step is small *in posterior standard deviations*.

For whitened residuals :math:`r(z)` (:mod:`inference.problem`: :math:`r \sim N(0, I)`) the
Gauss–Newton matrix :math:`H = J^\top J` is the Laplace precision of :math:`z`, and the
step :math:`\delta = -(J^\top J)^{-1}J^\top r` from a linearisation point has the Newton
decrement

.. math::  \lambda = \sqrt{\delta^\top H \delta} = \lVert J\delta\rVert_2 .

By Cauchy–Schwarz, for any linear functional :math:`u^\top z` (a parameter, a derived
quantity to first order), :math:`|u^\top\delta| \le \lambda\,\sqrt{u^\top H^{-1}u}`: the
step moves every one of them by at most :math:`\lambda` of its own sd. The solver stops at
the first linearisation with :math:`\lambda <` ``sd_tol`` (or when optimistix's Cauchy test
on the step just taken passes, as :class:`optimistix.GaussNewton` does). Its last step has
been *computed* but not taken: :func:`inference.map.fit_map` takes it, so the answer is
within about :math:`\rho\,\lambda` of the optimum (ρ the contraction per step: ≈ 10⁻³ on
the calibration records), one linearisation earlier than a test that must see the step
taken. The stopping test on the step taken alone needs the step after a small one to be
taken first, and a fixed tolerance in working units means different sds for different
parameters.

Subclasses :class:`optimistix.AbstractGaussNewton` the way optimistix's own solvers do
(same descent, search and state); only ``terminate`` is new.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import lineax as lx
import optimistix as optx

__all__ = ["DecrementGaussNewton"]


def _quiet(**_: Any) -> None:
    """No logging (optimistix's ``verbose=False``)."""


class DecrementGaussNewton(optx.AbstractGaussNewton):
    """Undamped Gauss–Newton (:class:`optimistix.GaussNewton`) with the decrement test
    (module docstring). ``sd_tol``: the step length, in posterior sds, below which the
    solve stops; ``rtol``/``atol``: optimistix's Cauchy test, kept as a second way out."""

    rtol: float
    atol: float
    sd_tol: float
    norm: Callable[[Any], Any]
    descent: optx.NewtonDescent
    search: optx.LearningRate
    verbose: Callable[..., None]

    def __init__(self, rtol: float, atol: float, sd_tol: float):
        if not (0.0 < sd_tol < 1.0):
            raise ValueError(f"sd_tol is a fraction of a standard deviation in (0, 1): {sd_tol}")
        self.rtol = rtol
        self.atol = atol
        self.sd_tol = sd_tol
        self.norm = optx.max_norm
        self.descent = optx.NewtonDescent(linear_solver=lx.AutoLinearSolver(well_posed=None))
        self.search = optx.LearningRate(1.0)
        self.verbose = _quiet

    def terminate(self, fn, y, args, options, state, tags):
        """Cauchy's test on the step taken, or λ = ‖J δ‖ < ``sd_tol`` for the step δ
        computed at the last linearisation (none before the first). optimistix calls this
        with the point *before* the step just taken, so δ is read from the descent's state
        (J⁺r, the step's negative: :class:`optimistix.NewtonDescent` at step size 1), not
        from ``y``."""
        cauchy, result = super().terminate(fn, y, args, options, state, tags)
        newton = state.descent_state.newton
        decrement = optx.two_norm(state.f_info.jac.mv(newton))  # residuals of any pytree
        small = jnp.invert(state.first_step) & (decrement < self.sd_tol)
        return cauchy | small, result
