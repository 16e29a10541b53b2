"""Integrated autocorrelation time of ensemble chains, and the burn-in and thinning it sets."""

from __future__ import annotations

import math

import numpy as np


def integrated_time(x: np.ndarray, c: float = 5.0) -> np.ndarray:
    """emcee's integrated autocorrelation time of ``x`` (step, walker, dim), vectorised.

    Same estimator as ``emcee.autocorr.integrated_time(x, c, tol=0)``: the normalised
    autocorrelation of every walker's series is averaged over walkers,
    τ(M) = 1 + 2 Σ_{t=1..M} ρ(t), and the window is the smallest M with M ≥ c·τ(M) (Sokal).
    One FFT over all walkers and dimensions instead of one per series. Walkers that never
    moved are left out of the average (emcee would return NaN); if none moved, τ = n_steps.
    """
    x = np.asarray(x, dtype=float)
    n_t = x.shape[0]
    if n_t < 2:
        return np.full(x.shape[2], np.nan)
    n = 1 << (n_t - 1).bit_length()
    xc = x - x.mean(axis=0)
    f = np.fft.rfft(xc, n=2 * n, axis=0)
    acf = np.fft.irfft(f * np.conj(f), n=2 * n, axis=0)[:n_t]
    moving = acf[0] > 0  # a walker that never moved has no autocorrelation to measure
    with np.errstate(invalid="ignore", divide="ignore"):
        acf = np.where(moving, acf / np.where(moving, acf[0], 1.0), 0.0)
    n_moving = moving.sum(axis=0)  # (dim,)
    rho = acf.sum(axis=1) / np.maximum(n_moving, 1)  # (step, dim)
    taus = 2.0 * np.cumsum(rho, axis=0) - 1.0
    below = np.arange(n_t)[:, None] < c * taus
    window = np.where(below.all(axis=0), n_t - 1, np.argmin(below, axis=0))
    tau = taus[window, np.arange(taus.shape[1])]
    return np.where(n_moving > 0, tau, float(n_t))  # nothing moved: as bad as it can be


def mean_tau(chains: list[np.ndarray], discard: int) -> np.ndarray:
    """Integrated autocorrelation time per coordinate, averaged over chains (steps)."""
    return np.mean([integrated_time(ch[discard:]) for ch in chains], axis=0)


def burn_thin(tau: np.ndarray, n_steps: int) -> tuple[int, int]:
    """Burn-in (2 τ_max, at most half the run) and thinning (τ_min / 2) of a run."""
    burn = math.ceil(2.0 * float(np.max(tau)))
    burn = min(burn, n_steps // 2)
    thin = max(1, int(float(np.min(tau)) // 2))
    return burn, thin
