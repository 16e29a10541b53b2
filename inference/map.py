r"""Maximum a posteriori estimate by nonlinear least squares, with a Laplace covariance.

.. math::  \hat z = \arg\min_z \tfrac12\lVert R(z)\rVert^2,\qquad
           R(z) = [\,r(\theta(z)),\; r_\text{prior}(z)\,],\qquad
           \Sigma_z \approx (J^\top J)^{-1},\; J = \partial R/\partial z\,|_{\hat z}.

The solve (optimistix Levenberg–Marquardt or Gauss–Newton), the residuals and Jacobian at the
solution (from the solver's last accepted linearisation, materialised; kept in the result for
budgets by row) and its thin SVD run in one function, which the problem's compiler
(``problem.executables``, the caller's: this package compiles nothing) compiles and keeps:
repeated fits with the same data shapes do not retrace; with an executable store a new
process loads it instead of tracing and compiling.
:func:`fit_map_batch` vmaps the same function over a leading batch axis of the data (lanes run
in lock step: a batch costs its slowest member; failures are reported per lane, never raised).
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

import functools
import hashlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from .jacobian import jacobian_once
from .laplace import DEFAULT_RCOND, LaplaceCovariance, laplace_from_svd
from .params import ParamSpace
from .problem import LeastSquaresProblem, stacked_residuals_of

__all__ = [
    "MapResult",
    "fit_map",
    "jacobian_once",
    "trace_count",
]

SolverName = Literal["lm", "gn"]
# optimistix's code of a successful solve (``optx.RESULTS.successful``, its enumeration's first
# member; a test checks it). optimistix is imported where a solve is traced, not here: a new
# process that runs stored executables never needs it (≈ 0.3 s of imports with lineax).
_SUCCESS = 0


# --------------------------------------------------------------------------- results
def _value_cov(space: ParamSpace, z: np.ndarray, cov_z: np.ndarray, names) -> np.ndarray:
    """Delta method: Cov(v) = D Cov(z) D with D = diag(dv/dz)."""
    idx = space.flat_indices(names)
    d = np.asarray(space.value_derivative(z))[idx]
    with np.errstate(invalid="ignore"):
        return d[:, None] * cov_z[np.ix_(idx, idx)] * d[None, :]


def _value_sd(space: ParamSpace, z: np.ndarray, cov_z: np.ndarray) -> dict[str, np.ndarray]:
    sd_z = np.sqrt(np.clip(np.diag(cov_z), 0.0, None))
    sd_v = np.abs(np.asarray(space.value_derivative(z))) * sd_z
    return {p.name: sd_v[space.slices[p.name]].reshape(p.shape) for p in space.params}


@dataclass
class MapResult:
    """MAP estimate and its Laplace approximation.

    ``cost = ½‖R(ẑ)‖²``; ``cov_z`` is the Laplace covariance in z (±inf for coordinates in an
    unidentified direction, listed in ``degenerate``); ``jacobian_cond = s_max/s_min`` of J.
    """

    z: np.ndarray
    values: dict[str, np.ndarray]
    converged: bool
    num_steps: int
    result_code: int
    """optimistix's result code (0: success); :attr:`message` says it in words."""
    cost: float
    cov_z: np.ndarray
    jacobian_cond: float
    degenerate: list[str] = field(default_factory=list)
    degenerate_directions: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    space: ParamSpace | None = field(default=None, repr=False)
    jacobian: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    """J = ∂R/∂z at ẑ (rows as ``residuals``), for budgets by row (empty if not kept)."""

    @property
    def message(self) -> str:
        """ "success" or optimistix's explanation of :attr:`result_code` (read when asked:
        the text needs optimistix imported, ≈ 0.1 s a process that only loads executables)."""
        return _messages(self.result_code)[0]

    def sd(self) -> dict[str, np.ndarray]:
        """Laplace sd per parameter in VALUE space (delta method: ``sd_v = |dv/dz|·sd_z``)."""
        return _value_sd(self._space(), self.z, self.cov_z)

    def cov_values(self, names: str | Sequence[str]) -> np.ndarray:
        """Laplace covariance of the flat elements of ``names`` in value space (delta method)."""
        return _value_cov(self._space(), self.z, self.cov_z, names)

    def cov_u(self) -> np.ndarray:
        """Laplace covariance of the unconstrained values ``u = loc + typical·z``."""
        step = self._space().step
        with np.errstate(invalid="ignore"):
            return step[:, None] * self.cov_z * step[None, :]

    def _space(self) -> ParamSpace:
        if self.space is None:
            raise ValueError("this MapResult carries no ParamSpace (built by hand?)")
        return self.space

    def summary(self) -> str:
        """A short human-readable report."""
        status = "converged" if self.converged else f"NOT converged: {self.message}"
        lines = [
            f"MAP {status} in {self.num_steps} steps; cost={self.cost:.6g} "
            f"({self.residuals.size} residuals); cond(J)={self.jacobian_cond:.3g}"
        ]
        if self.degenerate:
            lines.append(f"  NOT IDENTIFIED (infinite sd): {', '.join(self.degenerate)}")
        sd = self._space().flatten(self.sd())
        for name, v in self._space().flatten(self.values).items():
            lines.append(f"  {name:>16s} = {float(v):.10g} ± {float(sd[name]):.3g}")
        return "\n".join(lines)


