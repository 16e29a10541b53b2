"""How a run starts: :func:`acquire` checks a new run's request (record, metadata, g) and
runs it; :func:`resume` continues a killed or interrupted one from where it stands
(:mod:`hw.acquisition.resume`)."""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from chekan.errors import ChekanError
from chekan.physics.program import TiltProgram
from hw.acquisition.plan import Options, plan_from_program
from hw.acquisition.resume import resume_state
from hw.acquisition.runner import Acquisition
from hw.acquisition.summary import Summary
from hw.errors import BadMetadata, PortsUnknown, RecordExists
from hw.journal import journal_path
from hw.progress import Progress

PROTECTED_META = ("format", "serial", "platform_serial", "sample_rate_hz", "started")
_META_KEY = re.compile(r"[a-z0-9_]+")


def check_meta(meta: Mapping[str, str]) -> dict[str, str]:
    """A copy of the user's header keys; BadMetadata for a protected key or a bad key/value."""
    user = dict(meta)
    bad = sorted(set(user) & set(PROTECTED_META))
    if bad:
        raise BadMetadata(f"cannot set {', '.join(bad)} (they come from the devices)")
    for k, v in user.items():
        if not _META_KEY.fullmatch(str(k)) or "\n" in str(v) or "\r" in str(v):
            raise BadMetadata(f"{k}={v!r}: key of [a-z0-9_], value on one line")
    return user


def g_local_text(g_local_mgal: float | str) -> str:
    """The header value of ``g_local_mgal`` (a finite number; text is kept as written)."""
    try:
        g = float(g_local_mgal)
    except (TypeError, ValueError):
        g = math.nan
    if not math.isfinite(g):
        raise ChekanError(f"g_local_mgal must be a finite number, not {g_local_mgal!r}")
    return str(g_local_mgal).strip() if isinstance(g_local_mgal, str) else repr(g)


def acquire(
    record_path: str | Path,
    program: TiltProgram,
    options: Options,
    *,
    g_local_mgal: float | str,
    meta: dict[str, str] | None = None,
    progress: Callable[[Progress], None] | None = None,
    report: Callable[[str], None] | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Summary:
    """Start a new run of ``program`` into a new record (refuses to overwrite one).

    ``report`` (e.g. ``print``) receives the summary text at the end; by default nothing
    is printed: the caller shows the returned :class:`Summary`.
    """
    path = Path(record_path)
    for p in (path, journal_path(path)):
        if p.exists():
            raise RecordExists(str(p))
    user = check_meta(meta or {})
    user["g_local_mgal"] = g_local_text(g_local_mgal)
    acq = Acquisition(
        path,
        plan_from_program(program),
        options,
        program_name=program.name,
        meta=user,
        progress=progress,
        report=report,
        clock=clock,
        sleep=sleep,
    )
    return acq.run()


def resume(
    record_path: str | Path,
    *,
    sensor_url: str | None = None,
    platform_url: str | None = None,
    options: Options | None = None,
    overrides: dict[str, Any] | None = None,
    progress: Callable[[Progress], None] | None = None,
    report: Callable[[str], None] | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Summary:
    """Continue a killed or interrupted run of ``record_path`` (what is kept and what is run
    again: :mod:`hw.acquisition.resume`).

    Ports and options come from the journal unless given (``overrides``: Options fields;
    ``options`` is not changed). ``report`` receives the summary text at the end.
    """
    state, start, plan, _ = resume_state(record_path)
    if state is None:
        s = Summary(status="completed", n_steps=len(plan), steps_done=len(plan))
        s.message = "nothing to resume: the run is complete"
        if report is not None:
            report(s.message)
        return s
    base = options or Options.from_json(start.get("options", {}))
    opts = Options.from_json(base.to_json())  # a copy: the caller's options stay as they are
    for k, v in (overrides or {}).items():
        if v is not None:
            setattr(opts, k, v)
    if sensor_url:
        opts.sensor_url = sensor_url
    if platform_url:
        opts.platform_url = platform_url
    if not opts.sensor_url or not opts.platform_url:
        raise PortsUnknown()
    acq = Acquisition(
        record_path,
        plan,
        opts,
        program_name=str(start.get("program", "custom")),
        resume_state=state,
        progress=progress,
        report=report,
        clock=clock,
        sleep=sleep,
    )
    return acq.run()
