"""The running calibration of the live page: classical after every ± pair, MAP per round.

- :func:`classical_snapshot` runs the classical method (Calibr.exe: increments of every
  completed ± pair against the interpolated level, b per round and system, a, δg) on
  the completed holds so far; it takes a few ms and runs in the page's update thread.
- :func:`estimate_map` is the ONE place that calls the joint estimator (its API is
  being refactored: keep every call to it here). :class:`MapRunner` runs it in a
  separate worker process, one job at a time, newest round first, so the JAX work
  never blocks the page (nor, the page being a separate process, the acquisition).
- :func:`expected_sd` is the expected sd at the end of the program (``chekan design``).
"""

from __future__ import annotations

import math
import multiprocessing
import os
import threading
import time
import warnings
from concurrent.futures import Future, ProcessPoolExecutor

import numpy as np

from chekan.records import Record

PARAMS = ("b1", "b2", "a")


def partial_record(
    meta: dict[str, str],
    cols: dict[str, np.ndarray],
    complete: set[int],
    *,
    path: str = "<live>",
) -> Record:
    """A :class:`Record` of the rows so far where only completed steps keep their index;
    ``path`` is the user's file, so that every message of the estimators names it."""
    step = np.asarray(cols["step"], dtype=float)
    ok = np.isin(np.where(np.isfinite(step), step, -1).astype(np.int64), sorted(complete))
    step = np.where(ok & np.isfinite(step), step, -1)
    temp = cols.get("temp_c")
    return Record(
        meta=dict(meta),
        t_s=cols["t_s"],
        m1_pix=cols["m1_pix"],
        m2_pix=cols["m2_pix"],
        tilt_x_arcsec=cols["tilt_x_arcsec"],
        tilt_y_arcsec=cols["tilt_y_arcsec"],
        step=step,
        temp_c=temp if temp is not None and np.isfinite(temp).any() else None,
        path=path,
    )