# --------------------------------------------------------------------------- compiled core
def trace_count(problem: LeastSquaresProblem) -> int:
    """How many times the problem's compiler has traced (for tests; 0 where it does not
    count)."""
    return int(getattr(problem.executables, "traces", 0))


def _check_solver(solver: SolverName) -> None:
    if solver not in ("lm", "gn"):
        raise ValueError(
            f"solver must be 'lm' (Levenberg–Marquardt) or 'gn' (Gauss–Newton): {solver!r}"
        )


def _check_sd_tol(solver: SolverName, sd_tol: float | None) -> None:
    if sd_tol is None:
        return
    if solver != "gn":
        raise ValueError("sd_tol (the decrement test) is for solver='gn' (Gauss–Newton) only")
    if not (0.0 < sd_tol < 1.0):
        raise ValueError(f"sd_tol is a fraction of a standard deviation in (0, 1): {sd_tol}")


def _make_solver(solver: SolverName, rtol: float, atol: float, sd_tol: float | None):
    import optimistix as optx  # the name was checked by ``_compiled``, before tracing

    if solver == "lm":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    if sd_tol is not None:
        from .gauss_newton import DecrementGaussNewton

        return DecrementGaussNewton(rtol, atol, sd_tol)
    return optx.GaussNewton(rtol=rtol, atol=atol)


def _core(
    problem: LeastSquaresProblem,
    solver: SolverName,
    rtol: float,
    atol: float,
    max_steps: int,
    sd_tol: float | None = None,
) -> Callable:
    """``(z0, data) -> (z, result, num_steps, residuals, s, vt, J)`` for one problem (not
    jitted). The optimistix solver is built when ``run`` is traced (a stored executable
    needs neither it nor the import).

    With ``sd_tol`` (Gauss–Newton's decrement test, :mod:`inference.gauss_newton`) a
    successful solve returns its last linearisation point plus the step δ computed there
    (shorter than ``sd_tol`` sds when that test stopped it; smaller still after a step
    that passed the Cauchy test), and the residuals there to first order, r + Jδ. J is
    the linearisation's, δ away: the covariance changes by far less than sd_tol."""
    p = problem.space.size
    # ``run`` holds the problem's parts, never the problem: JAX keeps what it traced (a
    # static ``run``, the residual function) in process-wide caches, and the problem would
    # keep its store and every executable in it alive there
    space, residuals = problem.space, problem.residuals

    def run(z0, data):
        import optimistix as optx

        solver_ = _make_solver(solver, rtol, atol, sd_tol)
        fn: Callable[..., Any] = functools.partial(stacked_residuals_of, space, residuals)
        if solver == "gn":
            # LM keeps its linearisation as before: the regression snapshot was taken with
            # it, and J formed once moves a near-zero drift slope there by 1.8e-6 relative
            # (1e-7 sd), past the snapshot's 1e-6; GN's answers equal 0.3.4's to 1e-11 sd
            fn = jacobian_once(fn)
        sol: Any = optx.least_squares(fn, solver_, z0, data, max_steps=max_steps, throw=False)
        z = sol.value
        # R and J at ẑ from the solver's last accepted step (its linearisation there, J
        # already a matrix: see ``jacobian_once``)
        info = sol.state.f_info
        r = info.residual
        jac = info.jac.as_matrix()
        if sd_tol is not None:  # take the step computed at the last linearisation
            ok = sol.result == optx.RESULTS.successful
            step = jnp.where(ok, sol.state.y_eval - z, 0.0)
            z = z + step
            r = r + jac @ step
        padded = jac
        if jac.shape[0] < p:  # under-determined: pad so the thin SVD has p values
            padded = jnp.concatenate([jac, jnp.zeros((p - jac.shape[0], p))])
        _, s, vt = jnp.linalg.svd(padded, full_matrices=False)
        # the result's integer code, not optimistix's RESULTS object: a plain array output
        # (stored executables keep only arrays and built-in containers)
        return z, sol.result._value, sol.stats["num_steps"], r, s, vt, jac

    return run


def _compiled(
    problem, solver, rtol, atol, max_steps, batched: bool, data_axes=0, sd_tol=None
) -> Callable:
    """The solve compiled by the problem's compiler (``problem.executables``: this package
    compiles nothing itself), under a name that says what it computes."""
    if not isinstance(problem, LeastSquaresProblem):
        raise TypeError(f"problem must be a LeastSquaresProblem, got {type(problem).__name__}")
    _check_solver(solver)  # an unknown name fails here, before any tracing
    _check_sd_tol(solver, sd_tol)
    sd_key = None if sd_tol is None else float(sd_tol)
    run = _core(problem, solver, rtol, atol, int(max_steps), sd_key)
    if batched:
        run = jax.vmap(run, in_axes=(0, data_axes))
    name = f"map_{solver}_{rtol:g}_{atol:g}_{max_steps}_{'batch' if batched else 'one'}"
    if sd_key is not None:
        name += f"_sd{sd_key:g}"
    if batched and _axes_key(data_axes) != _axes_key(0):  # other axes: another function
        name += f"_axes{hashlib.sha256(repr(_axes_key(data_axes)).encode()).hexdigest()[:12]}"
    return problem.executables.jit(name, run)


