r"""R̂, effective sample sizes, Monte-Carlo error and HDI of (chain, draw) arrays in NumPy.

The estimators of Vehtari et al. (2021), written exactly as ArviZ 0.23 computes them
(``arviz.rhat(method="rank")``, ``arviz.ess(method="bulk"|"tail")``,
``arviz.mcse(method="mean")``, ``arviz.hdi``), so that a posterior summary needs neither
ArviZ nor xarray nor ``scipy.stats`` (≈ 2 s of imports in a new process). A test compares
every function with ArviZ on random and autocorrelated chains (equal to round-off).

With the chains split in halves, :math:`z` the normal scores of the pooled ranks
(Blom: :math:`\Phi^{-1}((r - 3/8)/(n + 1/4))`), the autocovariance :math:`\hat c_t` of each
chain (FFT) and :math:`\hat\rho_t = 1 - (W - \bar c_t)/\widehat{\mathrm{var}}^+`,

.. math::  \mathrm{ESS} = \frac{MN}{-1 + 2\sum_{t\le T}\hat\rho_t}

with Geyer's initial positive and monotone sequences choosing :math:`T`;
:math:`\hat R = \max(\hat R(z), \hat R(z_{\text{folded}}))`, each
:math:`\sqrt{(B/W + N - 1)/N}`.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ess_bulk", "ess_mean", "ess_tail", "hdi", "mcse_mean", "rhat_rank"]


def _valid(ary: np.ndarray, min_chains: int) -> bool:
    return not (np.isnan(ary).any() or ary.shape[0] < min_chains or ary.shape[1] < 4)


def _next_fast_len(target: int) -> int:
    """Smallest 5-smooth number ≥ ``target`` (``scipy.fftpack.next_fast_len``)."""
    n = max(int(target), 1)
    while True:
        m = n
        for p in (2, 3, 5):
            while m % p == 0:
                m //= p
        if m == 1:
            return n
        n += 1


def _autocov(ary: np.ndarray) -> np.ndarray:
    """Autocovariance of each row at every lag (biased, / n), by FFT."""
    n = ary.shape[1]
    m = _next_fast_len(2 * n)
    x = ary - ary.mean(axis=1, keepdims=True)
    f = np.fft.rfft(x, n=m, axis=1)
    f *= np.conjugate(f)
    return np.fft.irfft(f, n=m, axis=1)[:, :n] / n


def _rankdata(a: np.ndarray) -> np.ndarray:
    """Average ranks (1-based) of the flattened ``a`` (``scipy.stats.rankdata``)."""
    a = np.ravel(a)
    sorter = np.argsort(a, kind="mergesort")
    inv = np.empty(sorter.size, dtype=np.intp)
    inv[sorter] = np.arange(sorter.size, dtype=np.intp)
    s = a[sorter]
    obs = np.r_[True, s[1:] != s[:-1]]
    dense = obs.cumsum()[inv]
    count = np.r_[np.nonzero(obs)[0], len(obs)]
    return 0.5 * (count[dense] + count[dense - 1] + 1)


def _poly(c: tuple[float, ...], r: np.ndarray) -> np.ndarray:
    out = np.full_like(r, c[0])
    for a in c[1:]:
        out = out * r + a
    return out


_AS241 = (
    (2.5090809287301226727e3, 3.3430575583588128105e4, 6.7265770927008700853e4,
     4.5921953931549871457e4, 1.3731693765509461125e4, 1.9715909503065514427e3,
     1.3314166789178437745e2, 3.3871328727963666080e0),
    (5.2264952788528545610e3, 2.8729085735721942674e4, 3.9307895800092710610e4,
     2.1213794301586595867e4, 5.3941960214247511077e3, 6.8718700749205790830e2,
     4.2313330701600911252e1, 1.0),
    (7.7454501427834140764e-4, 2.2723844989269184583e-2, 2.4178072517745061177e-1,
     1.2704582524523683826e0, 3.6478483247632046050e0, 5.7694972214606914055e0,
     4.6303378461565452959e0, 1.4234371107496835773e0),
    (1.0507500716444168432e-9, 5.4759380849953449460e-4, 1.5198666563616457197e-2,
     1.4810397642748007459e-1, 6.8976733498510000455e-1, 1.6763848301838038494e0,
     2.0531916266377588219e0, 1.0),
    (2.0103343992922881327e-7, 2.7115555687434875782e-5, 1.2426609473880784386e-3,
     2.6532189526576123093e-2, 2.9656057182850489123e-1, 1.7848265399172913358e0,
     5.4637849111641143699e0, 6.6579046435011037772e0),
    (2.0442631033899397856e-15, 1.4215117583164458887e-7, 1.8463183175100546818e-5,
     7.8686913114561325910e-4, 1.4875361290850614853e-2, 1.3692988092273580531e-1,
     5.9983220655588793769e-1, 1.0),
)  # fmt: skip


def _ndtri(p: np.ndarray) -> np.ndarray:
    """Φ⁻¹(p) for 0 < p < 1 (Wichura 1988, AS241, as Python's ``statistics.NormalDist``;
    ≈ 1e-16 relative, as ``scipy.special.ndtri``, without importing SciPy)."""
    p = np.asarray(p, dtype=float)
    q = p - 0.5
    r = 0.180625 - q * q
    central = q * _poly(_AS241[0], r) / _poly(_AS241[1], r)
    t = np.sqrt(-np.log(np.where(q <= 0.0, p, 1.0 - p)))
    near = _poly(_AS241[2], t - 1.6) / _poly(_AS241[3], t - 1.6)
    far = _poly(_AS241[4], t - 5.0) / _poly(_AS241[5], t - 5.0)
    tail = np.where(t <= 5.0, near, far)
    return np.where(np.abs(q) <= 0.425, central, np.where(q < 0.0, -tail, tail))


def _z_scale(ary: np.ndarray) -> np.ndarray:
    rank = _rankdata(ary)
    return _ndtri((rank - 3 / 8) / (rank.size - 2 * 3 / 8 + 1)).reshape(ary.shape)


def _split_chains(ary: np.ndarray) -> np.ndarray:
    half = ary.shape[1] // 2
    return np.vstack((ary[:, :half], ary[:, -half:]))


def _rhat(ary: np.ndarray) -> float:
    n = ary.shape[1]
    between = n * np.var(np.mean(ary, axis=1), ddof=1)
    within = np.mean(np.var(ary, axis=1, ddof=1))
    return float(np.sqrt((between / within + n - 1) / n))


def _ess(ary: np.ndarray) -> float:
    ary = np.asarray(ary, dtype=float)
    if np.isnan(ary).any():
        return math.nan
    if (np.max(ary) - np.min(ary)) < np.finfo(float).resolution:
        return float(ary.size)
    n_chain, n_draw = ary.shape
    acov = _autocov(ary)
    mean_var = np.mean(acov[:, 0]) * n_draw / (n_draw - 1.0)
    var_plus = mean_var * (n_draw - 1.0) / n_draw
    if n_chain > 1:
        var_plus += np.var(ary.mean(axis=1), ddof=1)
    acov_mean = acov.mean(axis=0)
    rho = np.zeros(n_draw)
    even = 1.0
    rho[0] = even
    odd = 1.0 - (mean_var - acov_mean[1]) / var_plus
    rho[1] = odd
    t = 1  # Geyer's initial positive sequence
    while t < (n_draw - 3) and (even + odd) > 0.0:
        even = 1.0 - (mean_var - acov_mean[t + 1]) / var_plus
        odd = 1.0 - (mean_var - acov_mean[t + 2]) / var_plus
        if (even + odd) >= 0:
            rho[t + 1] = even
            rho[t + 2] = odd
        t += 2
    max_t = t - 2
    if even > 0:
        rho[max_t + 1] = even
    t = 1  # Geyer's initial monotone sequence
    while t <= max_t - 2:
        if (rho[t + 1] + rho[t + 2]) > (rho[t - 1] + rho[t]):
            rho[t + 1] = (rho[t - 1] + rho[t]) / 2.0
            rho[t + 2] = rho[t + 1]
        t += 2
    ess = n_chain * n_draw
    tau = -1.0 + 2.0 * np.sum(rho[: max_t + 1]) + np.sum(rho[max_t + 1 : max_t + 2])
    tau = max(tau, 1 / np.log10(ess))
    return math.nan if np.isnan(rho).any() else float(ess / tau)


def rhat_rank(x: np.ndarray) -> float:
    """Rank-normalised split R̂, the larger of the bulk and the folded (tail) one."""
    x = np.asarray(x, dtype=float)
    if not _valid(x, 2):
        return math.nan
    s = _split_chains(x)
    return max(_rhat(_z_scale(s)), _rhat(_z_scale(np.abs(s - np.median(s)))))


def ess_bulk(x: np.ndarray) -> float:
    """Rank-normalised bulk ESS of a (chain, draw) array."""
    x = np.asarray(x, dtype=float)
    return _ess(_z_scale(_split_chains(x))) if _valid(x, 1) else math.nan


def ess_mean(x: np.ndarray) -> float:
    """Split-chain ESS of the mean (no rank normalisation)."""
    x = np.asarray(x, dtype=float)
    return _ess(_split_chains(x)) if _valid(x, 1) else math.nan


def ess_tail(x: np.ndarray, prob: tuple[float, float] = (0.05, 0.95)) -> float:
    """The smaller ESS of the indicators x ≤ q at the 5 % and 95 % quantiles (type 7)."""
    x = np.asarray(x, dtype=float)
    if not _valid(x, 1):
        return math.nan
    return min(_ess(_split_chains((x <= np.quantile(x, p)).astype(float))) for p in prob)


def mcse_mean(x: np.ndarray) -> float:
    """Monte-Carlo standard error of the mean: sd / √ESS_mean."""
    x = np.asarray(x, dtype=float)
    if not _valid(x, 1):
        return math.nan
    return float(np.std(x, ddof=1) / np.sqrt(ess_mean(x)))


def hdi(x: np.ndarray, hdi_prob: float) -> tuple[float, float]:
    """Highest-density interval of all values of ``x`` (the narrowest window holding
    ⌊p·n⌋ + 1 sorted values)."""
    a = np.sort(np.asarray(x, dtype=float).reshape(-1))
    a = a[~np.isnan(a)] if not np.isnan(a).all() else a
    n = a.size
    k = int(np.floor(hdi_prob * n))
    width = a[k:] - a[: n - k]
    if width.size == 0:
        raise ValueError("Too few elements for interval calculation. ")
    i = int(np.argmin(width))
    return float(a[i]), float(a[i + k])
