"""A record that lacks part of its program, and an EM that stops at its cap, are flagged:
the result, the console and the certificate say so, and ``--strict`` exits 3."""

from __future__ import annotations

import dataclasses
import warnings

import pytest

from chekan.cli.commands import main
from chekan.pipeline import CalibrationOptions, calibrate
from chekan.records import Record, write_record
from chekan.results.summary import format_summary


@pytest.fixture(scope="module")
def one_round(short_session) -> tuple[Record, int]:
    """The short session (2 rounds) cut after its first round, as a run stopped half way."""
    _, rec, _ = short_session
    steps = int(rec.meta["program_steps"])
    half = steps // 2
    return rec.rows(rec.t_s < rec.t_s[rec.step == half][0]), steps


def _classical(rec: Record) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return calibrate(rec, CalibrationOptions(method="classical", progress=False))


def test_the_simulator_states_the_programs_steps(short_session, short_program) -> None:
    _, rec, _ = short_session
    assert rec.meta["program_steps"] == str(short_program.n_steps)
    assert "program_coverage" not in _classical(rec)


def test_a_record_missing_half_its_program_says_so(one_round) -> None:
    rec, steps = one_round
    res = _classical(rec)
    cov = res["program_coverage"]
    assert cov["program_steps"] == steps and cov["program_steps_known"]
    assert cov["missing_steps"] == list(range(steps // 2, steps))
    problems = res["diagnostics"]["problems"]
    assert any(f"of the program's {steps} steps" in p for p in problems), problems
    assert f"{steps // 2}–{steps - 1}" in format_summary(res)


def test_without_the_header_a_missing_inner_step_is_still_seen(short_session) -> None:
    _, rec, _ = short_session
    meta = {k: v for k, v in rec.meta.items() if k != "program_steps"}
    res = _classical(dataclasses.replace(rec.rows(rec.step != 5), meta=meta))
    assert res["program_coverage"]["missing_steps"] == [5]
    assert not res["program_coverage"]["program_steps_known"]


def test_strict_exits_3_on_a_record_missing_part_of_its_program(one_round, tmp_path) -> None:
    rec, _ = one_round
    path = tmp_path / "half.csv"
    write_record(path, rec)
    args = ["calibrate", str(path), "--method", "classical", "-q"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(args) == 0
        assert main([*args, "--strict"]) == 3


def _map_with_em_stopping(monkeypatch, short_session, moving) -> dict:
    """The short session's MAP with every EM pass reported stopped at its cap, ``moving``
    still moving."""
    from chekan.fit import map as joint_map

    real = joint_map.between_passes

    def capped(model, z, h):
        moved, h_new, n, _ = real(model, z, h)
        return moved, h_new, n, moving

    monkeypatch.setattr(joint_map, "between_passes", capped)
    _, rec, _ = short_session
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return calibrate(rec, CalibrationOptions(method="map", progress=False))


def test_an_em_stopped_at_its_cap_is_not_converged(short_session, monkeypatch) -> None:
    """The MAP converged but EM did not: before, the result said "converged: yes"."""
    res = _map_with_em_stopping(monkeypatch, short_session, (("σ_θ", 0.003),))
    d = res["diagnostics"]
    assert d["converged"] is False
    assert any("stopped at its cap" in p for p in d["problems"]), d["problems"]
    assert [p.get("hyper_converged", True) for p in d["map_passes"]][:-1] == [False, False]
    assert "converged: NO" in format_summary(res)


def test_an_em_creeping_to_a_variance_of_zero_at_its_cap_is_not_converged(
    short_session, monkeypatch
) -> None:
    """EM converging slowly to a boundary (a variance the data do not show) that its cap
    stops on the way down has not reached its estimate either: the result says so
    ("converged: NO", never yes at the cap) and flags the variance as one that ended at its
    bound is (the uncertainty that rests on it may be wrong)."""
    res = _map_with_em_stopping(monkeypatch, short_session, (("σ_θ", -0.002),))
    d = res["diagnostics"]
    assert d["converged"] is False
    assert not any("without converging" in p for p in d["problems"]), d["problems"]
    assert any("σ_θ still falling towards zero" in p for p in d["problems"]), d["problems"]
    assert "converged: NO" in format_summary(res)


def test_what_still_moves_at_the_cap() -> None:
    from chekan.joint.em import HYPER_TOL, still_moving, to_zero

    step = [0.0, 2 * HYPER_TOL, -0.5 * HYPER_TOL, 0.0, -3 * HYPER_TOL]
    moving = still_moving(step)
    assert [n for n, _ in moving] == ["noise scale s₂", "slew error κ"]
    assert not to_zero(moving)  # a noise scale still moves: not converged
    assert to_zero(still_moving([0.0, 0.0, -2 * HYPER_TOL, 0.0, -3 * HYPER_TOL]))
    assert not to_zero(still_moving([0.0, 0.0, 2 * HYPER_TOL, 0.0, -3 * HYPER_TOL]))
    assert not to_zero(())
