r"""Importance sampling from a fitted proposal: a fast path for the posterior, with its test.

**Self-normalised importance sampling.** With :math:`x_i \sim q` (:math:`i = 1..S`, independent)
and the ratios :math:`r_i = p(x_i)/q(x_i)` of the unnormalised posterior :math:`p` to the
normalised proposal :math:`q`, the weights :math:`w_i = r_i / \sum_j r_j` give

.. math::  \hat\mu_f = \sum_i w_i f(x_i) \;\to\; E_p[f],

consistent whatever the normalisation of :math:`p`, but reliable only where the ratios have a
light right tail (Geweke 1989; Owen 2013, ch. 9).

**PSIS.** Pareto-smoothed importance sampling (Vehtari, Simpson, Gelman, Yao & Gabry 2024,
"Pareto smoothed importance sampling", JMLR 25(72)) fits a generalised Pareto distribution to
the :math:`M = \min(S/5, 3\sqrt S)` largest ratios, replaces them by the fit's expected order
statistics (truncated at the largest raw ratio) and reports the fit's shape :math:`\hat k`. The
ratios have :math:`\lfloor 1/k \rfloor` finite moments: :math:`\hat k < 1/2`, finite variance,
the central limit theorem holds; :math:`\hat k < \min(1 - 1/\log_{10} S,\, 0.7)`, the smoothed
estimate's error falls quickly enough with S to be trusted; above it, the proposal's tails are
too light for the posterior and no practicable S helps (:func:`judge` refuses). Computed by
:func:`inference.arviz_io.psis_log_weights` (ArviZ's ``psislw``); −inf log densities (outside
the support) get weight 0.

**Per-quantity ESS.** With normalised :math:`w` and :math:`\hat\mu = \sum_i w_i f_i`, the
estimate's variance is :math:`\widehat{\mathrm{Var}}(\hat\mu) = \sum_i w_i^2 (f_i-\hat\mu)^2`
and the posterior variance :math:`\widehat{\mathrm{Var}}_p(f) = \sum_i w_i (f_i-\hat\mu)^2`,
so (Vehtari et al. 2024, the function-specific effective sample size)

.. math::  \mathrm{ESS}_f = \frac{\widehat{\mathrm{Var}}_p(f)}{\widehat{\mathrm{Var}}(\hat\mu)}
           = \frac{\sum_i w_i (f_i-\hat\mu)^2}{\sum_i w_i^2 (f_i-\hat\mu)^2},\qquad
           \mathrm{MCSE}_f = \sqrt{\textstyle\sum_i w_i^2 (f_i-\hat\mu)^2},

against Kish's :math:`1/\sum_i w_i^2` for every f (the two agree for f uncorrelated with w).

**Systematic resampling.** Equal-weight draws for the caller's summaries: the points are drawn
in independent *batches* that serve as chains (R̂ across batches checks that they agree);
within a batch with normalised weights :math:`w` and cumulative sums :math:`c_j`, one uniform
:math:`U` gives :math:`u_m = (U + m)/M` (:math:`m = 0..M-1`) and the index
:math:`\min\{j : c_j > u_m\}`: point j is taken :math:`\lfloor M w_j \rfloor` or
:math:`\lceil M w_j \rceil` times (Kitagawa 1996; Douc, Cappé & Moulines 2005), so equal
weights and M = the batch size take every point once. Duplicates are adjacent; the draws are
then shuffled within their batch (``shuffle``), so that autocorrelation-based diagnostics do not
mistake the copies for a slowly mixing chain. The resampled draws add resampling noise: report
the ESS and MCSE of the weighted estimate, not of the resampled draws.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from .arviz_io import psis_log_weights

__all__ = [
    "ImportanceDraws",
    "ImportanceVerdict",
    "Proposal",
    "draw_importance",
    "extend",
    "judge",
    "k_threshold",
    "quantity_ess",
    "quantity_ess_many",
    "resample",
    "weighted_mean_mcse",
]


class Proposal(Protocol):
    """What :func:`draw_importance` needs of a proposal (a
    :class:`inference.proposal.MixtureProposal`)."""

    def sample(self, n: int, random: np.random.Generator) -> np.ndarray: ...

    def log_q(self, x: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class ImportanceDraws:
    """Independent draws from a proposal q, weighted towards the posterior p.

    ``points`` (n, d); ``log_density`` (n,) log p, −inf outside the support; ``log_q`` (n,);
    ``log_weights`` (n,) PSIS-smoothed, normalised over all n (logsumexp 0; −inf: weight 0);
    ``khat`` the Pareto shape of the ratios p/q; ``batch`` (n,) the independent batch
    (0..B−1) each point belongs to.
    """

    points: np.ndarray
    log_density: np.ndarray
    log_q: np.ndarray
    log_weights: np.ndarray
    khat: float
    batch: np.ndarray

    def __post_init__(self) -> None:
        n = self.points.shape[0]
        if self.points.ndim != 2:
            raise ValueError(f"points must be (n, d), got {self.points.shape}")
        for name in ("log_density", "log_q", "log_weights", "batch"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"{name} must be ({n},), got {getattr(self, name).shape}")

    @property
    def n_batches(self) -> int:
        """B, the number of independent batches."""
        return int(self.batch.max()) + 1

    @property
    def log_ratios(self) -> np.ndarray:
        """log p − log q (−inf outside the support), before smoothing."""
        return np.where(np.isfinite(self.log_density), self.log_density - self.log_q, -np.inf)

    @property
    def ess(self) -> float:
        """Kish's effective sample size 1/Σᵢ wᵢ² of the normalised weights."""
        return float(1.0 / np.sum(np.exp(2.0 * self.log_weights)))


