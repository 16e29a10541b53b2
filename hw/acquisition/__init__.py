"""The acquisition: a tilt program on the platform, every sensor sample to a record.

For each program step it sends ``TILT``, waits for a ``HOLD`` at the target
(reported after the command's reply, within ``angle_tol_arcsec``), then counts
the dwell in SENSOR SAMPLES: ``round(dwell_s × rate)`` sample periods from the
first sample after the hold, on the sample clock (``t_s`` comes from ``seq``
through its wrap; a jump in ``seq`` is a gap and ``t_s`` jumps with it). Every
sample is recorded, also while the platform moves (``step`` empty), with the
latest platform angles (empty when no ``PLT`` came for ``stale_s``). The record
starts with the first sample after the first ``PLT``; the first row of each
session (new or resumed) never belongs to a dwell, so a resumed step's new run
is always a separate contiguous run. A dwell is one uninterrupted run of rows:
a gap (lost samples), platform statuses gone stale or a lost hold cut it, the
first row after the cut carries no step, and the dwell is served again in full,
settling included, until the step's last run of rows spans the whole dwell with
no gap (lost samples are counted, journaled and in the summary; a step cut
``max_dwell_cuts`` times gives up, exit 3).

Faults: silence longer than ``timeout_s`` (or a read error) reopens the port with
back-off, up to ``give_up_s`` without data (exit 3). A platform ``FAULT`` re-sends
the step's ``TILT`` and restarts its dwell at the next ``HOLD`` (the interrupted
run stays in the record). ``TILT,ERR`` stops the run (exit 1). At the end, on an
error and on Ctrl-C (exit 130) the platform is levelled. :func:`resume` continues
a killed or interrupted run from its journal and record.

Modules (one job each)::

    plan      PlanStep, plan_from_program, Options, exit codes
    summary   Summary: the outcome of a session and its printed table
    clock     SampleClock: seq → t_s through the wrap, gaps and duplicates
    steps     StepMachine and its Phase: TILT, HOLD, dwell, FAULT, levelling
    links     LinkSupervisor: open, watch, reconnect with back-off, retried queries
    recorder  Recorder: record rows, journal events, raw log
    runner    Acquisition: one session wiring the parts together
    start     acquire: a new run (record, metadata and g checked)
    resume    resume_state / resume: continue a killed or interrupted run
"""

from hw.acquisition.clock import BACKWARDS_WINDOW, Anchor, SampleClock
from hw.acquisition.plan import (
    EXIT_CONFIG,
    EXIT_DEVICE,
    EXIT_GAVE_UP,
    EXIT_INTERRUPTED,
    EXIT_OK,
    Options,
    PlanStep,
    plan_from_program,
)
from hw.acquisition.resume import ResumeState, resume_state
from hw.acquisition.runner import Acquisition
from hw.acquisition.start import PROTECTED_META, acquire, resume
from hw.acquisition.steps import Phase, StepMachine
from hw.acquisition.summary import PORTS, Summary

__all__ = [
    "BACKWARDS_WINDOW",
    "EXIT_CONFIG",
    "EXIT_DEVICE",
    "EXIT_GAVE_UP",
    "EXIT_INTERRUPTED",
    "EXIT_OK",
    "PORTS",
    "PROTECTED_META",
    "Acquisition",
    "Anchor",
    "Options",
    "Phase",
    "PlanStep",
    "ResumeState",
    "SampleClock",
    "StepMachine",
    "Summary",
    "acquire",
    "plan_from_program",
    "resume",
    "resume_state",
]
