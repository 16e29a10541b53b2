"""The reported quantities of a fit, evaluated by the engine's compiled functions
(:mod:`chekan.runtime.engine`; their maths: :mod:`chekan.joint.derived`): at the MAP with
delta-method sds and the hyperparameters' Type A (:mod:`chekan.fit.typea`), and for every
posterior draw, with β drawn given θ."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from chekan.fit.map import MapFit
from chekan.fit.typea import reliabilities
from chekan.jaxconfig import device_array
from chekan.physics.parameters import PHYSICAL
from chekan.runtime.engine import engine_for
from inference.chunks import map_chunks


@dataclass(frozen=True)
class MapDerived:
    """The reported quantities at the MAP (:func:`map_derived`): ``values`` {name: (value,
    sd)} of the physical quantities (``PHYSICAL``), ``hyper`` {name: value} the
    hyperparameters at their EM values (no sd); ``nu_eff`` and ``u_hyper`` each physical
    quantity's effective degrees of freedom and uₕ (:mod:`chekan.fit.typea`);
    ``m_level_pix`` (2,) the estimated level readings;
    ``type_a_clipped``: the information on the noise variances was not positive definite
    (:func:`inference.dof.log_var_cov` took its positive part)."""

    values: Mapping[str, tuple[float, float]]
    hyper: Mapping[str, float]
    nu_eff: Mapping[str, float]
    u_hyper: Mapping[str, float]
    m_level_pix: np.ndarray
    type_a_clipped: bool


@dataclass(frozen=True)
class ReportedDraws(Mapping[str, np.ndarray]):
    """Every reported quantity of posterior draws (a mapping {name: (chain, draw, ...)}, what
    the sampler's stopping rule checks and the posterior reports) and, apart, the pointwise
    log-likelihood of each bin mean given each draw (``loglik``: (chain, draw, bins, 2))."""

    quantities: Mapping[str, np.ndarray]
    loglik: np.ndarray
    log_density: np.ndarray | None = None
    """log p(θ, h | y) of each draw (chain, draw), from the evaluation that drew β."""

    def __getitem__(self, name: str) -> np.ndarray:
        return self.quantities[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.quantities)

    def __len__(self) -> int:
        return len(self.quantities)

    def take(self, index: np.ndarray) -> ReportedDraws:
        """The draws of one chain (1, n, ...) at ``index`` (chain, draw): the resampled
        draws of the importance path (:mod:`inference.importance_path`)."""
        lp = None if self.log_density is None else np.asarray(self.log_density)[0][index]
        return ReportedDraws(
            {k: np.asarray(v)[0][index] for k, v in self.quantities.items()},
            np.asarray(self.loglik)[0][index],
            lp,
        )

    @staticmethod
    def joined(parts: Sequence[ReportedDraws]) -> ReportedDraws:
        """The draws of ``parts`` (each (1, n, ...)) one after the other, as one chain."""
        names = parts[0].quantities
        lps = [p.log_density for p in parts if p.log_density is not None]
        return ReportedDraws(
            {k: np.concatenate([p.quantities[k] for p in parts], axis=1) for k in names},
            np.concatenate([p.loglik for p in parts], axis=1),
            np.concatenate(lps, axis=1) if len(lps) == len(parts) else None,
        )


#: the key under which :func:`chekan.joint.derived.draws_fn` returns the pointwise
#: log-likelihood beside the reported quantities (split off by :func:`posterior_draws`)
LOGLIK_KEY = "_loglik"
#: and the log-density of each draw's point (:attr:`ReportedDraws.log_density`)
LOGP_KEY = "_logp"


def map_derived(fit: MapFit) -> MapDerived:
    """Derived quantities at the MAP with delta-method sds (:class:`MapDerived`).

    With θ ~ N(θ̂, C) and β | θ ~ N(β̂(θ), M⁻¹):
    var g = (∂g/∂θ + ∂g/∂β ∂β̂/∂θ) C (…)ᵀ + ∂g/∂β M⁻¹ (∂g/∂β)ᵀ + uₕ²,
    uₕ² the variance from the hyperparameters' estimation (:mod:`chekan.fit.typea`).
    Hyperparameters are reported at their EM values (sd None).
    """
    model, res, h = fit.model, fit.result, fit.hyper
    data = model.data
    blocks = model.structure.beta_blocks
    jitted = engine_for(model.structure).map_derived
    out_j = jitted(device_array(res.z), h, data, model.duration_h)
    val, Jz, Jb, Minv, beta, A_w, base, trans, pv = (np.asarray(x) for x in out_j)
    cov = np.asarray(res.cov_z)
    finite = np.isfinite(np.diag(cov))
    cz = np.where(np.isfinite(cov), cov, 0.0)
    var = np.einsum("ij,jk,ik->i", Jz, cz, Jz) + np.einsum("ij,jk,ik->i", Jb, Minv, Jb)
    rel = reliabilities(fit, Jz, Jb, Minv, A_w, base, trans, pv)
    u_hyper = np.array([r.u2_components for r in rel])
    sd = np.sqrt(np.maximum(var + u_hyper, 0.0))
    if not finite.all():
        sd = np.where(np.abs(Jz[:, ~finite]).sum(axis=1) > 0, np.inf, sd)
    s = np.asarray(h["noise_scale"]) * np.asarray(data.sigma_base)
    hyper = {
        "sigma1_pix": float(s[0]),
        "sigma2_pix": float(s[1]),
        "sigma_theta_arcsec": float(h["sigma_theta_arcsec"]),
        "sigma_hold_pix": float(h["sigma_hold_pix"]),
        "slew_error": float(h["slew_error"]),
    }
    return MapDerived(
        values={n: (float(val[i]), float(sd[i])) for i, n in enumerate(PHYSICAL)},
        hyper=hyper,
        nu_eff={n: rel[i].nu_eff for i, n in enumerate(PHYSICAL)},
        u_hyper={n: float(np.sqrt(max(u_hyper[i], 0.0))) for i, n in enumerate(PHYSICAL)},
        m_level_pix=np.asarray(data.m_ref) + np.asarray(beta)[blocks["c"]],
        type_a_clipped=any(r.clipped for r in rel),
    )


def posterior_draws(fit: MapFit, zs: np.ndarray, keys, chunk: int = 64) -> ReportedDraws:
    """Every reported quantity for each posterior draw ``zs`` (n, 12), β drawn given θ
    with ``keys``, and the pointwise log-likelihood; in fixed-size chunks on both cores
    (one compile, bounded memory; the size: ``docs/tuning.md``)."""
    model = fit.model
    fn = engine_for(model.structure).draws
    dur_h = model.duration_h  # traced, as in map_derived
    flat = map_chunks(lambda z, k: fn(z, k, model.data, dur_h), [zs, keys], chunk)
    quantities = {k: np.asarray(v) for k, v in flat.items() if k not in (LOGLIK_KEY, LOGP_KEY)}
    return ReportedDraws(quantities, np.asarray(flat[LOGLIK_KEY]), np.asarray(flat[LOGP_KEY]))
