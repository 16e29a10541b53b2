"""inference.map.jacobian_once: the solvers' linearisation with the Jacobian formed once.

Same derivatives as plain forward mode; only z is differentiable; and a solve through it
compiles ahead of time, is stored and loads again with the same numbers (a ``custom_jvp``
that closed over traced data lowered with hidden inputs and could not be called).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from chekan.runtime.compiler import Compiler
from chekan.runtime.store import ExecutableStore
from inference import LeastSquaresProblem, Param, ParamSpace, fit_map
from inference.map import _SUCCESS, jacobian_once

ROOT = Path(__file__).resolve().parents[1]
T = np.linspace(0.0, 6.0, 60)
CONST = np.linspace(0.5, 1.5, 60)  # an array the residuals close over (a model constant)


def _residuals(z, data):
    return (data["y"] - z[0] * jnp.exp(-T * CONST / z[1])) / data["sigma"]


def _data():
    rng = np.random.default_rng(3)
    y = 2.0 * np.exp(-T * CONST / 1.5) + 0.01 * rng.normal(size=T.size)
    return {"y": jnp.asarray(y), "sigma": jnp.asarray(0.01)}


def test_values_and_derivatives_equal_plain_forward_mode():
    f = jacobian_once(_residuals)
    z, data = jnp.array([1.7, 1.2]), _data()
    np.testing.assert_array_equal(f(z, data), _residuals(z, data))
    np.testing.assert_array_equal(jax.jacfwd(f)(z, data), jax.jacfwd(_residuals)(z, data))
    t = jnp.array([0.3, -0.7])
    _, tan = jax.jvp(lambda u: f(u, data), (z,), (t,))
    _, ref = jax.jvp(lambda u: _residuals(u, data), (z,), (t,))
    np.testing.assert_allclose(tan, ref, rtol=1e-13, atol=1e-12)
    zs = jnp.stack([z, z + 0.1])  # batched, as fit_map_batch runs it
    np.testing.assert_array_equal(
        jax.vmap(jax.jacfwd(f), (0, None))(zs, data),
        jax.vmap(jax.jacfwd(_residuals), (0, None))(zs, data),
    )


def test_a_derivative_in_the_data_is_refused():
    f = jacobian_once(_residuals)
    with pytest.raises(ValueError, match="with respect to z only"):
        jax.jacfwd(f, argnums=1)(jnp.array([1.7, 1.2]), _data())


def test_the_success_code_is_optimistix_own():
    import optimistix as optx

    assert int(optx.RESULTS.successful._value) == _SUCCESS  # type: ignore[attr-defined]


def test_a_solve_through_it_is_stored_and_loaded_with_the_same_numbers(tmp_path):
    space = ParamSpace([Param("amp", loc=2.0, scale=1.0), Param("tau", loc=1.0, scale=1.0)])

    def residuals(v, d):
        return _residuals(jnp.stack([v["amp"], v["tau"]]), d)

    def problem(store):
        return LeastSquaresProblem(space, residuals, Compiler() if store is None else store)

    data = _data()
    plain = fit_map(problem(None), data, solver="gn")  # equinox's jit, no store
    first = ExecutableStore(tmp_path, "jac-once-v1")
    compiled = fit_map(problem(first), data, solver="gn")
    again = ExecutableStore(tmp_path, "jac-once-v1")  # a new store: reads the file
    loaded = fit_map(problem(again), data, solver="gn")
    assert [e for _, e in first.events] == ["compiled"]
    assert [e for _, e in again.events] == ["loaded"]
    assert plain.converged and compiled.converged and loaded.converged
    np.testing.assert_array_equal(loaded.z, compiled.z)
    np.testing.assert_array_equal(loaded.cov_z, compiled.cov_z)
    np.testing.assert_allclose(compiled.z, plain.z, rtol=1e-12)
    assert loaded.values["tau"] == pytest.approx(1.5, abs=0.01)


# a process that runs only stored executables never imports optimistix (0.3 s with lineax)
# nor equinox (≈ 0.3 s more: jaxtyping, equinox.nn)
PROGRAM = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    import numpy as np
    import jax.numpy as jnp
    from inference import LeastSquaresProblem, Param, ParamSpace, fit_map
    from chekan.runtime.store import ExecutableStore

    T = np.linspace(0.0, 6.0, 60)
    space = ParamSpace([Param("amp", loc=2.0, scale=1.0), Param("tau", loc=1.0, scale=1.0)])
    y = 2.0 * np.exp(-T / 1.5)

    def residuals(v, d):
        return (d["y"] - v["amp"] * jnp.exp(-T / v["tau"])) / 0.01

    store = ExecutableStore(Path(sys.argv[1]), "optx-free-v1")
    res = fit_map(LeastSquaresProblem(space, residuals, store), {"y": y}, solver="gn")
    imported = ["optimistix" in sys.modules, "equinox" in sys.modules]
    print(store.events[-1][1], res.converged, *imported, repr(res.z[1]))
    """
)


def test_a_process_running_stored_solves_imports_neither_optimistix_nor_equinox(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}

    def run() -> list[str]:
        cmd = [sys.executable, "-c", PROGRAM, str(tmp_path)]
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return proc.stdout.split()

    first, second = run(), run()
    assert first[:4] == ["compiled", "True", "True", "True"]  # tracing the solve needs them
    assert second[:4] == ["loaded", "True", "False", "False"]
    assert first[4] == second[4]  # bit for bit
