"""Angles as a row records them: the platform's latest report, up to one report period old
(the serial protocol: at least one report a second). The simulator can make them so
(``Truth.platform_report_period_s``), and the validation has a case for it."""

from __future__ import annotations

import numpy as np
import pytest

from chekan.demo import demo_program
from chekan.records.simulate import random_truth, simulate_session


def _session(seed: int, period_s: float, phase_s: float | None, *, quiet=(), **overrides):
    """A 3 h session; ``quiet`` names the noises set to zero after the draw
    ("tilt_jitter_arcsec", "noise_pix"), ``overrides`` go to the drawn instrument."""
    truth = random_truth(
        np.random.default_rng(seed),
        serial="LATE",
        platform_report_period_s=period_s,
        platform_report_phase_s=phase_s,
        **overrides,
    )
    for name in quiet:
        setattr(truth, name, 0.0 if name == "tilt_jitter_arcsec" else (0.0, 0.0))
    return simulate_session(demo_program(quick=True), truth, seed=seed)


def test_a_row_carries_the_latest_report_and_nothing_else_moves():
    on, _ = _session(3, 0.0, None)
    late, truth = _session(3, 1.0, 0.95)  # every report 0.05 s before a sample
    assert truth.platform_report_phase_s == 0.95
    for col in ("t_s", "m1_pix", "m2_pix", "step"):
        assert np.array_equal(getattr(on, col), getattr(late, col)), col
    d = late.tilt_y_arcsec - on.tilt_y_arcsec
    hold = on.step >= 0
    assert np.abs(d[hold & np.roll(hold, 1)]).max() < 1e-9  # inside holds: the same angle
    moving = ~hold & np.roll(~hold, 1) & np.roll(~hold, -1)
    speed_arcsec_per_s = 0.5 * 3600  # the simulator's slew, 0.5°/s
    slewing = moving & (np.abs(np.gradient(on.tilt_y_arcsec)) > 0.9 * speed_arcsec_per_s)
    assert slewing.sum() > 20
    # 0.05 s late on the slope of the slew (the jitter is drawn alike in both)
    lag = -d[slewing] / np.gradient(on.tilt_y_arcsec)[slewing]
    np.testing.assert_allclose(lag, 0.05, atol=1e-3)


def test_the_phase_is_drawn_when_not_given_and_kept_in_the_truth():
    _, truth = _session(4, 1.0, None)
    assert 0.0 <= truth.platform_report_phase_s < 1.0


def test_the_truth_handed_to_the_simulator_is_left_as_it_was():
    """What is drawn (angle errors, hold offsets, the report phase) goes into the returned
    copy; the caller's Truth, and so a second session from it, are unchanged."""
    import dataclasses

    from chekan.demo import demo_program
    from chekan.records.simulate import Truth, simulate_session

    given = Truth(platform_report_period_s=1.0, motion_substeps=2)
    before = dataclasses.asdict(given)
    rec1, drawn = simulate_session(demo_program(quick=True), given, seed=4)
    assert dataclasses.asdict(given) == before
    assert drawn.platform_report_phase_s is not None and drawn.angle_error_arcsec
    rec2, again = simulate_session(demo_program(quick=True), given, seed=4)
    assert dataclasses.asdict(again) == dataclasses.asdict(drawn)
    np.testing.assert_array_equal(rec2.tilt_y_arcsec, rec1.tilt_y_arcsec)


def test_the_validation_case_draws_a_one_second_stream():
    from chekan.study.coverage import CASES
    from chekan.study.scenario import DEFAULT_SCENARIO, session_truth

    assert "late_angles" in CASES
    phases = set()
    for i in range(3):
        t = session_truth("late_angles", np.random.default_rng(i), i, DEFAULT_SCENARIO)
        assert t.platform_report_period_s == 1.0 and t.motion_substeps == 10
        phases.add(t.platform_report_phase_s)
    assert len(phases) == 3 and all(0.0 <= p < 1.0 for p in phases)
    typical = session_truth("typical", np.random.default_rng(0), 0, DEFAULT_SCENARIO)
    assert typical.platform_report_period_s == 0.0 and typical.motion_substeps == 1
    cont = session_truth("continuous", np.random.default_rng(0), 0, DEFAULT_SCENARIO)
    assert cont.motion_substeps == 10 and cont.platform_report_period_s == 0.0


