"""Issue 30: acquisition of programs about both platform axes on the built-in emulator,
the emulator's X geometry and its two angle sensors' errors."""

from __future__ import annotations

import json
import signal

import numpy as np
import pytest

from chekan.physics import sensor as fm
from chekan.physics.program import build_program
from chekan.physics.units import ARCSEC_PER_RAD
from chekan.records import read_record
from chekan.records.simulate import Truth
from hw import anglesensors
from hw.acquisition import Acquisition, Options, PlanStep, acquire, resume
from hw.emulator import InProcessEmulator, PlatformModel
from hw.journal import journal_path, read_journal
from hw.progress import Progress, format_progress

DWELL = 30
XY = build_program([1.0, 2.0], axis="xy", dwell_s=DWELL, settle_s=10, rounds=2, name="xy")
# quiet, fast instrument: a hold's last readings are its equilibrium within 0.01 pix
QUIET = Truth(
    tau_s=1.0,
    noise_pix=(0.002, 0.002),
    hold_offset_sd_pix=0.0,
    drift_pix_per_h=(0.0, 0.0),
    drift_pix_per_h2=(0.0, 0.0),
)


def _opts(emu) -> Options:
    return Options(sensor_url=emu.sensor_url, platform_url=emu.platform_url, timeout_s=2.0)


def _tilts(events) -> list[tuple[float, float]]:
    """The emulator's TILT commands, (x, y) arcsec."""
    out = []
    for _, what in events:
        if what.startswith("TILT ") and "ERR" not in what:
            x, y = what.split()[1:]
            out.append((float(x), float(y)))
    return out


def _rows(rec, k: int) -> np.ndarray:
    return np.flatnonzero(rec.step == k)


@pytest.fixture(scope="module")
def xy_run(tmp_path_factory):
    """The "xy" program (rounds about Y, then X) acquired on the emulator."""
    d = tmp_path_factory.mktemp("xy")
    with InProcessEmulator("axes-xy", speed=0, seed=4, truth=QUIET) as emu:
        s = acquire(d / "rec.csv", XY, _opts(emu), g_local_mgal=981922.05)
        holds = list(emu.emulator.platform.holds)
        events = list(emu.emulator.events)
    return d / "rec.csv", s, holds, events


def test_xy_program_records_holds_about_each_axis(xy_run):
    path, s, holds, events = xy_run
    assert (s.exit_code, s.steps_done, s.levelled) == (0, XY.n_steps, True), s.message
    rec = read_record(path)
    for st in XY.steps:
        rows = _rows(rec, st.index)
        assert rows.size == DWELL, st
        x, y = rec.tilt_x_arcsec[rows], rec.tilt_y_arcsec[rows]
        # each sensor reads its own axis: the commanded angle about the step's axis, 0 on
        # the other (± its jitter, 0.3″)
        assert np.abs(x - st.tilt_x_arcsec).max() < 1.5, st
        assert np.abs(y - st.tilt_y_arcsec).max() < 1.5, st
        if st.kind == "tilt":
            assert abs(st.tilt_x_arcsec if st.axis == "x" else st.tilt_y_arcsec) >= 3600
    assert {st.axis for st in XY.steps if st.kind == "tilt"} == {"x", "y"}
    # the platform was commanded about one axis at a time (rounds meet at level)
    tilts = _tilts(events)
    assert len(tilts) == XY.n_steps and all(x == 0.0 or y == 0.0 for x, y in tilts)
    assert all(h.target_arcsec[0] == 0.0 or h.target_arcsec[1] == 0.0 for h in holds)
    journal = read_journal(journal_path(path))
    plan = next(e for e in journal if e["event"] == "run_start")["plan"]
    assert [p["axis"] for p in plan] == [st.axis for st in XY.steps]
    starts = [e for e in journal if e["event"] == "step_start"]
    assert [e["axis"] for e in starts] == [st.axis for st in XY.steps]
    assert not any(e.get("reason") == "via level" for e in journal)


