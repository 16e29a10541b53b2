"""Simulated calibration sessions: a realistic 1 Hz record of a whole tilt program.

The readings come from the exact forward model (:mod:`chekan.physics.sensor`) at the *true*
platform attitude, passed through the first-order damping lag, plus a polynomial
drift and white noise. The platform's angle sensor reports the attitude with a
readout error that is constant over each hold and a small jitter; the true attitude is
the commanded one minus that error. The error has a **systematic part**, a fixed
function of the angle repeated in every round (:func:`systematic_angle_error`: periodic
graduation/interpolation errors, a scale error, a zero offset, per-graduation errors; up
to ``angle_systematic_arcsec``, drawn per session from its own random stream), and a
random part per hold (σ = ``angle_error_sd_arcsec``).
Defaults give classical residuals like the paper's (RMS 0.5–1 mGal per column).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

import chekan.jaxconfig  # noqa: F401
from chekan.physics import sensor as fm
from chekan.physics.program import TiltProgram, default_program
from chekan.physics.units import ARCMIN_PER_RAD, ARCSEC_PER_RAD

K_DESIGN_PIX_PER_RAD = 60428.0  # eq. (4): 2nF/δ with n = 1.4, F = 150 mm, δ = 7 µm


@dataclass
class Truth:
    """True parameters of a simulated session (user units at the edges)."""

    serial: str = "SIM-1"
    g_local_mgal: float = 981922.05
    K_pix_per_rad: float = K_DESIGN_PIX_PER_RAD
    m0_pix: float = 1024.0
    b_mgal_per_pix: tuple[float, float] = (6.980, 6.882)
    m_level_pix: tuple[float, float] = (1031.2, 1012.9)
    eps_arcmin: tuple[float, float] = (4.0, -3.0)
    dgamma_arcmin: float = 8.0
    tau_s: float = 30.0
    drift_pix_per_h: tuple[float, float] = (0.04, -0.03)
    drift_pix_per_h2: tuple[float, float] = (0.002, 0.001)
    noise_pix: tuple[float, float] = (0.15, 0.15)
    hold_offset_sd_pix: float = 0.08  # per hold and system (elastic after-effect, thermal)
    angle_error_sd_arcsec: float = 2.0  # random part, per hold
    angle_systematic_arcsec: float = 1.5  # bound of the systematic part (0: none)
    angle_systematic_shape: str = "mixed"  # see SYSTEMATIC_SHAPES
    angle_systematic_peak: tuple[float, float] = (0.4, 1.0)  # max |δ| / bound, drawn in
    # the X sensor (programs with rounds about X): its own systematic bound and random sd
    # (None: as the Y sensor's); each sensor's systematic error is drawn on its own
    angle_systematic_x_arcsec: float | None = None
    angle_error_sd_x_arcsec: float | None = None
    # the axis not tilted in a hold is read by its own sensor, with that sensor's zero
    # error and random error: the platform holds it at −(error) (programs about both axes)
    cross_axis_error: bool | None = None  # None: on for programs about both axes
    # the X rounds' response beyond eq. (6) (fibre sag and the like, which the model does
    # not contain): added to the equilibrium at tilts θ about X, per system, pix at the
    # largest X angle θ_r, with r = sin θ/sin θ_r: odd·((1 − c) r + c r³)
    # + even·((1 − cos θ)/(1 − cos θ_r))² (fibre sag moves the arm's angle: mostly ∝ sin θ;
    # c = x_unmodelled_cubic)
    x_unmodelled_odd_pix: tuple[float, float] = (0.0, 0.0)
    x_unmodelled_even_pix: tuple[float, float] = (0.0, 0.0)
    x_unmodelled_cubic: float = 0.3
    # the reading of each system's horizontal pendulum minus the CCD centre ``m0_pix``,
    # which the record states as m0 (the paper's convention: 0); eq. (6) turns about it
    horizontal_offset_pix: tuple[float, float] = (0.0, 0.0)
    tilt_jitter_arcsec: float = 0.3
    # the platform's angle stream (serial protocol: at least once per second) is not the
    # sensor's clock: a row carries the latest report, up to one period old; 0: on time
    platform_report_period_s: float = 0.0
    platform_report_phase_s: float | None = None  # of the reports in the period; None: drawn
    # the platform's motion and the pendulums followed at this many steps per sample, the
    # record keeping each sample's reading and the angle reported then (10: close to a
    # platform that moves continuously; 1: each sample held over the second before it, as
    # the model has it)
    motion_substeps: int = 1
    slew_deg_per_s: float = 0.5
    platform_settle_s: float = 3.0
    temp_c: float = 45.0
    sample_rate_hz: float = 1.0
    angle_error_arcsec: list[float] = field(default_factory=list)  # per step, drawn if empty
    angle_systematic_per_step_arcsec: list[float] = field(default_factory=list)  # its part
    hold_offset_pix: list[list[float]] = field(default_factory=list)  # per step × system

    def params(self) -> fm.SensorParams:
        """The forward model's parameters; m₀ is each pendulum's horizontal (the CCD centre
        plus ``horizontal_offset_pix``, a scalar where that is zero)."""
        off = np.asarray(self.horizontal_offset_pix, dtype=float)
        return fm.make_params(
            g_mgal=self.g_local_mgal,
            K_pix_per_rad=self.K_pix_per_rad,
            b_mgal_per_pix=self.b_mgal_per_pix,
            m_level_pix=self.m_level_pix,
            eps_rad=np.asarray(self.eps_arcmin) / ARCMIN_PER_RAD,
            gamma_rad=self.dgamma_arcmin / ARCMIN_PER_RAD,
            m0_pix=self.m0_pix + off if off.any() else self.m0_pix,
        )

    def drift_coeffs(self) -> np.ndarray:
        """(2, 2) drift coefficients per system: pix/h and pix/h²."""
        return np.array(
            [
                [self.drift_pix_per_h[0], self.drift_pix_per_h2[0]],
                [self.drift_pix_per_h[1], self.drift_pix_per_h2[1]],
            ]
        )

    def derived(self) -> dict:
        """a, b₀ (at the CCD centre, eq. 24) and the misalignment angles as the result JSON
        names them."""
        off = np.asarray(self.horizontal_offset_pix, dtype=float)
        centre = replace(self, horizontal_offset_pix=(0.0, 0.0)).params()
        at = fm.coefficients_at_horizontal(centre, off if off.any() else 0.0)
        a, b0 = (np.asarray(x) for x in at)
        return {
            "b1": self.b_mgal_per_pix[0],
            "b2": self.b_mgal_per_pix[1],
            "a": float(a.mean()),
            "b1_0": float(b0[0]),
            "b2_0": float(b0[1]),
            "eps1_arcmin": self.eps_arcmin[0],
            "eps2_arcmin": self.eps_arcmin[1],
            "dgamma_arcmin": self.dgamma_arcmin,
        }

    def to_json(self) -> dict:
        d = asdict(self)
        d["format"] = "chekan-truth/1"
        d["parameters"] = self.derived()
        return d


SYSTEMATIC_SHAPES = ("mixed", "periodic", "scale", "graduation", "offset", "none")


def systematic_angle_error(
    shape: str,
    bound_arcsec: float,
    theta_max_rad: float,
    rng: np.random.Generator,
    peak: tuple[float, float] = (0.4, 1.0),
):
    """A systematic angle-sensor error δ(θ) (reported − true, arcsec), fixed for a session.

    Shapes: ``periodic`` (graduation/interpolation errors: two or three sinusoids in θ of
    periods 0.5°–4°), ``scale`` (s·θ), ``graduation`` (independent errors at 20′ nodes,
    linearly interpolated: no smooth shape), ``offset`` (a zero offset), ``mixed`` (a
    random combination of all), ``none``. Scaled so that max |δ| over ±θ_max is
    ``bound_arcsec``·U(``peak``) (the specification bounds it; (0.83, 1) at a 3″ bound is
    a platform at the edge of its specification).
    """
    if shape not in SYSTEMATIC_SHAPES:
        raise ValueError(f"unknown systematic shape {shape!r}; one of {SYSTEMATIC_SHAPES}")
    tmax = max(float(theta_max_rad), 1e-6)
    if shape == "none" or bound_arcsec <= 0:
        return lambda theta: np.zeros_like(np.asarray(theta, dtype=float))
    parts = ("periodic", "scale", "graduation", "offset") if shape == "mixed" else (shape,)
    weights = rng.uniform(0.2, 1.0, len(parts)) if shape == "mixed" else np.ones(1)
    n_per = int(rng.integers(2, 4))
    periods = np.deg2rad(rng.uniform(0.5, 4.0, n_per))
    phases = rng.uniform(0, 2 * np.pi, n_per)
    amps = rng.normal(0, 1, n_per)
    sign = rng.choice([-1.0, 1.0], 2)
    nodes = np.arange(-tmax - np.deg2rad(1 / 3), tmax + np.deg2rad(2 / 3), np.deg2rad(1 / 3))
    node_err = rng.normal(0, 1, nodes.size)

    def raw(theta):
        th = np.asarray(theta, dtype=float)
        out = np.zeros_like(th)
        for w, part in zip(weights, parts, strict=True):
            if part == "periodic":
                comp = sum(
                    a * np.sin(2 * np.pi * th / p + f)
                    for a, p, f in zip(amps, periods, phases, strict=True)
                )
            elif part == "scale":
                comp = sign[0] * th / tmax
            elif part == "graduation":
                comp = np.interp(th, nodes, node_err)
            else:
                comp = sign[1] * np.ones_like(th)
            out = out + w * comp
        return out

    grid = np.linspace(-tmax, tmax, 2001)
    largest = max(float(np.max(np.abs(raw(grid)))), 1e-12)
    gain = bound_arcsec * rng.uniform(*peak) / largest
    return lambda theta: gain * raw(theta)


def session_systematic(truth: Truth, program: TiltProgram, seed: int, axis: str | None = None):
    """The systematic angle error δ(θ) (arcsec) of the ``axis`` sensor (default: the
    program's first) in session ``seed`` of ``truth`` on ``program``: drawn from its own
    stream, so the other draws do not move (a program about one axis uses the first
    stream whichever its axis; the X sensor of a two-axis program the second)."""
    axes = program.tilt_axes
    axis = axis or axes[0]
    theta = np.array([s.theta_rad for s in program.steps if s.axis == axis] or [0.0])
    second = axis == "x" and "y" in axes
    bound = truth.angle_systematic_arcsec
    if axis == "x" and truth.angle_systematic_x_arcsec is not None:
        bound = truth.angle_systematic_x_arcsec
    return systematic_angle_error(
        truth.angle_systematic_shape,
        bound,
        float(np.max(np.abs(theta))),
        np.random.default_rng([seed, 0x5158 if second else 0x5157]),
        truth.angle_systematic_peak,
    )


def random_truth(rng: np.random.Generator, serial: str = "SIM-1", **overrides) -> Truth:
    """Draw a plausible instrument: b ≈ 6.8–7.1 mGal/pix, |ε| ≲ 10′, |Δγ| ≲ 20′, τ 15–60 s."""
    kw: dict[str, Any] = dict(
        serial=serial,
        b_mgal_per_pix=tuple(rng.uniform(6.80, 7.10, 2)),
        m_level_pix=tuple(1024.0 + rng.normal(0, 25, 2)),
        eps_arcmin=tuple(np.clip(rng.normal(0, 4.0, 2), -10, 10)),
        dgamma_arcmin=float(np.clip(rng.normal(0, 8.0), -20, 20)),
        tau_s=float(rng.uniform(15, 60)),
        drift_pix_per_h=tuple(rng.normal(0, 0.05, 2)),
        drift_pix_per_h2=tuple(rng.normal(0, 0.003, 2)),
        noise_pix=tuple(rng.uniform(0.10, 0.25, 2)),
    )
    kw.update(overrides)
    return Truth(**kw)


@dataclass
class Timeline:
    """Sample-by-sample commanded/true attitude and step of a program run."""

    t_s: np.ndarray
    step: np.ndarray  # -1 while moving
    tx_true_rad: np.ndarray
    ty_true_rad: np.ndarray
    tx_read_arcsec: np.ndarray
    ty_read_arcsec: np.ndarray


def program_timeline(
    program: TiltProgram,
    truth: Truth,
    rng: np.random.Generator,
    systematic_arcsec: np.ndarray | None = None,
    systematic_fn=None,
    cross_arcsec: np.ndarray | None = None,
) -> tuple[Timeline, np.ndarray]:
    """Lay the program out at the sample rate: slews between holds, holds of ``dwell_s``.

    The angle error of step k about its own axis is the random draw (or
    ``truth.angle_error_arcsec``) plus ``systematic_arcsec[k]`` when given.
    ``systematic_fn`` (θ rad → arcsec, or a dict axis → such a function): the same
    sensor reads the slews, so their reported angles carry its error too.
    ``cross_arcsec`` (n_steps,): the error of the other axis's sensor in each step (the
    platform then holds that axis at minus it; None: exact)."""
    tl, err, _ = _timeline(program, truth, rng, systematic_arcsec, systematic_fn, cross_arcsec)
    return tl, err


def _timeline(
    program: TiltProgram,
    truth: Truth,
    rng: np.random.Generator,
    systematic_arcsec,
    systematic_fn,
    cross_arcsec,
) -> tuple[Timeline, np.ndarray, float | None]:
    """:func:`program_timeline` and the report phase (s; None: every sample reports)."""
    dt = 1.0 / truth.sample_rate_hz
    n_steps = program.n_steps
    fns = systematic_fn if isinstance(systematic_fn, dict) else None
    err = np.asarray(truth.angle_error_arcsec, dtype=float)
    if err.size == 0:
        if truth.angle_error_sd_x_arcsec is None or len(program.tilt_axes) == 1:
            err = rng.normal(0.0, truth.angle_error_sd_arcsec, n_steps)
        else:
            sd = [_random_sd(truth, s.axis) for s in program.steps]
            err = rng.normal(0.0, 1.0, n_steps) * np.asarray(sd)
        if systematic_arcsec is not None:
            err = err + np.asarray(systematic_arcsec, dtype=float)
    if err.size != n_steps:
        raise ValueError(f"angle_error_arcsec has {err.size} values, program has {n_steps} steps")
    cross = np.zeros(n_steps) if cross_arcsec is None else np.asarray(cross_arcsec, float)
    seg_step, seg_tx, seg_ty, seg_rx, seg_ry = [], [], [], [], []
    prev = (0.0, 0.0)
    prev_axis = program.steps[0].axis if program.steps else "y"
    for k, s in enumerate(program.steps):
        cmd = (s.tilt_x_rad, s.tilt_y_rad)
        dist = max(abs(cmd[0] - prev[0]), abs(cmd[1] - prev[1]))
        if k > 0 and dist > 0:
            n_slew = max(int(np.ceil(np.rad2deg(dist) / truth.slew_deg_per_s / dt)), 1)
            n_move = n_slew + int(np.ceil(truth.platform_settle_s / dt))
            f = np.minimum(np.arange(1, n_move + 1) / n_slew, 1.0)
            mx = prev[0] + f * (cmd[0] - prev[0])
            my = prev[1] + f * (cmd[1] - prev[1])
            seg_step.append(np.full(n_move, -1))
            seg_tx.append(mx)
            seg_ty.append(my)
            ex = ey = 0.0
            moving = s.axis if s.kind == "tilt" else prev_axis  # back to level: the tilt's
            fn = fns.get(moving) if fns is not None else systematic_fn
            if fn is not None:  # reported = true + the sensor's error
                ex, ey = (0.0, fn(my)) if moving == "y" else (fn(mx), 0.0)
            seg_rx.append(mx * ARCSEC_PER_RAD + ex)
            seg_ry.append(my * ARCSEC_PER_RAD + ey)
        n_hold = round(s.dwell_s / dt)
        e = err[k] / ARCSEC_PER_RAD  # readout − true, about the step's own axis
        c = cross[k] / ARCSEC_PER_RAD  # readout − true, about the other axis
        tx_true, ty_true = (cmd[0] - c, cmd[1] - e) if s.axis == "y" else (cmd[0] - e, cmd[1] - c)
        seg_step.append(np.full(n_hold, k))
        seg_tx.append(np.full(n_hold, tx_true))
        seg_ty.append(np.full(n_hold, ty_true))
        seg_rx.append(np.full(n_hold, cmd[0] * ARCSEC_PER_RAD))
        seg_ry.append(np.full(n_hold, cmd[1] * ARCSEC_PER_RAD))
        prev = cmd
        if s.kind == "tilt":
            prev_axis = s.axis
    step = np.concatenate(seg_step)
    n = step.size
    seg_t = np.arange(n) * dt
    rx, ry = np.concatenate(seg_rx), np.concatenate(seg_ry)
    period, phase = truth.platform_report_period_s, truth.platform_report_phase_s
    if period > 0:
        if phase is None:
            phase = float(rng.uniform(0.0, period))
        rx, ry = _latest_reports(period, phase, seg_t, rx, ry)
    rx = rx + rng.normal(0, truth.tilt_jitter_arcsec, n)
    ry = ry + rng.normal(0, truth.tilt_jitter_arcsec, n)
    tl = Timeline(seg_t, step, np.concatenate(seg_tx), np.concatenate(seg_ty), rx, ry)
    return tl, err, phase


def _latest_reports(period_s: float, phase_s: float, t_s: np.ndarray, rx, ry):
    """The angles as a row records them: the platform's latest report at or before each
    sample, its reports every ``period_s`` from ``phase_s`` (the angle path in between is
    the reported path, linear between samples)."""
    t_report = np.maximum(np.floor((t_s - phase_s) / period_s) * period_s + phase_s, t_s[0])
    return np.interp(t_report, t_s, rx), np.interp(t_report, t_s, ry)


def _random_sd(truth: Truth, axis: str) -> float:
    """The random angle error sd (arcsec) of the ``axis`` sensor."""
    if axis == "x" and truth.angle_error_sd_x_arcsec is not None:
        return truth.angle_error_sd_x_arcsec
    return truth.angle_error_sd_arcsec


def _x_unmodelled(truth: Truth, tx_true_rad: np.ndarray, ty_true_rad: np.ndarray, th_r: float):
    """(n, 2) pix: the X response that eq. (6) does not contain (:class:`Truth`)."""
    odd, even = np.asarray(truth.x_unmodelled_odd_pix), np.asarray(truth.x_unmodelled_even_pix)
    if not (odd.any() or even.any()) or th_r <= 0:
        return None
    about_x = np.abs(tx_true_rad) > np.abs(ty_true_rad)
    tx = np.where(about_x, tx_true_rad, 0.0)
    r = np.sin(tx) / np.sin(th_r)
    c = truth.x_unmodelled_cubic
    u = (1.0 - c) * r + c * r**3  # mostly an arm-angle offset (∝ sin θ), partly not
    v = ((1 - np.cos(tx)) / (1 - np.cos(th_r))) ** 2
    return u[:, None] * odd + v[:, None] * even


def simulate_readings(
    truth: Truth, tl: Timeline, rng: np.random.Generator, x_theta_max_rad: float = 0.0
) -> np.ndarray:
    """Readings (n, 2): (equilibrium [+ the unmodelled X response, largest X angle
    ``x_theta_max_rad``] + hold offset) → damping lag → + drift + noise."""
    p = truth.params()
    # solve the equilibrium once per distinct attitude (holds repeat one attitude)
    att = np.stack([tl.tx_true_rad, tl.ty_true_rad], axis=1)
    uniq, inv = np.unique(att, axis=0, return_inverse=True)
    m_eq = np.asarray(fm.equilibrium_readings(p, uniq[:, 0], uniq[:, 1]))[inv.ravel()]
    extra = _x_unmodelled(truth, tl.tx_true_rad, tl.ty_true_rad, x_theta_max_rad)
    if extra is not None:
        m_eq = m_eq + extra
    off = np.asarray(truth.hold_offset_pix, dtype=float).reshape(-1, 2)
    if off.size:  # a per-hold offset settles in with the lag like any equilibrium change
        m_eq = m_eq + np.where(tl.step[:, None] >= 0, off[np.maximum(tl.step, 0)], 0.0)
    dt = np.diff(tl.t_s, prepend=tl.t_s[0])
    m = fm.lag_filter_np(m_eq, dt, truth.tau_s)
    m = m + np.asarray(fm.drift_pix(np.asarray(truth.drift_coeffs()), tl.t_s))
    m = m + rng.normal(0.0, 1.0, m.shape) * np.asarray(truth.noise_pix)
    return m


def simulate_session(
    program: TiltProgram | None = None,
    truth: Truth | None = None,
    seed: int = 0,
    started: str = "2015-07-09T06:00:00Z",
):
    """Simulate a session; returns ``(record, truth)``: a copy of ``truth`` (which is left
    as it was) with what was drawn filled in (angle errors, hold offsets, the report phase)."""
    from chekan.records import Record

    program = program or default_program()
    rng = np.random.default_rng(seed)
    truth = replace(truth or Truth())
    systematic = None
    fns: dict = {}
    axes = program.tilt_axes
    if not truth.angle_error_arcsec:
        fns = {a: session_systematic(truth, program, seed, a) for a in axes}
        theta = np.array([s.theta_rad for s in program.steps])
        systematic = np.array([fns[s.axis](t) for s, t in zip(program.steps, theta, strict=True)])
        truth.angle_systematic_per_step_arcsec = [float(e) for e in systematic]
    cross = None
    if truth.cross_axis_error or (truth.cross_axis_error is None and len(axes) > 1):
        cross = _cross_axis_errors(truth, program, seed, fns)
    sub = int(truth.motion_substeps)
    if sub < 1:
        raise ValueError(f"motion_substeps must be ≥ 1, got {truth.motion_substeps}")
    # the motion at sub steps per sample (the rates in the timeline are the fine ones)
    fine = truth if sub == 1 else replace(truth, sample_rate_hz=truth.sample_rate_hz * sub)
    tl, err, phase = _timeline(
        program,
        fine,
        rng,
        systematic,
        (fns if len(axes) > 1 else fns[axes[0]]) if fns else None,
        cross,
    )
    truth.angle_error_arcsec = [float(e) for e in err]
    truth.platform_report_phase_s = phase
    if not truth.hold_offset_pix:
        off = rng.normal(0.0, truth.hold_offset_sd_pix, (program.n_steps, 2))
        truth.hold_offset_pix = [[float(a), float(b)] for a, b in off]
    x_max = max([abs(s.tilt_x_rad) for s in program.steps if s.axis == "x"] or [0.0])
    m = simulate_readings(truth, tl, rng, x_max)
    n = tl.t_s.size
    temp = truth.temp_c + 0.002 * rng.normal(size=n) + 0.01 * np.sin(2 * np.pi * tl.t_s / 7200.0)
    if sub > 1:  # every sample's reading and the angle reported then
        keep = np.arange(0, n, sub)
        tl = Timeline(*(getattr(tl, f.name)[keep] for f in dataclasses.fields(tl)))
        m, temp = m[keep], temp[keep]
    meta = {
        "format": "chekan-record/1",
        "serial": truth.serial,
        "instrument": "Chekan-AM",
        "model": "Shelf",
        "platform_serial": "SIM-PLATFORM",
        "started": started,
        "g_local_mgal": f"{truth.g_local_mgal:.2f}",
        "site": "simulation",
        "sample_rate_hz": f"{truth.sample_rate_hz:g}",
        "program": program.name,
        "program_dwell_s": f"{program.dwell_s:g}",
        "program_settle_s": f"{program.settle_s:g}",
        "program_steps": str(program.n_steps),
        "ccd_center_pix": f"{truth.m0_pix:g}",
        "ccd_range_pix": "0 2048",
        "b1_prior": f"{truth.b_mgal_per_pix[0] * (1 + 2e-4):.6f}",
        "b2_prior": f"{truth.b_mgal_per_pix[1] * (1 - 3e-4):.6f}",
        "generator": "chekan simulate",
    }
    rec = Record(
        meta=meta,
        t_s=tl.t_s.astype(float),
        m1_pix=m[:, 0],
        m2_pix=m[:, 1],
        tilt_x_arcsec=tl.tx_read_arcsec,
        tilt_y_arcsec=tl.ty_read_arcsec,
        step=tl.step.astype(np.int64),
        temp_c=temp,
    )
    return rec, truth


def _cross_axis_errors(truth: Truth, program: TiltProgram, seed: int, fns: dict) -> np.ndarray:
    """(n_steps,) arcsec: the error of the sensor of the axis a step does not tilt about:
    that sensor's systematic error at zero and its random error (its own stream)."""
    rng = np.random.default_rng([seed, 0x5159])
    out = np.zeros(program.n_steps)
    for k, s in enumerate(program.steps):
        other = "x" if s.axis == "y" else "y"
        fn = fns.get(other)
        zero = float(fn(0.0)) if fn is not None else 0.0
        out[k] = zero + rng.normal(0.0, _random_sd(truth, other))
    return out