def _batch_labels(n_points: int, n_batches: int) -> np.ndarray:
    """Batch b of B gets ⌊n/B⌋ points, the first n mod B batches one more, contiguous."""
    sizes = np.full(n_batches, n_points // n_batches) + (
        np.arange(n_batches) < n_points % n_batches
    )
    return np.repeat(np.arange(n_batches), sizes)


def _draw_block(
    log_density: Callable[[np.ndarray], np.ndarray],
    proposal: Proposal,
    n_points: int,
    rng: np.random.Generator,
    ndim: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = np.asarray(proposal.sample(n_points, rng), dtype=float)
    if x.ndim != 2 or x.shape[0] != n_points:
        raise ValueError(f"proposal.sample({n_points}) gave shape {x.shape}, not (n, d)")
    if ndim is not None and x.shape[1] != ndim:
        raise ValueError(f"the proposal's points have {x.shape[1]} coordinates, the draws {ndim}")
    lp = np.asarray(log_density(x), dtype=float)
    lq = np.asarray(proposal.log_q(x), dtype=float)
    for name, v in (("log_density", lp), ("proposal.log_q", lq)):
        if v.shape != (n_points,):
            raise ValueError(f"{name} of ({n_points}, d) points gave shape {v.shape}")
    if np.isnan(lp).any() or np.isposinf(lp).any():
        bad = int(np.count_nonzero(np.isnan(lp) | np.isposinf(lp)))
        raise ValueError(f"log_density is NaN or +inf at {bad} of {n_points} points")
    if not np.all(np.isfinite(lq)):
        raise ValueError("proposal.log_q is not finite at points it drew")
    return x, lp, lq


def _weighted(
    points: np.ndarray, lp: np.ndarray, lq: np.ndarray, batch: np.ndarray
) -> ImportanceDraws:
    lr = np.where(np.isfinite(lp), lp - lq, -np.inf)
    log_w, khat = psis_log_weights(lr)
    return ImportanceDraws(points, lp, lq, log_w, khat, batch)


def draw_importance(
    log_density: Callable[[np.ndarray], np.ndarray],
    proposal: Proposal,
    n_points: int,
    n_batches: int,
    rng: np.random.Generator,
) -> ImportanceDraws:
    """``n_points`` draws of ``proposal`` in ``n_batches`` independent batches, weighted by
    PSIS of the ratios log p − log q over all of them (module docstring).

    ``log_density``: (n, d) → (n,) log p up to a constant, −inf outside the support (called
    once on all points: the caller chunks it); ``proposal``: ``.sample(n, rng)`` and
    ``.log_q(x)`` of a normalised density.
    """
    if n_batches < 1 or n_points < n_batches:
        raise ValueError(f"need 1 ≤ n_batches ≤ n_points, got {n_batches} and {n_points}")
    x, lp, lq = _draw_block(log_density, proposal, n_points, rng)
    return _weighted(x, lp, lq, _batch_labels(n_points, n_batches))


def extend(
    draws: ImportanceDraws,
    log_density: Callable[[np.ndarray], np.ndarray],
    proposal: Proposal,
    n_points: int,
    rng: np.random.Generator,
) -> ImportanceDraws:
    """``draws`` and ``n_points`` new draws of the same ``proposal``, shared among the same
    batches, with PSIS again on the union (k̂ and the weights of all points change); for an
    ESS short of its target while k̂ is fine: it grows about in proportion to the points.
    ``draws`` is not changed."""
    b = draws.n_batches
    if n_points < b:
        raise ValueError(f"need at least one new point per batch ({b}), got {n_points}")
    x, lp, lq = _draw_block(log_density, proposal, n_points, rng, draws.points.shape[1])
    return _weighted(
        np.concatenate([draws.points, x]),
        np.concatenate([draws.log_density, lp]),
        np.concatenate([draws.log_q, lq]),
        np.concatenate([draws.batch, _batch_labels(n_points, b)]),
    )


# --------------------------------------------------------------------------- estimates
def _normalised(log_weights: np.ndarray, n: int) -> np.ndarray:
    lw = np.asarray(log_weights, dtype=float)
    if lw.shape != (n,):
        raise ValueError(f"log_weights must be ({n},) for {n} points, got {lw.shape}")
    if not np.isfinite(lw).any() or np.isnan(lw).any():
        raise ValueError("log_weights need a finite entry and no NaN")
    w = np.exp(lw - np.max(lw))
    return w / w.sum()


def _centred(values: np.ndarray, log_weights: np.ndarray):
    """(w (n,), f − μ̂ (n, m), μ̂ (m,), bad (m,)): f flattened to columns, 0 where w = 0."""
    f = np.asarray(values, dtype=float)
    if f.ndim < 1:
        raise ValueError("values need a leading axis of points")
    w = _normalised(log_weights, f.shape[0])
    f = f.reshape(f.shape[0], -1)
    pos = w > 0
    bad = ~np.all(np.isfinite(f[pos]), axis=0)
    f = np.where(pos[:, None] & np.isfinite(f), f, 0.0)
    mu = w @ f
    return w, f - mu, mu, bad


def weighted_mean_mcse(
    values: np.ndarray, log_weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """μ̂ = Σᵢ wᵢ fᵢ and its MCSE √(Σᵢ wᵢ² (fᵢ − μ̂)²) for ``values`` (n, ...) → (...) each;
    NaN where f is not finite at a point of positive weight."""
    shape = np.shape(values)[1:]
    w, d, mu, bad = _centred(values, log_weights)
    mcse = np.sqrt((w * w) @ (d * d))
    mu, mcse = np.where(bad, np.nan, mu), np.where(bad, np.nan, mcse)
    return mu.reshape(shape), mcse.reshape(shape)


def quantity_ess_many(values: np.ndarray, log_weights: np.ndarray) -> np.ndarray:
    """ESS_f = Σᵢ wᵢ (fᵢ − μ̂)² / Σᵢ wᵢ² (fᵢ − μ̂)² (Vehtari et al. 2024) of each quantity of
    ``values`` (n, ...) → (...); inf for one constant over the points of positive weight,
    NaN for one not finite at such a point. ``log_weights`` (n,), normalised or not."""
    arr = np.asarray(values, dtype=float)
    w, d, _, bad = _centred(arr, log_weights)
    pos = w > 0
    sub = arr.reshape(arr.shape[0], -1)[pos]
    const = np.all(sub == sub[:1], axis=0)
    num, den = w @ (d * d), (w * w) @ (d * d)
    with np.errstate(divide="ignore", invalid="ignore"):
        ess = num / den
    ess = np.where(const, np.inf, ess)
    return np.where(bad, np.nan, ess).reshape(arr.shape[1:])


def quantity_ess(values: np.ndarray, log_weights: np.ndarray) -> float:
    r"""ESS of the self-normalised estimate of :math:`E_p[f]`, ``values`` (n,):

    .. math::  \mathrm{ESS}_f = \frac{\sum_i w_i (f_i-\hat\mu)^2}{\sum_i w_i^2 (f_i-\hat\mu)^2},
               \qquad \hat\mu = \sum_i w_i f_i,

    the function-specific ESS of Vehtari et al. (2024), "Pareto smoothed importance
    sampling"; inf for a constant f (no Monte-Carlo error), NaN for f not finite at a point
    of positive weight."""
    f = np.asarray(values, dtype=float)
    if f.ndim != 1:
        raise ValueError(f"quantity_ess needs one value per point (n,), got {f.shape}")
    return float(quantity_ess_many(f, log_weights))


# --------------------------------------------------------------------------- resampling
def resample(
    draws: ImportanceDraws, n_per_batch: int, rng: np.random.Generator, *, shuffle: bool = True
) -> np.ndarray:
    """Indices (n_batches, n_per_batch) into ``draws.points`` of equal-weight draws: systematic
    resampling within each batch by the batch's own normalised weights (module docstring),
    then (``shuffle``) a random order within the batch. Row b holds points of batch b only."""
    if n_per_batch < 1:
        raise ValueError(f"n_per_batch must be ≥ 1, got {n_per_batch}")
    out = np.empty((draws.n_batches, n_per_batch), dtype=np.int64)
    for b in range(draws.n_batches):
        members = np.flatnonzero(draws.batch == b)
        lw = draws.log_weights[members]
        if not np.isfinite(lw).any():
            raise ValueError(f"batch {b} has no point of positive weight")
        w = np.exp(lw - np.max(lw))
        c = np.cumsum(w)
        c /= c[-1]
        u = (rng.random() + np.arange(n_per_batch)) / n_per_batch
        pick = np.minimum(np.searchsorted(c, u, side="right"), members.size - 1)
        idx = members[pick]
        out[b] = rng.permutation(idx) if shuffle else idx
    return out


# --------------------------------------------------------------------------- verdict
def k_threshold(n_points: int, k_max: float = 0.7) -> float:
    """The largest trustworthy k̂ for S points: min(1 − 1/log₁₀ S, k_max) (Vehtari et al. 2024);
    −inf for S ≤ 1."""
    if n_points <= 1:
        return -math.inf
    return min(1.0 - 1.0 / math.log10(n_points), k_max)


def _fmt(x: float) -> str:
    return f"{x:,.0f}".replace(",", " ") if math.isfinite(x) else str(x)


@dataclass(frozen=True)
class ImportanceVerdict:
    """Whether the importance draws may stand for the posterior, and why (``message``).

    ``khat`` and ``k_limit`` (the threshold it was held to); ``min_ess`` the least ESS of the
    quantities, ``limiting`` the quantity that refused or has it; ``ess`` each judged
    quantity's ESS; ``skipped`` the names of entries that are not one number per point.
    """

    accepted: bool
    khat: float
    k_limit: float
    min_ess: float
    limiting: str | None
    message: str
    ess: Mapping[str, float] = field(default_factory=dict)
    skipped: tuple[str, ...] = ()
    n_points: int = 0
    """The draws weighed."""
    refits: int = 0
    """How many times the proposal was refitted to weighted draws before these."""


#: The name under which :func:`judge` reports Kish's ESS when no quantity is given.
KISH = "weights (Kish)"


def judge(
    draws: ImportanceDraws,
    quantities: Mapping[str, np.ndarray],
    k_max: float = 0.7,
    target_ess: float = 1000.0,
) -> ImportanceVerdict:
    """Accept the draws where k̂ < :func:`k_threshold` (of the points of positive ratio,
    ``k_max``) and :func:`quantity_ess` ≥ ``target_ess`` for every quantity; otherwise refuse,
    saying why. ``quantities``: name → (n,) numbers per point; entries of another shape
    (a scalar, (n, k), text) are skipped; one not finite at a point of positive weight
    refuses. No usable quantity: Kish's ESS (:data:`KISH`) is held to the target."""
    n = draws.points.shape[0]
    lw = draws.log_weights
    ess: dict[str, float] = {}
    skipped: list[str] = []
    for name, v in quantities.items():
        a = np.asarray(v)
        if a.shape != (n,) or a.dtype.kind not in "biuf":
            skipped.append(name)
            continue
        ess[name] = quantity_ess(a.astype(float), lw)
    if not ess:
        ess[KISH] = draws.ess
    s = int(np.count_nonzero(np.isfinite(draws.log_ratios)))
    k_lim = k_threshold(s, k_max)
    bad = [k for k, e in ess.items() if math.isnan(e)]
    finite = {k: e for k, e in ess.items() if not math.isnan(e)}
    limiting = min(finite, key=lambda k: finite[k]) if finite else None
    min_ess = finite[limiting] if limiting is not None else math.nan
    khat = draws.khat

    def verdict(ok: bool, why: str, name: str | None) -> ImportanceVerdict:
        return ImportanceVerdict(ok, khat, k_lim, min_ess, name, why, ess, tuple(skipped), n)

    if not khat < k_lim:
        return verdict(
            False,
            f"importance sampling refused: k̂ = {khat:.2f} ≥ {k_lim:.2f} (the limit for {s} "
            "points): the proposal's tails are too light for the posterior",
            limiting,
        )
    if bad:
        w_pos = lw > -np.inf
        count = int(np.count_nonzero(w_pos & ~np.isfinite(np.asarray(quantities[bad[0]], float))))
        return verdict(
            False,
            f"importance sampling refused: {bad[0]!r} is not finite at {count} point(s) of "
            "positive weight",
            bad[0],
        )
    assert limiting is not None
    if min_ess < target_ess:
        return verdict(
            False,
            f"importance sampling refused: ESS of {limiting!r} = {_fmt(min_ess)} < "
            f"{_fmt(target_ess)} (k̂ = {khat:.2f} < {k_lim:.2f})",
            limiting,
        )
    return verdict(
        True,
        f"importance sampling: k̂ = {khat:.2f} < {k_lim:.2f}, ESS ≥ {_fmt(min_ess)} for every "
        f"quantity (least: {limiting!r})",
        limiting,
    )
