"""The uncertainty budget of b: var(b̂) split by the source of each whitened row of the
MAP Jacobian, var b̂ = Σ_rows hᵣ², h = e_bᵀ(JᵀJ)⁻¹Jᵀ.

Groups: noise (data rows), level offset, drift, X response (the X rounds' terms beyond
eq. 6), hold offsets, angle readout (the random error of every hold, δ, and the legacy
encoder terms), **angle systematic** (the sensor's error per commanded angle and its
scale error, repeated in every round: GUM Type B, from the platform's specification; one
line per angle sensor, ``angle_systematic_y`` and ``angle_systematic_x``, where the
record tilts about both axes, and ``angle_systematic_xy`` for the scale error the two may
share), a (the prior of K), other priors; scaled to the reported sd.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from chekan.errors import ChekanError
from chekan.fit.map import MapFit
from chekan.joint.problem import nonlinear_params
from chekan.runtime.engine import problem_for

#: Prior sds of the angles that a record may not inform (their prior's scale, one source:
#: :func:`chekan.joint.problem.nonlinear_params`).
PRIOR_SD = {
    p.name: p.scale
    for p in nonlinear_params()
    if p.name in ("eps1_arcmin", "eps2_arcmin", "dgamma_arcmin")
}


def uncertainty_budget(fit: MapFit) -> dict:
    """Linearised sd of b₁, b₂ per source group, and ``total_linearised``."""
    model, res = fit.model, fit.result
    structure = model.structure
    space = problem_for(structure).map_space
    J = np.asarray(res.jacobian)  # the solve's Jacobian at θ̂ (same model, hyper and level)
    if J.shape != (res.residuals.size, space.size):
        raise ValueError(
            f"the MAP result carries no Jacobian of shape {(res.residuals.size, space.size)} "
            f"(got {J.shape}): build fits with chekan.joint.fit_map_em"
        )
    n_data = int(np.asarray(model.data.mask).size)
    nb = structure.n_beta
    blocks = structure.beta_blocks
    groups = {"noise": np.arange(n_data)}
    off = n_data
    n_c, n_x = model.n_systematic_common, model.n_systematic_x
    sys_c = blocks["angle_systematic"][:n_c]
    sys_x = blocks["angle_systematic"][n_c : n_c + n_x]
    sys_y = blocks["angle_systematic"][n_c + n_x :]
    two = n_x > 0 and model.angle_spec is not None
    for name, idx_beta in (
        ("level_offset", blocks["c"]),
        ("drift", blocks["drift"]),
        ("x_response", blocks["x_response"]),
        ("hold_offsets", blocks["hold_offset"]),
        ("angle_readout", blocks["angle_error"]),
        ("angle_readout", blocks["encoder"]),
        ("angle_systematic_y" if two else "angle_systematic", sys_y),
        ("angle_systematic_x" if two else "angle_systematic", sys_x),
        ("angle_systematic_xy", sys_c),
    ):
        groups.setdefault(name, np.zeros(0, int))
        groups[name] = np.concatenate([groups[name], off + idx_beta])
    off += nb
    idx = off
    for p in (p for p in space.params if p.has_prior):
        key = "a" if p.name == "K" else "other_priors"
        groups.setdefault(key, np.zeros(0, int))
        groups[key] = np.concatenate([groups[key], np.arange(idx, idx + p.size)])
        idx += p.size
    H = _influence(J)  # (nz, rows)
    step = space.step
    out = {}
    for name in ("b1", "b2"):
        i = space.flat_indices([name])[0]
        h = H[i] * step[i]
        total = float(np.sum(h**2))
        out[name] = {
            g: float(np.sqrt(np.sum(h[rows] ** 2))) for g, rows in groups.items() if rows.size
        }
        out[name]["total_linearised"] = float(np.sqrt(total))
    return out


def _influence(J: np.ndarray) -> np.ndarray:
    """(JᵀJ)⁺Jᵀ: by the SVD of J (pinv), or where LAPACK's SVD does not converge (a
    Jacobian with rows of very different scale) by the eigendecomposition of JᵀJ."""
    try:
        return np.linalg.pinv(J.T @ J) @ J.T
    except np.linalg.LinAlgError:
        pass
    try:
        w, V = np.linalg.eigh(J.T @ J)
    except np.linalg.LinAlgError as e:
        raise ChekanError(
            f"the uncertainty budget cannot be computed: the MAP's Jacobian is singular ({e})"
        ) from None
    keep = w > w.max() * J.shape[1] * np.finfo(float).eps
    return (V[:, keep] / w[keep]) @ V[:, keep].T @ J.T


def budget_entries(
    budget_raw: Mapping[str, Mapping[str, float]],
    params: Mapping[str, Mapping[str, Any]],
    nu_eff: Mapping[str, float] | None = None,
) -> dict:
    """The result's ``uncertainty_budget``: each group scaled so that they add up (in
    quadrature) to the reported sd; the total u, the effective degrees of freedom
    ``nu_eff`` (None: not evaluated, k = 2), the coverage factor k = t₉₅.₄₅(ν_eff)
    (GUM G.6.4; :func:`inference.dof.coverage_factor`) and U = k·u (``expanded``).

    ``budget_raw`` may hold a line ``hyperparameters`` (uₕ, :mod:`chekan.fit.typea`), which
    is not in the linearised total (it is added to it here)."""
    from inference.dof import coverage_factor

    out = {}
    for name in ("b1", "b2"):
        raw = dict(budget_raw[name])
        lin = raw.pop("total_linearised")
        if "hyperparameters" in raw:
            lin = float(np.hypot(lin, raw["hyperparameters"]))
        sd = params[name]["sd"]
        scale = sd / lin if lin > 0 and sd else 1.0
        e: dict[str, float | None] = {k: v * scale for k, v in raw.items()}
        e["total"] = sd
        nu = (nu_eff or {}).get(name)
        k = coverage_factor(nu) if nu is not None else 2.0
        e["nu_eff"] = float(nu) if nu is not None else None
        finite = bool(np.isfinite(k))  # ν_eff < 1: no finite k, no U (a flagged problem)
        e["coverage_factor"] = k if finite else None
        e["expanded"] = k * sd if sd is not None and finite else None
        out[name] = e
    return out


def flag_prior_dominated(params: dict, diag: dict) -> dict:
    """``diag`` with ``prior_dominated`` (and notes): a posterior sd above half the prior
    sd means this program cannot separate the parameter."""
    dominated = [
        n for n, psd in PRIOR_SD.items() if n in params and (params[n]["sd"] or 0) > 0.5 * psd
    ]
    notes = list(diag.get("notes", []))
    for n in dominated:
        notes.append(
            f"{n} is prior-dominated (sd {params[n]['sd']:.3g} vs prior sd {PRIOR_SD[n]:g}): "
            "this program cannot separate it"
        )
    out = {**diag, "prior_dominated": dominated}
    if notes:
        out["notes"] = notes
    return out
