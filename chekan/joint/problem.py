"""The joint model as estimation problems: parameters, priors, the MAP least squares by
variable projection, the marginal log-density; one problem per model structure.

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
κ                       log κ ~ N(log 0.003, 1.5)          slew error, weak
c (pix)                 N(0, 1)                            around m_ref (classical m_h, then
                                                           the estimate: between_passes)
d (pix)                 N(0, 2²) per coefficient           drift over a session ≲ a few pixels
======================  =================================  ===================================

The sampler sees θ = (b₁, b₂, log K, ε₁, ε₂, Δγ, log τ) and the hyperparameters
(log s₁, log s₂, log σ_θ, log σ_o, log κ): 12 dimensions; β is marginalised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from chekan.jaxconfig import device_array
from chekan.joint.beta_posterior import solve_beta
from chekan.joint.hold_blocks import block_normal_equations
from chekan.joint.layout import ModelStructure, RecordData
from chekan.joint.likelihood import beta_prior_var
from chekan.physics.parameters import unit_of
from inference.normal_eq import marginal_loglik_blocks, split_prior
from inference.params import Param, ParamSpace
from inference.problem import LeastSquaresProblem

K_DESIGN = 60428.0
B_LOC = (6.9, 6.9)

Hyper = dict[str, jax.Array]
"""Hyperparameters: noise_scale (2,), sigma_theta_arcsec, sigma_hold_pix, slew_error."""


def nonlinear_params(b_loc=B_LOC) -> list[Param]:
    """θ: the physical parameters that enter the readings nonlinearly."""

    def p(name: str, **kw) -> Param:
        return Param(name, unit=unit_of(name), **kw)

    return [
        p("b1", loc=float(b_loc[0]), scale=0.5, typical=1e-3),
        p("b2", loc=float(b_loc[1]), scale=0.5, typical=1e-3),
        p("K", loc=math.log(K_DESIGN), scale=0.25, transform="log", typical=0.01),
        p("eps1_arcmin", scale=10.0, typical=0.1),
        p("eps2_arcmin", scale=10.0, typical=0.1),
        p("dgamma_arcmin", scale=10.0, typical=1.0),
        p("tau_s", loc=math.log(30.0), scale=1.0, transform="log", typical=0.1),
    ]


def hyper_params() -> list[Param]:
    """The hyperparameters as sampled parameters (log scale)."""
    return [
        Param("noise_scale", scale=0.5, transform="log", shape=(2,), typical=0.05),
        Param("sigma_theta_arcsec", loc=math.log(2.0), scale=0.5, transform="log", typical=0.2),
        Param("sigma_hold_pix", loc=math.log(0.05), scale=1.0, transform="log", typical=0.2),
        Param("slew_error", loc=math.log(0.003), scale=1.5, transform="log", typical=0.3),
    ]


def default_hyper(
    noise_scale=(1.0, 1.0), sigma_theta_arcsec=2.0, sigma_hold_pix=0.05, slew_error=0.003
) -> Hyper:
    """Hyperparameters as the model functions take them (the EM starts here)."""
    return {
        "noise_scale": device_array(noise_scale, dtype=np.float64),
        "sigma_theta_arcsec": device_array(sigma_theta_arcsec, dtype=np.float64),
        "sigma_hold_pix": device_array(sigma_hold_pix, dtype=np.float64),
        "slew_error": device_array(slew_error, dtype=np.float64),
    }


@dataclass(frozen=True, eq=False)
class CalibrationProblem:
    """The joint model of one structure as a MAP least-squares problem and as a marginal
    log-density. Built once per structure (:func:`chekan.runtime.engine.problem_for`)."""

    structure: ModelStructure
    theta_space: ParamSpace
    bayes_space: ParamSpace
    lsq: LeastSquaresProblem

    @property
    def map_space(self) -> ParamSpace:
        """The MAP's parameter space (θ; the hyperparameters are EM's)."""
        return self.theta_space

    def log_density(self, z, data: RecordData):
        """log p(θ, h | y) up to a constant, β marginalised (12-dim z); M factored by block
        elimination of the holds' (o₁, o₂, δ) (:attr:`ModelStructure.hold_bands`: the same
        value as the dense Cholesky to round-off, 2–3× cheaper on 160 holds), its blocks
        assembled directly (:func:`chekan.joint.hold_blocks.block_normal_equations`: M
        itself is never formed)."""
        v = self.bayes_space.to_values(z)
        st = self.structure
        blocks, _ = block_normal_equations(v, v, st, data)
        pv = beta_prior_var(v, st, data)
        ll = marginal_loglik_blocks(blocks, *split_prior(pv, st.hold_bands))
        lp = self.bayes_space.log_prior(z) + ll
        return jnp.where(jnp.isfinite(lp), lp, -jnp.inf)


def build_problem(structure: ModelStructure, store=None) -> CalibrationProblem:
    """Both views of the model for one structure (built once per structure by
    :func:`chekan.runtime.engine.engine_for`, whose ``store`` keeps the compiled solvers, so
    records of one shape share them: batch re-analysis, validation).

    MAP: LM over θ only; for each θ the linear block β is solved in closed form
    (:func:`chekan.joint.beta_posterior.solve_beta`, by the hold blocks), so the residual is
    the projected one and its Gauss–Newton covariance for θ equals the θ-block of the joint
    (θ, β) Laplace covariance. The residual function takes ``(values, (data, hyper))``.
    """
    theta = nonlinear_params()
    theta_space = ParamSpace(theta)
    bayes_space = ParamSpace(theta + hyper_params())

    def residuals(v, args):
        """Projected whitened bin residuals and β̂'s prior rows."""
        data, h = args
        sol = solve_beta(v, h, structure, data)
        return jnp.concatenate([sol.rw, sol.beta / jnp.sqrt(beta_prior_var(h, structure, data))])

    lsq = LeastSquaresProblem(theta_space, residuals, executables=store)
    return CalibrationProblem(structure, theta_space, bayes_space, lsq)
