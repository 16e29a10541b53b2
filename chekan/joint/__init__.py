"""The joint model of a record: both quartz systems, all rounds, one likelihood (pure maths;
what is compiled lives in :mod:`chekan.runtime`, what runs it on a record in :mod:`chekan.fit`).

==================  ==========================================================
module              what it states
==================  ==========================================================
``layout``          the static structure (what compiles) and the data pytree
``binning``         record → holds → bin means and slews (the data)
``slews``           the slews' measured paths and their types
``angles``          the angle sensors' errors: one basis per sensor
``xresponse``       the X rounds' response beyond eq. (6), the pendulums' horizontal
``likelihood``      the pieces of f(θ) + A(θ)β: sensor, lag, slews, noise, β's prior
``hold_blocks``     the bins' terms at θ and the normal equations by hold (the only assembly)
``beta_posterior``  β | θ, h from the hold blocks: β̂ and its θ-derivative, M⁻¹, E-step
``problem``         parameters and priors; MAP least squares; marginal density
``em``              between MAP passes: level re-centring, EM of hyperparameters
``em_theta``        the E-step's moments and what θ's uncertainty adds to them
``derived``         a, b₀, drift slope: one function for map, bayes and design
==================  ==========================================================
"""

from chekan.joint.binning import BIN_EDGES_S, prepare, prepare_record
from chekan.joint.layout import ModelStructure, RecordData, RecordModel
from chekan.joint.problem import CalibrationProblem, default_hyper
from chekan.runtime.engine import clear_caches, engine_for, problem_for
from chekan.runtime.padding import padded_shape

__all__ = [
    "BIN_EDGES_S",
    "CalibrationProblem",
    "ModelStructure",
    "RecordData",
    "RecordModel",
    "clear_caches",
    "default_hyper",
    "engine_for",
    "padded_shape",
    "prepare",
    "prepare_record",
    "problem_for",
]
