"""Settings of :func:`inference.sampling.sample`: ensembles, walkers, moves, the stopping
rule and the proposal of the independence moves."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

__all__ = ["SamplerConfig"]


@dataclass
class SamplerConfig:
    """Settings of :func:`sample`.

    ``n_walkers``: per ensemble (default ``max(2·ndim+2, 16)`` rounded up to even; must be even
    and ≥ 2·ndim). ``n_chains``: independent ensembles (≥ 2 for R̂; 4 recommended).
    ``moves``: ``"de"`` (emcee's DEMove, the default), ``"de-snooker"`` (DEMove 0.8 +
    :class:`SnookerMove` 0.2, for curved or multimodal targets), ``"stretch"`` (emcee's
    default) or ``"de-independence"``: :class:`IndependenceMove` 0.7 (a t proposal with
    ``proposal_df`` degrees of freedom centred on the mode, covariance the Laplace one
    (:func:`inference.mode.refine_mode`, from ``z_init``/``init_cov``) inflated by
    ``proposal_scale``²) + DEMove 0.3, for near-Gaussian posteriors (τ of a few steps
    instead of tens); ``"adaptive-independence"``: independence MH alone with a proposal
    fitted to the posterior by importance sampling from that t
    (:func:`inference.proposal.fit_proposal`, ``proposal_points``, ``proposal_components``),
    the walkers started as its draws: τ ≈ 2 steps where the posterior is skewed in a few
    coordinates (the t alone: ≈ 8).
    Measured on correlated Gaussians (integrated τ in steps; NumPy log-density):
    10-D/32 walkers: stretch 102, de 34, de-snooker 37; 30-D/64 walkers: 253, 93, 106. The
    snooker move updates the ensemble in quarters (4 log-density calls per step instead of 2),
    so ``"de"`` is also the cheapest per step.
    """

    n_walkers: int | None = None
    n_chains: int = 4
    max_steps: int = 20000
    min_steps: int = 500
    target_ess: float = 1000.0
    tau_factor: float = 50.0
    check_every: int = 250
    moves: Literal["de", "de-snooker", "stretch", "de-independence", "adaptive-independence"] = "de"
    max_draws: int | None = None  # per chain, after thinning (bounds the cost of derived draws)
    proposal_df: float = 5.0
    proposal_scale: float = 1.3
    proposal_points: int = 1024
    """``"adaptive-independence"``: importance draws that fit the proposal
    (:func:`inference.proposal.fit_proposal`)."""
    proposal_components: int = 3
    proposal_alpha: float = 0.15
    """``"adaptive-independence"``: weight of the defensive t component (the start, its
    covariance × ``proposal_tail_scale``², ``proposal_tail_df`` degrees of freedom)."""
    proposal_tail_scale: float = 1.0
    proposal_tail_df: float | None = None
    proposal_shoulder_weight: float = 0.0
    """``"adaptive-independence"`` with ``prior_sd`` given to :func:`sample`: the share of
    the shoulder components, one per coordinate whose Laplace sd is at least
    ``proposal_shoulder_ratio`` of its prior sd (:mod:`inference.proposal`)."""
    proposal_shoulder_ratio: float = 0.1
    de_weight: float = 0.0
    """``"adaptive-independence"``: share of emcee's DEMove among the moves (local moves
    that let a walker caught where the proposal is thin walk back to the bulk)."""
    stop_rule: Literal["emcee", "bulk"] = "emcee"
    """``"emcee"``: emcee's estimate C·W·(n − burn)/τ_max ≥ ``target_ess``; ``"bulk"``: the
    rank-normalised bulk ESS of every coordinate of the draws that would be retained (burn-in,
    thinning and ``max_draws`` applied) ≥ ``target_ess`` and their rank R̂ across the
    independent ensembles ≤ ``rhat_max`` (:mod:`inference.mcmc_stats`)."""
    rhat_max: float = 1.01
    sampler: Literal["emcee", "auto"] = "emcee"
    """``"auto"`` with ``moves="adaptive-independence"``: importance sampling from the
    fitted proposal where it is reliable (PSIS k̂ < ``khat_max`` and ESS ≥ ``target_ess``
    for every coordinate and reported quantity, :mod:`inference.importance_path`), else
    emcee; ``"emcee"``: emcee always."""
    importance_points: int = 2048
    """The importance path's first draws (in ``n_chains`` batches); more while k̂ passes
    and an ESS falls short (as many as it needs), up to ``importance_max_points``."""
    importance_max_points: int = 8192
    khat_max: float = 0.7
    importance_refits: int = 1
    """Where k̂ refuses the importance draws, how many times the proposal's Gaussian
    components may be fitted anew to the weighted draws (population Monte Carlo) and the
    draws made afresh from it before emcee runs (:func:`inference.proposal.refit`)."""
    seed: int = 0
    progress: bool = True
    threads: int | None = None
    """Ensembles advanced concurrently (None: min(n_chains, CPU count)). The draws are the
    same for any value: each ensemble has its own random state and the log-density is
    deterministic; the compiled log-density releases the GIL, so one ensemble's Python
    (emcee's moves) overlaps another's evaluation."""

    def walkers(self, ndim: int) -> int:
        """Number of walkers per ensemble for a ``ndim``-dimensional problem (validated)."""
        if self.n_walkers is None:
            nw = max(2 * ndim + 2, 16)
            return nw + (nw % 2)
        nw = int(self.n_walkers)
        if nw % 2 or nw < 2 * ndim:
            raise ValueError(
                f"n_walkers={nw} must be even (emcee updates two halves, one compile each) and "
                f"≥ 2·ndim = {2 * ndim} (fewer walkers cannot span the parameter space)"
            )
        return nw

    def check(self) -> None:
        """Raise ``ValueError`` for settings :func:`sample` cannot honour."""
        if self.n_chains < 1:
            raise ValueError(f"n_chains must be ≥ 1, got {self.n_chains}")
        if self.check_every < 1 or self.max_steps < 1 or self.min_steps < 0:
            raise ValueError("check_every and max_steps must be ≥ 1, min_steps ≥ 0")
        kinds = (
            "de",
            "de-snooker",
            "stretch",
            "de-independence",
            "adaptive-independence",
        )
        if self.moves not in kinds:
            raise ValueError(f"moves must be one of {', '.join(kinds)}; got {self.moves!r}")
        if self.sampler not in ("emcee", "auto"):
            raise ValueError(f"sampler must be 'emcee' or 'auto', got {self.sampler!r}")
        if self.importance_points < 2 * self.n_chains or self.importance_max_points < 1:
            raise ValueError("importance_points must be ≥ 2·n_chains")
        if self.importance_refits < 0:
            raise ValueError(f"importance_refits must be ≥ 0, got {self.importance_refits}")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"threads must be ≥ 1 or None, got {self.threads}")
