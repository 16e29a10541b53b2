"""Model-agnostic Bayesian and least-squares estimation on JAX.

The contract: a model supplies

* a :class:`ParamSpace` — named parameters with Gaussian (or flat) priors on their
  unconstrained values and identity/log transforms; solvers and samplers only ever see the flat,
  O(1)-scaled working vector ``z``;
* a whitened residual function ``residuals(values, data) -> r`` (``r ~ N(0, I)`` at the truth)
  wrapped in a :class:`LeastSquaresProblem`, for MAP + Laplace (:func:`fit_map`,
  :func:`fit_map_batch`; Gauss–Newton can stop on its decrement in posterior sds,
  :class:`DecrementGaussNewton`);
* and/or a log-density ``log_density(z, data) -> scalar`` (prior + likelihood; linear-Gaussian
  parameters can be integrated out with :func:`marginal_loglik`) for :func:`sample`.

:mod:`inference` does the rest: solves (compiled by the compiler the caller hands it: this
package compiles nothing), Laplace covariances that flag unidentified directions instead of
crashing, emcee with several independent ensembles and an autocorrelation-based stopping rule,
R̂/ESS diagnostics, ArviZ/NetCDF output (ArviZ is touched only in :mod:`inference.arviz_io`)
and simulation-based-calibration helpers (:mod:`inference.sbc`). It knows nothing about any
particular instrument.

All arrays are float64 (``jax_enable_x64`` is switched on when this package is imported).
"""

from . import _jax  # noqa: F401  (first: float64 before any array exists)

# isort: split

import importlib
from typing import Any

# Names are imported on first use (PEP 562): a MAP does not pay for emcee, scipy.stats and
# ArviZ (≈ 1.5 s of imports in every new process), a sampler does not pay for optimistix.
_WHERE = {
    "DecrementGaussNewton": "gauss_newton",
    "LaplaceCovariance": "laplace",
    "laplace_covariance": "laplace",
    "LeastSquaresProblem": "problem",
    "MapBatchResult": "map_batch",
    "MapResult": "map",
    "fit_map": "map",
    "fit_map_batch": "map_batch",
    "Param": "params",
    "ParamSpace": "params",
    "SamplerConfig": "sampling",
    "SamplingResult": "sampling",
    "sample": "sampling",
    "conditional_beta": "linear",
    "draw_beta": "linear",
    "marginal_loglik": "linear",
    "convergence_report": "diagnostics",
    "ess_bulk": "diagnostics",
    "rhat": "diagnostics",
    "summarize_draws": "diagnostics",
    "load_netcdf": "arviz_io",
    "save_netcdf": "arviz_io",
    "to_inference_data": "arviz_io",
}
_MODULES = ("arviz_io", "diagnostics", "linear", "sbc")


def __getattr__(name: str) -> Any:
    if name in _MODULES:
        return importlib.import_module(f".{name}", __name__)
    if name in _WHERE:
        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "DecrementGaussNewton",
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
