"""The fits of the joint model (:mod:`chekan.joint`): what ``--method map|bayes`` runs.

=================  ==========================================================
module             what it does
=================  ==========================================================
``record``         a record → its ``map`` or ``bayes`` fit (:func:`estimate`)
``protocol``       a legacy protocol → its joint fit (per-round characteristic)
``fitted``         the typed fits they return (:mod:`chekan.results.joint` writes them)
``start``          the MAP's start: classical θ; a τ read off the settling transients
``map``            MAP + EM of one record → :class:`MapFit`
``reported``       the MAP's derived quantities, run on a fit
``typea``          the MAP's Type A terms: uₕ and ν_eff from the estimated hyperparameters
``budget``         the uncertainty budget of b and U = k·u
``sampling``       emcee on the marginal posterior
``predictive``     posterior predictive, drift curve, NetCDF
=================  ==========================================================
"""

from chekan.fit.map import MapFit, fit_map_em
from chekan.fit.record import estimate
from chekan.fit.start import initial_values

__all__ = [
    "MapFit",
    "estimate",
    "fit_map_em",
    "initial_values",
]