def test_x_tilts_reach_the_instrument_through_the_full_geometry(xy_run):
    """The sensor's readings at every hold are the forward model's equilibrium at the TRUE
    (tx, ty) that the emulator held (commanded minus each sensor's error), X holds included:
    no Y-only shortcut (at 2° about X the readings differ from those at 2° about Y by ~13 pix)."""
    path, _s, holds, _ = xy_run
    rec = read_record(path)
    params = QUIET.params()
    by_target = {h.target_arcsec: h for h in holds}  # each target of XY is held once
    for st in XY.steps:
        if st.kind != "tilt":
            continue
        h = by_target[(st.tilt_x_arcsec, st.tilt_y_arcsec)]
        tx, ty = (v / ARCSEC_PER_RAD for v in h.true_arcsec)
        want = np.asarray(fm.equilibrium_readings(params, tx, ty))
        rows = _rows(rec, st.index)[-10:]
        got = np.array([rec.m1_pix[rows].mean(), rec.m2_pix[rows].mean()])
        assert np.abs(got - want).max() < 0.01, (st, got, want)
        swapped = np.asarray(fm.equilibrium_readings(params, ty, tx))
        if abs(st.theta_rad) > np.deg2rad(1.5):
            assert np.abs(got - swapped).max() > 5.0


