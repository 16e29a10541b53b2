"""Benchmark of the estimators on a full 9-hour record (prints figures; asserts nothing).

    python bench/calibration_bench.py [--seed 0] [--skip-bayes]

Figures: classical fit; MAP (optimistix LM, variable projection, EM hyperparameters)
first call (with compilation) and warm; one LM pass against scipy.optimize.least_squares
on the same residual function and Jacobian; the posterior (emcee, 4 ensembles) to bulk
ESS ≥ 400 for every reported parameter. Run it twice to see the persistent JAX cache.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip-bayes", action="store_true")
    args = ap.parse_args(argv)

    import jax
    import jax.numpy as jnp
    import numpy as np
    from scipy.optimize import least_squares

    from chekan import bayes
    from chekan.classical import calibrate_record
    from chekan.pipeline import CalibrationOptions
    from chekan.records import write_record
    from chekan.simulate import simulate_session
    from inference.map import fit_map

    rows: list[tuple[str, str, str]] = []
    t = time.perf_counter()
    rec, _ = simulate_session(seed=args.seed)
    rows.append(("simulate 9 h record", f"{time.perf_counter() - t:.2f} s", f"{rec.n} samples"))

    t = time.perf_counter()
    for _ in range(10):
        cres, _ = calibrate_record(rec)
    rows.append(("classical (numpy)", f"{(time.perf_counter() - t) / 10 * 1000:.1f} ms", "per fit"))

    opts = CalibrationOptions(method="map")
    _, model, prob = bayes._setup(rec, cres, opts)
    init = bayes._initial_values(cres, rec.g_local_mgal)
    t = time.perf_counter()
    _, h, hist = bayes.fit_map_em(prob, init)
    rows.append(("MAP first call", f"{time.perf_counter() - t:.2f} s", "incl. compilation"))
    t = time.perf_counter()
    _, h, hist = bayes.fit_map_em(prob, init)
    rows.append(
        (
            f"MAP warm ({len(hist)} EM passes)",
            f"{time.perf_counter() - t:.2f} s",
            f"{sum(p['steps'] for p in hist)} LM steps",
        )
    )

    data = {**model.data, "hyper": h}
    z0 = prob.map_space.to_z(init)
    t = time.perf_counter()
    one = fit_map(prob.lsq, data, z0)
    rows.append(
        ("optimistix LM, one pass", f"{time.perf_counter() - t:.2f} s", f"{one.num_steps} steps")
    )

    fun = jax.jit(lambda z: prob.lsq.stacked_residuals(z, data))
    jac = jax.jit(jax.jacfwd(lambda z: prob.lsq.stacked_residuals(z, data)))
    fun(z0).block_until_ready()
    jac(z0).block_until_ready()
    t = time.perf_counter()
    sp = least_squares(
        lambda z: np.asarray(fun(jnp.asarray(z))),
        np.asarray(z0),
        jac=lambda z: np.asarray(jac(jnp.asarray(z))),
        method="lm",
        xtol=1e-12,
        ftol=1e-12,
    )
    rows.append(
        (
            "scipy least_squares (lm), one pass",
            f"{time.perf_counter() - t:.2f} s",
            f"{sp.nfev} evaluations, same jitted residual/Jacobian",
        )
    )
    rows.append(
        ("  |z_scipy − z_optx|", f"{np.max(np.abs(sp.x - np.asarray(one.z))):.2e}", "working units")
    )

    if not args.skip_bayes:
        from chekan.pipeline import calibrate_file

        path = Path(os.environ.get("TMPDIR", "/tmp")) / f"chekan_bench_{args.seed}.csv"
        write_record(path, rec)
        t = time.perf_counter()
        r = calibrate_file(path, CalibrationOptions(method="bayes", quick=True, progress=False))
        d = r["diagnostics"]
        rows.append(
            (
                "posterior (MAP + emcee + derived)",
                f"{time.perf_counter() - t:.1f} s",
                f"ESS_bulk min {d['ess_bulk_min']:.0f}, R-hat max {d['r_hat_max']:.3f}, "
                f"{d['n_steps']} steps × {d['n_walkers']} walkers × {d['n_chains']} chains",
            )
        )
        path.unlink(missing_ok=True)

    w = max(len(r[0]) for r in rows)
    print(f"{'task':<{w}}  {'time':>10}  notes")
    for name, val, note in rows:
        print(f"{name:<{w}}  {val:>10}  {note}")
    print(f"JAX {jax.__version__} on {jax.devices()[0].platform}, {os.cpu_count()} CPU(s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
