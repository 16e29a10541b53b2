"""Gaps in a record (lost samples): where the sensor's state is unknown, the model does not
use the samples until it has settled, and a gap costs only about the information it removed.

The validation runs on sessions that the joint model did not generate: the platform moves
continuously between the samples and its angle reports lag the sensor's clock (effects the
model leaves out), cut at places of every kind (in a slew, across a whole hold, at the start
of a hold, inside a hold), and compares with the whole record's estimate and with the truth.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from chekan.physics.program import TiltProgram, load_program
from chekan.records import Record
from chekan.records.holds import GAP_HOLDING_S, known_state, segment_record
from chekan.records.simulate import Truth, simulate_session

SHORT = """angles = ["2°30'", "4°10'", "5°10'"]
axis = "y"
order = "+-"
sequence = "ascending"
dwell_s = 240
settle_s = 150
rounds = 2
"""


def cut(rec: Record, t_from: float, t_to: float) -> Record:
    """``rec`` without its samples at t_from ≤ t ≤ t_to (a stretch lost in acquisition)."""
    return rec.rows((rec.t_s < t_from) | (rec.t_s > t_to))


def _known(t, start, stop, settle_s=10.0, ok=None):
    """The rows' known state (None: known everywhere)."""
    t = np.asarray(t, float)
    ok = np.ones(t.size, bool) if ok is None else ok
    state = known_state(t, ok, np.asarray(start), np.asarray(stop), settle_s, 1.0)
    return None if state is None else state[0]


def test_a_gapless_record_has_its_state_known_everywhere() -> None:
    t = np.arange(60.0)
    assert _known(t, [0, 25], [20, 60]) is None


def test_a_gap_in_a_slew_hides_the_next_holds_start_until_it_settles() -> None:
    t = np.concatenate([np.arange(0.0, 22.0), np.arange(30.0, 70.0)])  # 23…29 lost
    start, stop = np.array([0, 24]), np.array([20, t.size])  # hold 1 from t = 32
    known = _known(t, start, stop)
    assert known is not None
    hold1 = t[24:]
    assert np.array_equal(known[24:], hold1 >= 32.0 + 10.0)
    assert known[:24].all()


def test_a_slew_sample_without_angles_is_a_gap_of_the_attitude() -> None:
    t = np.arange(60.0)
    ok = np.ones(60, bool)
    ok[22] = False  # a slew row whose angles were not read
    known = _known(t, [0, 25], [20, 60], ok=ok)
    assert known is not None and not known[25:35].any() and known[35:].all()


def test_a_short_gap_inside_a_hold_loses_only_its_samples() -> None:
    # the longest gap (between the samples either side) that leaves the state known
    t = np.concatenate([np.arange(0.0, 40.0), np.arange(39.0 + GAP_HOLDING_S, 80.0)])
    assert _known(t, [0, 25], [20, t.size]) is None
    longer = np.concatenate([np.arange(0.0, 40.0), np.arange(40.0 + GAP_HOLDING_S, 80.0)])
    assert _known(longer, [0, 25], [20, longer.size]) is not None


def test_a_long_gap_inside_a_hold_hides_the_state_after_it() -> None:
    t = np.concatenate([np.arange(0.0, 40.0), np.arange(60.0, 100.0)])
    known = _known(t, [0, 25], [20, t.size])
    assert known is not None
    after = t[40:]
    assert np.array_equal(known[40:], after >= 70.0) and known[:40].all()


def test_a_hold_whose_start_was_hidden_and_never_settles_hides_the_next_holds_start() -> None:
    # hold 1's slew is lost (rows 20… to t = 50) and hold 1 ends 4 s later: never settled
    t = np.concatenate([np.arange(0.0, 21.0), np.arange(50.0, 90.0)])
    start, stop = np.array([0, 21, 27]), np.array([19, 26, t.size])
    state = known_state(t, np.ones(t.size, bool), start, stop, 10.0, 1.0)
    assert state is not None
    known, fresh = state
    assert fresh.tolist() == [False, True, True]
    assert not known[21:26].any()
    hold2 = t[27:]
    assert np.array_equal(known[27:], hold2 >= hold2[0] + 10.0)