def _axes_key(axes) -> Any:
    leaves, treedef = jax.tree_util.tree_flatten(axes, is_leaf=lambda x: x is None)
    return (tuple(leaves), treedef)


def _z0(space: ParamSpace, z0, batch: int | None = None) -> np.ndarray:
    if z0 is None:
        z = np.zeros(space.size if batch is None else (batch, space.size))
    elif isinstance(z0, Mapping):
        if batch is not None:
            raise TypeError("z0_batch must be an array (B, p); convert values with space.to_z")
        z = np.asarray(space.to_z(z0))
    else:
        z = np.asarray(z0, dtype=float)
    want = (space.size,) if batch is None else (batch, space.size)
    if z.shape != want:
        raise ValueError(f"initial working vector has shape {z.shape}, expected {want}")
    if not np.all(np.isfinite(z)):
        raise ValueError("initial working vector has non-finite entries")
    # on the host: the compiled solve takes it as it is (jnp.asarray would compile a
    # conversion per new process; jax.device_put costs 0.1 ms a call, the executable's own
    # transfer a few µs)
    return z


def _messages(result) -> list[str]:
    """One message per lane ("success" or optimistix's explanation).

    ``optx.RESULTS[batched_result]`` returns the ``str`` of an array, so the integer codes are
    mapped through the enumeration's message table (equinox internals, with a fallback).
    """
    codes = np.atleast_1d(np.asarray(result)).reshape(-1)
    if (codes == _SUCCESS).all():
        return ["success"] * codes.size
    import optimistix as optx

    table = getattr(optx.RESULTS, "_index_to_message", None)
    out = []
    for c in codes.tolist():
        msg = table[c] if table is not None and 0 <= c < len(table) else f"optimistix code {c}"
        out.append(msg or "success")
    return out


def _host_values(space: ParamSpace, z: np.ndarray) -> dict[str, np.ndarray]:
    """Named values of ``z`` on the host. A pass that diverged (a start in the prior's far
    tails) can end where a log-parameter is beyond exp's range: its value is ``inf``, quietly
    (the caller judges the pass by ``converged`` and the prior's bulk, not by a warning)."""
    with np.errstate(over="ignore"):
        return {k: np.asarray(v) for k, v in space.to_values(z).items()}


def _laplace(s: np.ndarray, vt: np.ndarray, r: np.ndarray, rcond: float) -> LaplaceCovariance:
    """Laplace covariance, NaN when the residuals at the solution are not finite."""
    if not np.all(np.isfinite(r)):
        s = np.full_like(s, np.nan)
    return laplace_from_svd(s, vt, rcond=rcond)


def _laplace_names(space: ParamSpace, lap: LaplaceCovariance) -> list[str]:
    names = space.flat_names()
    return [names[i] for i in np.flatnonzero(lap.degenerate_mask)]


# --------------------------------------------------------------------------- public API
def fit_map(
    problem: LeastSquaresProblem,
    data: Any,
    z0: ArrayLike | Mapping[str, ArrayLike] | None = None,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    max_steps: int = 256,
    solver: SolverName = "lm",
    rcond: float = DEFAULT_RCOND,
    sd_tol: float | None = None,
) -> MapResult:
    """MAP estimate of ``problem`` given ``data`` (any pytree ``residuals`` accepts).

    ``z0``: initial working vector (default: the prior loc, z = 0) or a dict of named values.
    Compiled by the problem's compiler (``problem.executables``), once per solver settings
    and data shapes; a plain compiler (``equinox.filter_jit``) makes Python scalars inside
    ``data`` static (a new value recompiles): pass arrays.
    Never raises on solver failure: check ``converged``/``message``. Near-singular directions
    (s < rcond·s_max) get infinite sd and their coordinates are listed in ``degenerate``.

    ``sd_tol`` (Gauss–Newton only): also stop when the next step is shorter than this many
    posterior sds, and take that step (:mod:`inference.gauss_newton`); None: optimistix's
    Cauchy test on ``rtol``/``atol`` alone.
    """
    space = problem.space
    run = _compiled(problem, solver, rtol, atol, max_steps, batched=False, sd_tol=sd_tol)
    # every output to the host in one transfer (on the host: comparisons compile nothing)
    z, result, steps, r, s, vt, jac = jax.device_get(run(_z0(space, z0), data))
    lap = _laplace(s, vt, r, rcond)
    return MapResult(
        z=z,
        values=_host_values(space, z),
        converged=bool(result == _SUCCESS),
        num_steps=int(steps),
        result_code=int(result),
        cost=float(0.5 * np.sum(r**2)),
        cov_z=lap.cov,
        jacobian_cond=float(lap.cond),
        degenerate=_laplace_names(space, lap),
        degenerate_directions=lap.degenerate_directions,
        residuals=r,
        space=space,
        jacobian=jac,
    )