@pytest.fixture(scope="module")
def late_map():
    """MAP of a record whose angles are all 0.05 s late (the simulator's held samples)."""
    from chekan.options import CalibrationOptions
    from chekan.pipeline import calibrate

    rec, truth = _session(3, 1.0, 0.95)
    return calibrate(rec, CalibrationOptions(method="map", progress=False)), truth


@pytest.mark.slow
def test_a_record_whose_slews_open_the_angle_error_mode_is_flagged(late_map):
    res, _ = late_map
    (flag,) = [p for p in res["diagnostics"]["problems"] if "random angle error" in p]
    sigma = res["parameters"]["sigma_theta_arcsec"]["mean"]
    assert sigma > 6.0 and f"σ_θ = {sigma:.3g}″" in flag and "3″ specification" in flag


def test_the_angle_error_flag_reads_the_specification():
    from chekan.results.entries import implausible_angle_error

    assert implausible_angle_error({"sigma_theta_arcsec": 5.9}, 3.0) == []
    (text,) = implausible_angle_error({"sigma_theta_arcsec": 6.5}, 3.0)
    assert "6.5″ is 2.2× the platform's 3″ specification" in text
    assert implausible_angle_error({"sigma_theta_arcsec": 6.5}, 4.0) == []


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="known fragility (README, 'Angles up to a second late'): a slew path the model "
    "misreads (angles interpolated 0.05 s late on held samples) inflates σ_θ to ≈ 16″ and "
    "moves b₁ and b₂ by ≈ 5.7 sd on this record",
)
def test_map_b_holds_when_the_angles_are_a_twentieth_of_a_second_late(late_map):
    res, truth = late_map
    for name, true in zip(("b1", "b2"), truth.b_mgal_per_pix, strict=True):
        p = res["parameters"][name]
        assert abs(p["mean"] - true) < 3 * p["sd"], (name, (p["mean"] - true) / p["sd"])


def test_sub_steps_keep_each_sample_and_converge_to_a_continuous_motion():
    """The reading kept at a sample is the response to the motion followed at Δt/sub: it
    moves from the held-sample one only around the slews, and sub = 10 and 20 agree far
    better than 1 and 10 (the held sample is a first-order error in Δt)."""

    def session(sub: int):
        quiet = ("tilt_jitter_arcsec", "noise_pix")
        return _session(5, 0.0, None, quiet=quiet, motion_substeps=sub)[0]

    held, ten, twenty = session(1), session(10), session(20)
    n = min(len(held.t_s), len(ten.t_s), len(twenty.t_s))
    assert np.array_equal(ten.t_s[:n], np.arange(n, dtype=float))  # every second kept
    d_held = np.abs(ten.m1_pix[:n] - held.m1_pix[:n])
    d_fine = np.abs(twenty.m1_pix[:n] - ten.m1_pix[:n])
    on_slew = np.nonzero(ten.step[:n] < 0)[0]
    assert d_held[on_slew].max() > 10 * d_fine[on_slew].max() > 0


def test_late_reports_on_the_fine_grid_are_the_path_lambda_earlier():
    def session(period: float):  # every report 0.3 s late
        phase = 0.7 if period else None
        return _session(6, period, phase, quiet=("tilt_jitter_arcsec",), motion_substeps=10)

    (on, _), (late, truth) = session(0.0), session(1.0)
    assert truth.platform_report_phase_s == 0.7
    assert np.array_equal(on.m1_pix, late.m1_pix) and np.array_equal(on.step, late.step)
    moving = np.nonzero((on.step < 0) & (np.abs(np.gradient(on.tilt_y_arcsec)) > 1700))[0]
    slope = np.gradient(on.tilt_y_arcsec)[moving]
    lag = (on.tilt_y_arcsec[moving] - late.tilt_y_arcsec[moving]) / slope
    np.testing.assert_allclose(np.median(lag), 0.3, atol=0.02)