def _f(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def _fl(a) -> list:
    return [_f(v) if np.ndim(v) == 0 else _fl(v) for v in np.asarray(a, dtype=float)]


def classical_snapshot(record: Record, settle_s: float | None = None) -> dict | None:
    """Classical increments, δg and b of the completed ± pairs; None before the first pair.

    ``a`` is fitted once two angles are paired (with one angle it cannot be told from b)
    and held at 0 until then.
    """
    from chekan.classical import fit as classical
    from chekan.classical.settling import unsettled_hold_means
    from chekan.errors import ChekanError
    from chekan.records.holds import segment_record, settle_of

    settle_s = settle_of(record, settle_s)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            holds = segment_record(record, settle_s=settle_s)
            table = classical.increments_from_holds(holds, record.g_local_mgal)
            paired = np.isfinite(table.x_pix[:, 0, :])
            if not paired.any():
                return None
            a_fixed = None if paired.any(axis=0).sum() >= 2 else 0.0
            # rounds about X are fitted apart; the preview shows what the certificate uses
            res = classical.fit_by_axis(table, a_fixed=a_fixed, preview=True)
            # the preview takes the hold means as settled, as Calibr.exe does
            unsettled = unsettled_hold_means(holds, record, res, a_fixed=a_fixed, preview=True)
    except (ChekanError, ValueError, IndexError, np.linalg.LinAlgError):
        return None
    rounds_done = sum(1 for r in holds.rounds if r.level_before is not None and r.level_after)
    return {
        "hold_axis": {int(k): str(a) for k, a in zip(holds.step, holds.hold_axis, strict=True)},
        "notes": [f"{record.path}: {w}" for w in holds.warnings],
        "unsettled": unsettled.problem if unsettled is not None else None,
        "pairs": int(paired.sum()),
        "rounds_complete": int(rounds_done),
        "rounds": [int(r) for r in res.table.rounds],
        "angles": list(res.table.angle_label),
        "dg_mgal": _fl(res.dg_mgal),  # (R, 2, n)
        "delta_g_mgal": _fl(res.delta_g_mgal),  # (R, 2, n)
        "b": _fl(res.b),  # (R, 2)
        "b_sd": _fl(res.b_sd),
        "b_mean": _fl(res.b_mean),
        "b_mean_sd": _fl(res.b_mean_sd),
        "a": _f(res.a),
        "a_sd": None if res.a_sd is None else _f(res.a_sd),
        "a_fixed": a_fixed is not None,
        "sigma_mgal": _f(res.sigma_mgal),
    }


def estimate_map(record: Record) -> dict:
    """MAP b₁, b₂, a (with sd) of a partial record: the one call into the estimator.

    Goes through :func:`chekan.pipeline.calibrate` (classical → MAP), as ``chekan calibrate
    --method map`` does, on the rows so far in memory (an error names the user's record).
    """
    from chekan.pipeline import CalibrationOptions, calibrate

    result = calibrate(record, CalibrationOptions(method="map", progress=False))
    return {k: result["parameters"][k] for k in PARAMS if k in result.get("parameters", {})}


def _map_job(record: Record, round_no: int) -> dict:
    """Worker-process entry: time the estimate and return a JSON-able snapshot."""
    t0 = time.perf_counter()
    params = estimate_map(record)
    return {
        "round": round_no,
        "samples": int(record.n),
        "t_s": _f(record.t_s[-1]) if record.n else None,
        "seconds": round(time.perf_counter() - t0, 2),
        "params": {
            k: {"mean": _f(v["mean"]), "sd": None if v.get("sd") is None else _f(v["sd"])}
            for k, v in params.items()
        },
    }


def exit_with_parent(parent_pid: int, period_s: float = 1.0) -> None:
    """Worker initialiser: end this process once ``parent_pid`` is no longer its parent.

    A page killed outright (SIGKILL, or SIGTERM without cleanup) cannot shut its pool
    down, and its worker, orphaned in the middle of a MAP, ran on for minutes (found by
    the suite: one stray worker per killed page). A daemon thread checks the parent once
    per ``period_s``.
    """

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(period_s)
        os._exit(0)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


class MapRunner:
    """Runs :func:`estimate_map` in one worker process, the newest request first.

    :meth:`submit` queues a round (a newer one replaces a waiting one); :meth:`poll`
    collects finished snapshots. A failed or killed worker is reported, never raised.
    """

    def __init__(self, job=_map_job):
        self._job = job
        self._pool: ProcessPoolExecutor | None = None
        self._running: tuple[int, Future] | None = None
        self._waiting: tuple[int, Record] | None = None
        self.results: list[dict] = []
        self.errors: list[str] = []
        self.busy_round: int | None = None

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(
                max_workers=1,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=exit_with_parent,
                initargs=(os.getpid(),),
            )
        return self._pool

    def submit(self, round_no: int, record: Record) -> None:
        self._waiting = (round_no, record)
        self._start()

    def _start(self) -> None:
        if self._running is not None or self._waiting is None:
            return
        round_no, record = self._waiting
        self._waiting = None
        try:
            fut = self._executor().submit(self._job, record, round_no)
        except Exception as e:  # a broken pool: start a new one next time
            self.errors.append(f"round {round_no}: {type(e).__name__}: {e}")
            self._drop_pool()
            return
        self._running = (round_no, fut)
        self.busy_round = round_no

    def _drop_pool(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def poll(self) -> bool:
        """Collect a finished job and start the next; True if something changed."""
        if self._running is None:
            self._start()
            return False
        round_no, fut = self._running
        if not fut.done():
            return False
        self._running = None
        self.busy_round = None
        try:
            self.results.append(fut.result())
        except Exception as e:
            self.errors.append(f"round {round_no}: {type(e).__name__}: {e}")
            if "Broken" in type(e).__name__:
                self._drop_pool()
        self._start()
        return True

    def close(self) -> None:
        self._waiting = None
        self._drop_pool()


def program_from_plan(plan: list[dict], name: str = "recorded"):
    """The :class:`~chekan.physics.program.TiltProgram` of a journal's ``run_start`` plan."""
    from chekan.physics.program import Step, TiltProgram
    from chekan.physics.units import ARCSEC_PER_RAD

    steps = []
    mags: list[float] = []
    axis = "y"
    for d in plan:
        x, y = float(d["x_arcsec"]) / ARCSEC_PER_RAD, float(d["y_arcsec"]) / ARCSEC_PER_RAD
        tilt = d["kind"] != "level"
        th = y if x == 0.0 else x
        if tilt and x != 0.0:
            axis = "x"
        ai = -1
        if tilt:
            m = abs(th)
            hit = [i for i, v in enumerate(mags) if abs(v - m) < 1e-9]
            if not hit:
                mags.append(m)
            ai = hit[0] if hit else len(mags) - 1
        steps.append(
            Step(
                int(d["index"]),
                int(d["round"]),
                "tilt" if tilt else "level",
                ai,
                int(np.sign(th)) if tilt else 0,
                x,
                y,
                float(d["dwell_s"]),
                float(d["settle_s"]),
            )
        )
    return TiltProgram(
        name=name,
        angles_rad=tuple(mags),
        axis=axis,
        order="as-recorded",
        sequence="as-recorded",
        dwell_s=float(plan[0]["dwell_s"]) if plan else 0.0,
        settle_s=float(plan[0]["settle_s"]) if plan else 0.0,
        rounds=max((int(d["round"]) for d in plan), default=0),
        steps=tuple(steps),
    )


def expected_sd(program) -> dict | None:
    """Expected sd of b₁, b₂, a at the end of ``program`` (``chekan design``'s model)."""
    try:
        from chekan.design import expected_precision

        prec = expected_precision(program)
    except Exception as e:  # the page shows it without the design figure
        return {"error": f"{type(e).__name__}: {e}"}
    return {k: _f(prec.sd[k]) for k in PARAMS if k in prec.sd}