def write_truth(path: str | Path, truth: Truth) -> Path:
    from chekan.files.durable import atomic_output

    path = Path(path)
    with atomic_output(path) as f:
        f.write(json.dumps(truth.to_json(), indent=2, ensure_ascii=False) + "\n")
    return path


class Instrument:
    """Sample-by-sample sensor for the emulator: ``sample(t_s, tx, ty)`` → (m1, m2, temp).

    ``tx``, ``ty`` are the TRUE platform angles in radians; ``t_s`` is the sample clock.
    Call :meth:`begin_hold` when the platform starts holding a new target and
    :meth:`end_hold` when it starts moving (per-hold offsets of the quartz systems).

    Keeps the lag state between calls; the equilibrium of the last attitude is cached,
    so a hold costs one solve.
    """

    def __init__(self, truth: Truth | None = None, seed: int = 0):
        self.truth = truth or Truth()
        self._params = self.truth.params()
        self._rng = np.random.default_rng(seed)
        self._drift = np.asarray(self.truth.drift_coeffs())
        self._att: tuple[float, float] | None = None
        self._m_eq = np.asarray(self.truth.m_level_pix, dtype=float)
        self._y: np.ndarray | None = None
        self._t: float | None = None
        self._offset = np.zeros(2)

    def begin_hold(self) -> None:
        """The platform reached a new hold: draw that hold's offset of each system."""
        self._offset = self._rng.normal(0.0, self.truth.hold_offset_sd_pix, 2)

    def end_hold(self) -> None:
        self._offset = np.zeros(2)

    def equilibrium(self, tx_rad: float, ty_rad: float) -> np.ndarray:
        att = (float(tx_rad), float(ty_rad))
        if att != self._att:
            self._m_eq = np.asarray(
                fm.equilibrium_readings(self._params, att[0], att[1]), dtype=float
            )
            self._att = att
        return self._m_eq

    def sample(
        self, t_s: float, tx_true_rad: float, ty_true_rad: float
    ) -> tuple[float, float, float]:
        x = self.equilibrium(tx_true_rad, ty_true_rad) + self._offset
        if self._y is None or self._t is None:
            self._y = x.copy()
        else:
            a = np.exp(-(t_s - self._t) / self.truth.tau_s)
            self._y = x + (self._y - x) * a
        self._t = t_s
        h = t_s / 3600.0
        m = self._y + self._drift[:, 0] * h + self._drift[:, 1] * h * h
        m = m + self._rng.normal(0.0, 1.0, 2) * np.asarray(self.truth.noise_pix)
        temp = self.truth.temp_c + 0.002 * self._rng.normal()
        return float(m[0]), float(m[1]), float(temp)
