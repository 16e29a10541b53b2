"""A live page of an acquisition: readings, tilt angles, link health, running calibration.

``chekan acquire … --live [HOST:]PORT`` starts it beside the acquisition (a separate
process: :func:`start_beside`); ``chekan live REC.csv`` follows a record that another
process writes, or shows a finished one. The page reads only the files the acquisition
writes (record, journal, raw log), tailing them incrementally, so it can neither slow
nor stop the run. Modules: :mod:`~chekan.live.follow` (file tails),
:mod:`~chekan.live.state` (what the page shows), :mod:`~chekan.live.calib` (running
classical and MAP calibration), :mod:`~chekan.live.server` (HTTP + server-sent events),
``static/page.html`` (the page, uPlot vendored from npm, MIT).
"""

from __future__ import annotations

import argparse
import os
import re
import selectors
import subprocess
import sys
from pathlib import Path

from chekan import argtypes

LINGER_S = 120.0  # after the run (and its last MAP), the page stays up this long


def add_live_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "live",
        help="live page of a record being acquired (or of a finished one)",
        description=(
            "Serve a self-updating page of REC (readings, tilt angles and holds, current "
            "step and time left, link health from the journal, alarms, and the running "
            "calibration: classical after every ± pair, MAP after every round). Read-only; "
            "follows the files another process is writing. Ctrl-C to stop."
        ),
    )
    p.add_argument("record", help="chekan-record/1 file (journal REC.journal.jsonl beside it)")
    p.add_argument(
        "--live",
        default="127.0.0.1:8050",
        metavar="[HOST:]PORT",
        help="where to listen (default 127.0.0.1:8050; port 0: any free port, printed)",
    )
    p.add_argument(
        "--program",
        help="program TOML for the expected sd at the end (default: the journal's plan)",
    )
    p.add_argument("--owner-pid", type=argtypes.integer(1), help=argparse.SUPPRESS)
    p.add_argument("--linger-s", type=argtypes.non_negative, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_live)
    return p


def cmd_live(args: argparse.Namespace) -> int:
    from chekan.live.server import serve

    program = None
    if args.program:
        from chekan.physics.program import load_program

        program = load_program(args.program)
    beside = args.owner_pid is not None

    def announce(line: str) -> None:
        print(line, flush=True)
        if beside:  # the acquisition read this line; further output goes to the log
            sys.stdout = sys.stderr

    return serve(
        args.record,
        args.live,
        owner_pid=args.owner_pid,
        linger_s=args.linger_s,
        program=program,
        announce=announce,
    )


def start_beside(record: str | Path, address: str, *, timeout_s: float = 30.0):
    """Start ``chekan live`` for ``record`` in its own process and session; return
    ``(process, announce lines)`` (the address line, and the warning of a page open to the
    network), or ``(None, reason)`` if it did not come up.

    The process outlives nothing: it leaves ``LINGER_S`` after the run's ``run_stop``
    (or after this process is gone and the record stopped). Its stderr goes to
    ``REC.live.log``. Never raises: the acquisition runs with or without its page.
    """
    try:
        from chekan.live.server import parse_address

        parse_address(address)
        record = Path(record)
        record.parent.mkdir(parents=True, exist_ok=True)
        log = open(f"{record}.live.log", "ab")
        cmd = [sys.executable, "-m", "chekan.live", str(record), "--live", str(address)]
        cmd += ["--owner-pid", str(os.getpid()), "--linger-s", str(LINGER_S)]
        proc = subprocess.Popen(
            cmd,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            bufsize=0,  # unbuffered: a line read leaves the next one for the selector to see
            stderr=log,
            start_new_session=True,  # Ctrl-C of the acquisition is not its business
        )
        log.close()
        out = proc.stdout
        assert out is not None
        sel = selectors.DefaultSelector()
        sel.register(out, selectors.EVENT_READ)
        line = b""
        if sel.select(timeout_s):
            line = out.readline()
        if re.search(rb"bound to (0\.0\.0\.0|::):", line):
            if sel.select(timeout_s):  # the warning that the page is open to the network
                line += out.readline()
        sel.close()
        out.close()
        text = line.decode("utf-8", "replace").strip()
        if not text.startswith("live page"):
            if proc.poll() is None:
                proc.kill()
            return None, f"the live page did not start (see {record}.live.log) {text}".strip()
        return proc, text
    except Exception as e:
        return None, f"the live page did not start: {type(e).__name__}: {e}"
