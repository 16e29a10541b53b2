"""Options of one calibration, typed and built at the edge (CLI, archive, validation)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

METHODS = ("classical", "map", "bayes")


@dataclass(frozen=True)
class CalibrationOptions:
    """How to calibrate one record or protocol."""

    method: str = "classical"
    hdi_prob: float = 0.95
    settle_s: float | None = None  # None: the record's program_settle_s, else 300 s
    a_fixed: float | None = None  # record convention, mGal/pix²
    netcdf: str | Path | None = None  # bayes: where to write the ArviZ posterior
    seed: int = 0
    progress: bool = True
    encoder_error: bool = False  # bayes/map: smooth systematic angle error per commanded angle
    quick: bool = False  # bayes: cap the sampler at 3000 steps (tests, demos)
