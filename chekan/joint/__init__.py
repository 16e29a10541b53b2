"""The joint calibration of a record: both quartz systems, all rounds, one likelihood.

==================  ============================================================
module              what it does
==================  ============================================================
``layout``          the static structure (what compiles) and the data pytree
``binning``         record → holds → bin means and slews (the data)
``likelihood``      the pieces of f(θ) + A(θ)β: sensor, lag, slews, noise, β's prior
``hold_blocks``     the bins' terms at θ and the normal equations by hold (the only assembly)
``beta_posterior``  β | θ, h from the hold blocks: β̂ and its θ-derivative, M⁻¹, E-step
``problem``         parameters and priors; MAP least squares; marginal density
``em``              between MAP passes: level re-centring, EM of hyperparameters
``em_theta``        the E-step's moments and what θ's uncertainty adds to them
``start``           the MAP's start: classical θ; a τ read off the settling transients
``map``             MAP + EM of one record → :class:`MapFit`
``derived``         a, b₀, drift slope: one function for map, bayes and design
``typea``           the MAP's Type A terms: uₕ and ν_eff from the estimated hyperparameters
``budget``          the uncertainty budget of b and U = k·u
``sampling``        emcee on the marginal posterior
``predictive``      posterior predictive, drift curve, NetCDF
``estimate``        the ``map`` and ``bayes`` results
``legacy``          the joint model of a legacy protocol (per-round characteristic)
==================  ============================================================

What is compiled for a structure, kept, loaded and cleared lives in :mod:`chekan.runtime`
(``engine_for``, ``problem_for`` and ``clear_caches`` are re-exported here).
"""

from chekan.joint.binning import BIN_EDGES_S, prepare, prepare_record
from chekan.joint.estimate import estimate, map_result, posterior_result
from chekan.joint.layout import ModelStructure, RecordData, RecordModel
from chekan.joint.map import MapFit, fit_map_em
from chekan.joint.problem import CalibrationProblem, default_hyper
from chekan.joint.start import initial_values
from chekan.runtime.engine import clear_caches, engine_for, problem_for
from chekan.runtime.padding import padded_shape
from chekan.settling import tau_from_transients

__all__ = [
    "BIN_EDGES_S",
    "CalibrationProblem",
    "MapFit",
    "ModelStructure",
    "RecordData",
    "RecordModel",
    "clear_caches",
    "default_hyper",
    "engine_for",
    "estimate",
    "fit_map_em",
    "initial_values",
    "map_result",
    "padded_shape",
    "posterior_result",
    "prepare",
    "prepare_record",
    "problem_for",
    "tau_from_transients",
]
