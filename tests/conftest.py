"""Shared fixtures: the paper's protocol, a short simulated session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("CHEKAN_JAX_CACHE", str(Path(__file__).resolve().parents[1] / ".jax-cache"))

SHARED = Path(__file__).resolve().parents[2] / "shared"
PAPER_PROTOCOL = SHARED / "reference" / "calibr_46_protocol.csv"


@pytest.fixture(scope="session")
def paper_protocol() -> Path:
    if not PAPER_PROTOCOL.is_file():
        pytest.skip(f"the paper's protocol is not at {PAPER_PROTOCOL}")
    return PAPER_PROTOCOL


@pytest.fixture(scope="session")
def short_program():
    """The paper's eight angles with 300 s dwells (200 s settle): 3 h, ~11 000 samples."""
    from chekan.demo import demo_program

    return demo_program(quick=True)


@pytest.fixture(scope="session")
def short_session(short_program, tmp_path_factory):
    """(record path, Record, Truth) of a short simulated session (seed 7)."""
    from chekan.records import write_record
    from chekan.simulate import Truth, simulate_session

    rec, truth = simulate_session(short_program, Truth(serial="T-1"), seed=7)
    path = tmp_path_factory.mktemp("session") / "rec.csv"
    write_record(path, rec)
    return path, rec, truth
