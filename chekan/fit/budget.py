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
