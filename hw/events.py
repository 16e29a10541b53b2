"""The acquisition journal's events: their names and fields, for the writers
(:mod:`hw.acquisition`) and the readers (resume, the live page, :mod:`chekan.live.state`).

Every journal line is ``{"event": NAME, "utc": ISO 8601, **fields}`` (:class:`hw.journal.
Journal`); the names below are the on-disk values and never change (old journals resume).
"""

from __future__ import annotations

import enum
from types import MappingProxyType


class Event(enum.StrEnum):
    """A journal event's name (a ``str``: it compares equal to the name read from disk)."""

    RUN_START = "run_start"
    RESUME = "resume"
    SYNC = "sync"
    GAP = "gap"
    STEP_START = "step_start"
    TILT = "tilt"
    HOLD = "hold"
    HOLD_LOST = "hold_lost"
    HOLD_TIMEOUT = "hold_timeout"
    FAULT = "fault"
    STEP_DONE = "step_done"
    SENSOR_STATUS = "sensor_status"
    LINK_LOST = "link_lost"
    RECONNECT = "reconnect"
    REPLY_TIMEOUT = "reply_timeout"
    REPLY_LOST_COMMAND_OBEYED = "reply_lost_command_obeyed"
    LEVEL = "level"
    LEVELLED = "levelled"
    LEVEL_UNCONFIRMED = "level_unconfirmed"
    LEVEL_FAILED = "level_failed"
    LEVEL_INTERRUPTED = "level_interrupted"
    RUN_STOP = "run_stop"


#: The fields each event carries besides ``event`` and ``utc`` (``t_s``: the record's time).
FIELDS = MappingProxyType(
    {
        Event.RUN_START: ("record", "program", "plan", "rate_hz", "sensor", "platform", "options"),
        Event.RESUME: ("from_step", "steps_done", "last_t_s", "torn_saved_to", "options"),
        Event.SYNC: ("seq_ref", "t_ref", "resumed"),
        Event.GAP: ("seq_from", "seq_to", "lost", "t_s_from", "t_s_to", "step", "resumed?"),
        Event.STEP_START: (
            *("step", "round", "kind", "label", "axis", "x", "y", "dwell_samples", "t_s"),
        ),
        Event.TILT: ("step", "x", "y", "reason", "t_s"),
        Event.HOLD: ("step", "t_s", "angles"),
        Event.HOLD_LOST: ("step", "state", "t_s", "samples", "lost?"),
        Event.HOLD_TIMEOUT: ("step", "t_s"),
        Event.FAULT: ("step", "t_s", "angles"),
        Event.STEP_DONE: ("step", "t_s_first", "t_s_last", "samples", "lost"),
        Event.SENSOR_STATUS: ("status", "was", "t_s"),
        Event.LINK_LOST: ("port", "reason", "t_s"),
        Event.RECONNECT: ("port", "attempts", "down_s", "t_s"),
        Event.REPLY_TIMEOUT: ("port", "query", "t_s"),
        Event.REPLY_LOST_COMMAND_OBEYED: ("port", "query"),
        Event.LEVEL: ("t_s",),
        Event.LEVELLED: ("t_s",),
        Event.LEVEL_UNCONFIRMED: ("t_s",),
        Event.LEVEL_FAILED: ("error",),
        Event.LEVEL_INTERRUPTED: (),
        Event.RUN_STOP: ("status", "exit_code", "message", "summary"),
    }
)
"""A name ending in ``?`` is written only when it applies."""