def test_a_gap_inside_a_seen_hold_leaves_the_next_holds_start_known() -> None:
    """The platform holds its target through a gap inside a hold whose slew was seen: the
    next hold's slew is seen too, so it starts from that hold's equilibrium."""
    t = np.concatenate([np.arange(0.0, 24.0), np.arange(50.0, 90.0)])
    start, stop = np.array([0, 22, 28]), np.array([20, 27, t.size])
    state = known_state(t, np.ones(t.size, bool), start, stop, 10.0, 1.0)
    assert state is not None
    known, fresh = state
    assert fresh.tolist() == [False, False, False]
    assert known[22:24].all() and not known[24:27].any() and known[28:].all()


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A short program (3 angles, 2 rounds, 1.6 h) simulated richer than the model."""
    path = tmp_path_factory.mktemp("gaps") / "short.toml"
    path.write_text(SHORT, encoding="utf-8")
    program: TiltProgram = load_program(path)
    truth = Truth(serial="GAP-1", motion_substeps=10, platform_report_period_s=1.0)
    return simulate_session(program, truth, seed=41)


def _hold_times(rec: Record) -> dict[int, tuple[float, float]]:
    out = {}
    for s in np.unique(rec.step[rec.step >= 0]):
        t = rec.t_s[rec.step == s]
        out[int(s)] = (float(t[0]), float(t[-1]))
    return out


def test_the_settled_hold_means_leave_out_the_unknown_state(session) -> None:
    rec, _ = session
    hold = _hold_times(rec)
    t0 = hold[8][0]
    gapped = cut(rec, t0 + 20.0, t0 + 50.0)  # 31 s lost inside hold 8 (240 s)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        holds = segment_record(gapped, settle_s=150.0)
    assert any("gap" in str(w.message) and "not used" in str(w.message) for w in caught)
    k = int(np.flatnonzero(holds.step == 8)[0])
    used = gapped.t_s[holds.start[k] : holds.stop[k]][holds.settled(k, gapped.t_s)]
    assert used.size and used.min() >= t0 + 51.0 + 150.0
    assert holds.gaps == [(t0 + 19.0, t0 + 51.0)]
    assert not holds.restarted(k) and not holds.restarted(k + 1)  # its slew was seen


@pytest.fixture(scope="module")
def fits(session):
    """MAP of the whole record and of records cut at places of every kind."""
    from chekan.pipeline import CalibrationOptions, calibrate

    rec, truth = session
    hold = _hold_times(rec)
    cuts = {
        "whole": None,
        "a slew and a whole hold": (hold[9][1] - 12.0, hold[11][0] + 43.0),
        "a slew": (hold[5][1] + 2.0, hold[6][0] + 3.0),
        "the start of a hold": (hold[7][0] - 1.0, hold[7][0] + 100.0),
        "inside a hold": (hold[8][0] + 180.0, hold[8][0] + 215.0),
        "a few samples inside a hold": (hold[3][0] + 50.0, hold[3][0] + 53.0),
    }
    opts = CalibrationOptions(method="map", progress=False)
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, span in cuts.items():
            out[name] = calibrate(rec if span is None else cut(rec, *span), opts)
    return out, truth


def test_a_gap_costs_about_the_information_it_removed(fits) -> None:
    """Before, a slew and a hold lost (the case a kill -9 and --resume leave) gave b₁ 0.9
    mGal/pix off with an sd 100× the whole record's: the model took the gap for a slew."""
    res, truth = fits
    whole = res["whole"]["parameters"]
    for name, r in res.items():
        p = r["parameters"]
        for j in (1, 2):
            b, sd = p[f"b{j}"]["mean"], p[f"b{j}"]["sd"]
            z = (b - truth.b_mgal_per_pix[j - 1]) / sd
            assert abs(z) < 3.0, (name, j, b, sd, z)
            assert abs(b - whole[f"b{j}"]["mean"]) < 2.0 * whole[f"b{j}"]["sd"], (name, j)
            assert sd < 1.3 * whole[f"b{j}"]["sd"], (name, j, sd, whole[f"b{j}"]["sd"])
        assert r["diagnostics"]["converged"], name
        assert p["sigma_theta_arcsec"]["mean"] < 4.0, (name, p["sigma_theta_arcsec"])
