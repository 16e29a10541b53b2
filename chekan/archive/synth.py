r"""Simulated archives: years of SHORT calibration sessions of instruments whose scale drifts.

For tests, benchmarks and demos of the archive. The true scale factors of an instrument at
date t are

.. math::  b_s(t) = b_s^{(0)}\,\bigl(1 + 10^{-6}[\,r\,(t - t_\mathrm{ref}) + J(t)]\bigr)

with r in ppm per year (t in years of 365.25 days) and J(t) the sum of the jumps (ppm)
dated on or before t. Each session is a record of a short program (4 angles, 120 s dwell,
one round: about 25 minutes, 60 kB) simulated by :func:`chekan.records.simulate.simulate_session`
with a fast-settling sensor, so that the classical estimate is unbiased.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from chekan.archive.history import DAYS_PER_YEAR


@dataclass
class InstrumentSpec:
    """An instrument of a simulated archive (dates ISO ``YYYY-MM-DD``)."""

    serial: str
    b_ref: tuple[float, float] = (6.98, 6.88)
    rate_ppm_per_year: float = 0.0
    t_ref: str = "2015-01-01"
    jumps: list[tuple[str, float]] = field(default_factory=list)
    seed: int = 0

    def b_at(self, date: str) -> tuple[float, float]:
        """True (b1, b2) at ``date``."""
        d = _dt.date.fromisoformat(date[:10])
        t = (d - _dt.date.fromisoformat(self.t_ref)).days / DAYS_PER_YEAR
        ppm = self.rate_ppm_per_year * t + sum(
            j for jd, j in self.jumps if _dt.date.fromisoformat(jd) <= d
        )
        return (self.b_ref[0] * (1 + 1e-6 * ppm), self.b_ref[1] * (1 + 1e-6 * ppm))


def short_program():
    """4 angles (2°…5°), dwell 120 s of which 40 s settle, one round: 10 steps, 20 min."""
    from chekan.physics.program import build_program

    return build_program([2.0, 3.0, 4.0, 5.0], name="short", dwell_s=120.0, settle_s=40.0, rounds=1)


def session_dates(start: str, years: float, n: int, rng: np.random.Generator) -> list[str]:
    """``n`` sorted dates spread over ``years`` from ``start`` (jittered by ±1 month)."""
    d0 = _dt.date.fromisoformat(start)
    span = years * DAYS_PER_YEAR
    days = np.linspace(0, span, n) + rng.uniform(-30, 30, n)
    days = np.sort(np.clip(days, 0, span)).round().astype(int)
    return [(d0 + _dt.timedelta(days=int(x))).isoformat() for x in days]


def write_session(path: str | Path, spec: InstrumentSpec, date: str, seed: int, program=None):
    """Simulate one session of ``spec`` on ``date`` into ``path``; returns the Truth."""
    from chekan.records import write_record
    from chekan.records.simulate import Truth, simulate_session

    rng = np.random.default_rng(spec.seed)  # the instrument's constant properties
    truth = Truth(
        serial=spec.serial,
        b_mgal_per_pix=spec.b_at(date),
        m_level_pix=tuple(1024.0 + rng.normal(0, 15, 2)),
        eps_arcmin=tuple(rng.normal(0, 3.0, 2)),
        dgamma_arcmin=float(rng.normal(0, 5.0)),
        tau_s=5.0,
        noise_pix=(0.10, 0.10),
        hold_offset_sd_pix=0.03,
        angle_error_sd_arcsec=0.5,
        # a quiet platform: these archives test the history's statistics, not the angle
        # model (a systematic error redrawn per session would be a different platform)
        angle_systematic_arcsec=0.0,
    )
    rec, truth = simulate_session(
        program or short_program(), truth, seed=seed, started=f"{date}T06:00:00Z"
    )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_record(path, rec)
    return truth


def write_archive_inputs(
    out_dir: str | Path,
    specs: list[InstrumentSpec],
    *,
    sessions: int = 12,
    start: str = "2010-01-15",
    years: float = 10.0,
    seed: int = 0,
) -> dict[str, list[tuple[Path, str]]]:
    """Write ``sessions`` records per instrument under ``out_dir/<serial>/``.

    Returns ``{serial: [(path, date), …]}``.
    """
    out: dict[str, list[tuple[Path, str]]] = {}
    program = short_program()
    for k, spec in enumerate(specs):
        rng = np.random.default_rng(seed + 1000 * k)
        out[spec.serial] = []
        for i, date in enumerate(session_dates(start, years, sessions, rng)):
            p = Path(out_dir) / spec.serial / f"calib_{spec.serial}_{date}.csv"
            write_session(p, spec, date, seed=seed + 1000 * k + i, program=program)
            out[spec.serial].append((p, date))
    return out