def test_up_vector_follows_the_record_format_geometry():
    """u = (−sin ty·cos tx, sin tx, cos ty·cos tx): Δu_z = −u_x·sin ε + (u_z − 1)·cos ε and
    u_y of system 1 (γ = 0) for tilts about X, Y and both."""
    eps = np.array([0.01, -0.02])
    for tx, ty in ((0.07, 0.0), (0.0, -0.08), (0.05, 0.03)):
        du_z, u_y, _ = fm.up_vector_deviation(tx, ty, 0.0, eps)
        ux, uy, uz = -np.sin(ty) * np.cos(tx), np.sin(tx), np.cos(ty) * np.cos(tx)
        want = -ux * np.sin(eps) + (uz - 1.0) * np.cos(eps)
        np.testing.assert_allclose(np.asarray(du_z), want, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(np.asarray(u_y), [uy, -uy], rtol=1e-12, atol=1e-15)


class _Killed(Acquisition):
    """A run that dies without levelling the platform (as kill -9 leaves it)."""

    def _level(self) -> None:
        pass


def _step(i: int, kind: str, x: float, y: float, axis: str) -> PlanStep:
    label = "level" if kind == "level" else f"{x or y:+g}″"
    return PlanStep(i, 1, kind, label, x, y, float(DWELL), 10.0, axis)


def test_axis_change_goes_through_level_also_on_resume(tmp_path):
    """A plan that changes axis without a level step between (Y → X → Y), killed right
    after its X step with the platform left tilted about X: the run and its resume slew
    between the axes only through level, and the record is complete."""
    plan = [
        _step(0, "level", 0.0, 0.0, "y"),
        _step(1, "tilt", 0.0, 3600.0, "y"),
        _step(2, "tilt", 7200.0, 0.0, "x"),
        _step(3, "tilt", 0.0, -3600.0, "y"),
        _step(4, "level", 0.0, 0.0, "y"),
    ]
    path = tmp_path / "rec.csv"

    def kill_after_x_step(p) -> None:
        if p.step == 2 and p.phase == "done":
            raise KeyboardInterrupt

    with InProcessEmulator("axes-resume", speed=0, seed=6) as emu:
        first = _Killed(
            path,
            plan,
            _opts(emu),
            program_name="cross",
            meta={"g_local_mgal": "981922.05"},
            progress=kill_after_x_step,
        ).run()
        assert first.status == "interrupted" and first.steps_done == 3
        assert emu.emulator.platform.target == (7200.0, 0.0)  # left tilted about X
        n_tilts = len(_tilts(emu.emulator.events))
        s = resume(path, report=None)
        events = list(emu.emulator.events)
        holds = list(emu.emulator.platform.holds)
    assert (s.exit_code, s.steps_done, s.levelled) == (0, 5, True), s.message
    tilts = _tilts(events)
    # step 0, 1, level on the way from Y to X, step 2; killed; level on the way back, 3, 4
    assert tilts[:n_tilts] == [(0.0, 0.0), (0.0, 3600.0), (0.0, 0.0), (7200.0, 0.0)]
    assert tilts[n_tilts:] == [(0.0, 0.0), (0.0, -3600.0), (0.0, 0.0)]
    assert all(h.target_arcsec[0] == 0.0 or h.target_arcsec[1] == 0.0 for h in holds)
    journal = read_journal(journal_path(path))
    via = [e["step"] for e in journal if e["event"] == "tilt" and e["reason"] == "via level"]
    assert via == [2, 3]
    assert [e["from_step"] for e in journal if e["event"] == "resume"] == [3]
    rec = read_record(path)
    for st in plan:
        rows = _rows(rec, st.index)
        assert rows.size == DWELL, st
        assert np.abs(rec.tilt_x_arcsec[rows] - st.x_arcsec).max() < 1.5
        assert np.abs(rec.tilt_y_arcsec[rows] - st.y_arcsec).max() < 1.5
    # no sample, moving or held, shows the platform tilted about both axes at once
    x, y = rec.tilt_x_arcsec, rec.tilt_y_arcsec
    both = (np.abs(x) > 60) & (np.abs(y) > 60)
    assert not both.any()


def test_old_journal_plan_without_axis_reads():
    d = {"index": 3, "round": 2, "kind": "tilt", "label": "+1°", "x_arcsec": 3600.0}
    d |= {"y_arcsec": 0.0, "dwell_s": 60.0, "settle_s": 20.0}
    assert PlanStep.from_json(d).axis == "x"
    assert PlanStep.from_json(d | {"x_arcsec": 0.0, "y_arcsec": -3600.0}).axis == "y"


# ---------------------------------------------------------------------- angle sensors


def test_default_sensors_each_a_periodic_and_a_scale_error_inside_the_bound():
    s = anglesensors.default_sensors()
    grid = np.linspace(-6 * 3600.0, 6 * 3600.0, 2001)
    curves = {}
    for axis in ("x", "y"):
        sen = s.sensor(axis)
        d = sen.systematic(grid)
        assert 1.0 < np.abs(d).max() <= anglesensors.BOUND_ARCSEC
        assert sen.amp > 0 and sen.scale_ppm != 0 and sen.sd > 0 and sen.jitter > 0
        # not a polynomial: a cubic leaves the periodic part (> 0.5″ RMS)
        resid = d - np.polyval(np.polyfit(grid, d, 3), grid)
        assert np.sqrt(np.mean(resid**2)) > 0.5
        curves[axis] = d
    assert np.abs(curves["x"] - curves["y"]).max() > 1.0  # each sensor its own
    assert anglesensors.default_sensors() == s  # fixed: no draw


def test_random_sensors_are_seeded_and_inside_the_bound():
    for seed in range(20):
        s = anglesensors.random_sensors(seed)
        assert s == anglesensors.random_sensors(seed)
        for sen in (s.x, s.y):
            assert sen.max_systematic_arcsec() <= anglesensors.BOUND_ARCSEC
    assert anglesensors.random_sensors(1) != anglesensors.random_sensors(2)


def _hold_at(pm: PlatformModel, t: float, x: float, y: float) -> float:
    pm.command(t, x, y)
    t += 1000.0
    assert pm.update(t, False) == ["HOLD"]
    return t


@pytest.mark.parametrize("name", ["default", "none"])
def test_true_attitude_is_commanded_minus_each_sensors_error(name):
    """At a hold about Y the Y sensor reads the command and the true angle is command − δy −
    e_y; the X axis sits at −δx(0) − e_x (its own offset and random error): statistically
    over 400 holds, and the same holds again for the same seed."""
    truth = Truth()
    sensors = anglesensors.parse(name)
    runs = []
    for _ in range(2):
        pm = PlatformModel(truth, np.random.default_rng(11), sensors)
        t, rows = 0.0, []
        for k in range(400):
            x, y = (0.0, 9000.0) if k % 2 else (-12000.0, 0.0)
            t = _hold_at(pm, t, x, y)
            assert pm.reading(t) == (x, y)
            tx, ty = pm.true_attitude(t)
            rows.append((x, y, tx, ty))
        runs.append(np.array(rows))
    assert np.array_equal(runs[0], runs[1])
    r = runs[0]
    for about_y in (True, False):
        sel = (r[:, 1] != 0) if about_y else (r[:, 0] != 0)
        x, y, tx, ty = r[sel].T
        dx = sensors.x.systematic_arcsec(x[0])
        dy = sensors.y.systematic_arcsec(y[0])
        for err, sys_part, sd in ((x - tx, dx, sensors.x.sd), (y - ty, dy, sensors.y.sd)):
            assert abs(err.mean() - sys_part) < 4 * sd / np.sqrt(err.size)
            assert 0.8 * sd < err.std() < 1.2 * sd
        if name == "none":
            assert dx == dy == 0.0
        else:
            assert abs(dy if about_y else dx) > 0.5 and abs(dx if about_y else dy) > 0.2
    assert pm.holds[-1].systematic_arcsec == pm.sys_err


def test_parse_changes_one_number_and_refuses_bad_items():
    s = anglesensors.parse("none;x.scale_ppm=40 y.sd=1.5")
    assert (s.x.scale_ppm, s.x.amp, s.y.sd, s.y.amp) == (40.0, 0.0, 1.5, 0.0)
    assert anglesensors.parse("y.amp=0").y.amp == 0.0
    assert anglesensors.parse("y.amp=0").x == anglesensors.default_sensors().x
    assert anglesensors.parse("random", seed=3) == anglesensors.random_sensors(3)
    for bad, why in (
        ("bogus", "first item"),
        ("x.foo=1", "unknown field"),
        ("z.amp=1", "AXIS.FIELD"),
        ("x.amp=-1", "negative"),
        ("y.period_deg=0", "positive"),
        ("y.scale_ppm=nan", "finite"),
        ("none;default", "AXIS.FIELD"),
    ):
        with pytest.raises(ValueError, match=why):
            anglesensors.parse(bad)


def test_emulate_angle_errors_option(tmp_path, capsys):
    from hw.cli import main

    handler = signal.getsignal(signal.SIGTERM)
    try:
        assert main(["emulate", "--angle-errors", "x.amp=oops", "--duration-s", "0"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "x.amp=oops" in err[0]
        truth = tmp_path / "t.json"
        argv = ["emulate", "--sensor", str(tmp_path / "s"), "--platform", str(tmp_path / "p")]
        argv += ["--duration-s", "0.3", "--truth", str(truth), "--angle-errors", "none;y.amp=1"]
        assert main(argv) == 0
    finally:
        signal.signal(signal.SIGTERM, handler)
    out = capsys.readouterr().out
    assert "angle sensors (none, changed): X 0″·sin" in out
    d = json.loads(truth.read_text())
    assert d["angle_sensors"]["y"]["amp"] == 1.0 and d["angle_sensors"]["x"]["amp"] == 0.0
    h = d["holds"][0]
    assert h["target_arcsec"] == [0.0, 0.0] and len(h["systematic_arcsec"]) == 2
    assert h["systematic_arcsec"][1] == pytest.approx(1.0 * np.sin(0.0))
    assert np.allclose(np.subtract(h["target_arcsec"], h["readout_error_arcsec"]), h["true_arcsec"])


def test_acquire_command_runs_an_xy_program_without_warning(tmp_path, capsys):
    """``chekan acquire --program`` with ``axis = "xy"``: no warning, every step recorded
    about its own axis; the progress line names the axis."""
    from hw.cli import main

    prog = tmp_path / "xy.toml"
    prog.write_text(
        'name = "xy"\nangles = ["1°"]\naxis = "xy"\ndwell_s = 20\nsettle_s = 5\nrounds = 2\n',
        encoding="utf-8",
    )
    rec = tmp_path / "rec.csv"
    handler = signal.getsignal(signal.SIGTERM)
    try:
        with InProcessEmulator("axes-cli", speed=0, seed=2) as emu:
            code = main(
                ["acquire", "--sensor", emu.sensor_url, "--platform", emu.platform_url,
                 "--out", str(rec), "--program", str(prog), "--g-local-mgal", "981922.05"]
            )  # fmt: skip
    finally:
        signal.signal(signal.SIGTERM, handler)
    out, err = capsys.readouterr()
    assert code == 0, out + err
    assert "warning" not in err.lower() and "refuse" not in (out + err)
    assert "about Y and X (alternate rounds)" in out and "steps      8/8 done" in out
    line = format_progress(Progress(6, 8, 2, "+1°00'", "dwell", 3, 20, 99.0, 60.0, 99, 0, 0, "x"))
    assert "round 2 +1°00' X dwell" in line  # the status line names the step's axis
    r = read_record(rec)
    x_rows = np.isin(r.step, [5, 6])  # round 2: level, +1°, −1°, level
    assert np.allclose(np.abs(r.tilt_x_arcsec[x_rows]), 3600, atol=1.5)
    assert np.abs(r.tilt_y_arcsec[x_rows]).max() < 1.5
