"""Model-agnostic Bayesian and least-squares estimation on JAX.

The contract: a model supplies

* a :class:`ParamSpace` — named parameters with Gaussian (or flat) priors on their
  unconstrained values and identity/log transforms; solvers and samplers only ever see the flat,
  O(1)-scaled working vector ``z``;
* a whitened residual function ``residuals(values, data) -> r`` (``r ~ N(0, I)`` at the truth)
  wrapped in a :class:`LeastSquaresProblem`, for MAP + Laplace (:func:`fit_map`,
  :func:`fit_map_batch`);
* and/or a log-density ``log_density(z, data) -> scalar`` (prior + likelihood; linear-Gaussian
  parameters can be integrated out with :func:`marginal_loglik`) for :func:`sample`.

:mod:`inference` does the rest: compiled and cached solves, Laplace covariances that flag
unidentified directions instead of crashing, emcee with several independent ensembles and an
autocorrelation-based stopping rule, R̂/ESS diagnostics, ArviZ/NetCDF output (ArviZ is touched
only in :mod:`inference.arviz_io`) and simulation-based-calibration helpers
(:mod:`inference.sbc`). It knows nothing about any particular instrument.

All arrays are float64 (``jax_enable_x64`` is switched on when this package is imported).
"""

from . import _jax  # noqa: F401  (first: float64 before any array exists)

# isort: split

from . import arviz_io, diagnostics, linear, sbc
from .arviz_io import load_netcdf, save_netcdf, to_inference_data
from .diagnostics import convergence_report, ess_bulk, rhat, summarize_draws
from .laplace import LaplaceCovariance, laplace_covariance
from .linear import conditional_beta, draw_beta, marginal_loglik
from .map import MapBatchResult, MapResult, fit_map, fit_map_batch
from .params import Param, ParamSpace
from .problem import LeastSquaresProblem
from .sampling import SamplerConfig, SamplingResult, sample

__all__ = [
    "LaplaceCovariance",
    "LeastSquaresProblem",
    "MapBatchResult",
    "MapResult",
    "Param",
    "ParamSpace",
    "SamplerConfig",
    "SamplingResult",
    "arviz_io",
    "conditional_beta",
    "convergence_report",
    "diagnostics",
    "draw_beta",
    "ess_bulk",
    "fit_map",
    "fit_map_batch",
    "laplace_covariance",
    "linear",
    "load_netcdf",
    "marginal_loglik",
    "rhat",
    "sample",
    "save_netcdf",
    "sbc",
    "summarize_draws",
    "to_inference_data",
]
