"""What the joint estimators return: typed, frozen fits, formatted into the
``chekan-result/1`` dict by :mod:`chekan.results.joint` alone.

:class:`MapEstimate` (``--method map`` on a record), :class:`PosteriorEstimate` (``bayes``),
:class:`ProtocolEstimate` (either, on a legacy protocol); each with the classical items'
:class:`~chekan.classical.settling.Settling` where a record's lag is fitted.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from chekan.classical.settling import Settling
from chekan.fit.map import MapFit
from chekan.fit.reported import MapDerived

if TYPE_CHECKING:
    from inference.sampling import SamplingResult

#: The raw uncertainty budget of b₁, b₂: {name: {source: sd}} with ``total_linearised``
#: (:func:`chekan.fit.budget.uncertainty_budget`).
RawBudget = Mapping[str, Mapping[str, float]]
#: A posterior summary: {name: {mean, sd, hdi_low, hdi_high, r_hat, ess_bulk, …}}
#: (:func:`inference.diagnostics.summarize_draws`).
Summary = Mapping[str, Mapping[str, Any]]


@dataclass(frozen=True)
class MapEstimate:
    """The ``map`` fit of a record: the MAP, its derived quantities with delta-method sds,
    the raw uncertainty budget, the classical items' settling and the seconds taken."""

    fit: MapFit
    derived: MapDerived
    budget: RawBudget
    settling: Settling
    seconds: float


@dataclass(frozen=True)
class PosteriorEstimate:
    """The ``bayes`` fit of a record: the MAP it started from, the raw budget, the sampler's
    result (draws, statistics and the reported draws as ``sampling.derived``,
    :class:`~chekan.fit.reported.ReportedDraws`), their summary and convergence verdict
    (``draws_converged``, ``problems``), the posterior predictive replicates of the
    residual table δg (draws, R, 2, angles), the NetCDF written (or None), the settling, the
    seconds taken (up to the summary) and the drift curve."""

    fit: MapFit
    budget: RawBudget
    sampling: SamplingResult
    summary: Summary
    draws_converged: bool
    problems: tuple[str, ...]
    replicates: np.ndarray
    netcdf: Path | None
    settling: Settling
    seconds: float
    drift: Mapping[str, Any]
    """The drift curve of the draws, with its interval
    (:func:`~chekan.fit.predictive.drift_curve`)."""
