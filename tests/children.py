"""Stopping a child process that a test started, never leaving it running."""

from __future__ import annotations

import signal
import subprocess


def interrupt(p: subprocess.Popen, timeout_s: float) -> tuple:
    """Ctrl-C for ``p`` and its output (``communicate``); a child still running after
    ``timeout_s`` is killed before the ``TimeoutExpired`` goes on to fail the test (once, a
    ``chekan live`` child outlived its timed-out test by 50 minutes)."""
    p.send_signal(signal.SIGINT)
    try:
        return p.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        p.kill()
        p.communicate()
        raise
