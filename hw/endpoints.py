"""Where the emulator's bytes go: a pseudo-terminal or an in-process pipe.

:class:`PtyEndpoint` opens a pty pair (``os.openpty``, slave in raw mode), keeps
the slave open itself (so the pty survives the host closing its port) and
points a stable symlink given by the user (e.g. ``/tmp/chekan-sensor``) at the
slave device. ``vanish`` closes the pty and removes the symlink (the host's
reads fail as on a USB unplug); ``restore`` creates a new pty (possibly another
``/dev/pts/N``) behind the same symlink.

:class:`MemoryEndpoint` is the same contract in memory, reached by the pyserial
URL ``chekanemu://<port>?session=<name>`` (:mod:`hw.protocol_chekanemu`); it
buffers up to 4096 bytes towards the host like a tty line discipline.

Both are driven by the emulator's thread only, except the ``host_*`` methods of
:class:`MemoryEndpoint`, called by the host's serial object.
"""

from __future__ import annotations

import array
import contextlib
import errno
import fcntl
import os
import termios
import threading
import time
import tty
from collections.abc import Callable

from serial import SerialException

TTY_BUFFER = 4096


class PtyEndpoint:
    """One emulated port on a pseudo-terminal with a stable symlink."""

    async_delivery = True  # written bytes reach the slave's queue a little later

    def __init__(self, name: str, link_path: str | None = None):
        self.name = name
        self.link_path = str(link_path) if link_path else None
        self.master: int | None = None
        self.slave: int | None = None
        self.device: str | None = None

    @property
    def present(self) -> bool:
        return self.master is not None

    @property
    def path(self) -> str | None:
        """What the host opens: the symlink if any, else the slave device."""
        return self.link_path or self.device

    def create(self) -> None:
        m, s = os.openpty()
        tty.setraw(s)
        os.set_blocking(m, False)
        self.master, self.slave = m, s
        self.device = os.ttyname(s)
        if self.link_path:
            tmp = f"{self.link_path}.tmp-{os.getpid()}"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            os.symlink(self.device, tmp)
            os.replace(tmp, self.link_path)

    def _unlink(self) -> None:
        if not self.link_path:
            return
        try:
            if os.readlink(self.link_path) == self.device:
                os.unlink(self.link_path)
        except OSError:
            pass

    def vanish(self) -> None:
        """Remove the symlink and close the pty: the host sees its device disappear."""
        self._unlink()
        for fd in (self.master, self.slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.master = self.slave = None

    def restore(self) -> None:
        if not self.present:
            self.create()

    close = vanish

    def fileno(self) -> int | None:
        return self.master

    def write(self, data: bytes) -> int:
        """Write what fits without blocking; returns the bytes accepted."""
        if self.master is None:
            return 0
        try:
            return os.write(self.master, data)
        except BlockingIOError:
            return 0
        except OSError:
            return 0

    def read(self) -> bytes:
        if self.master is None:
            return b""
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as e:  # EIO: no slave open (cannot happen while we hold one)
            if e.errno == errno.EIO:
                return b""
            raise

    def pending(self) -> int:
        """Bytes written towards the host that it has not read yet (line discipline)."""
        if self.slave is None:
            return 0
        buf = array.array("i", [0])
        try:
            fcntl.ioctl(self.slave, termios.FIONREAD, buf)
        except OSError:
            return 0
        return int(buf[0])


class MemoryEndpoint:
    """One emulated port in memory, for ``chekanemu://`` URLs (same contract as a pty)."""

    def __init__(self, name: str, wake: Callable[[], None] | None = None):
        self.name = name
        self._wake = wake or (lambda: None)
        self._cond = threading.Condition()
        self._to_host = bytearray()
        self._from_host = bytearray()
        self._present = False
        self._generation = 0
        self._attached: int | None = None  # generation of the attached host, if any

    # --- device side (emulator thread)
    @property
    def present(self) -> bool:
        return self._present

    def create(self) -> None:
        with self._cond:
            self._present = True

    def vanish(self) -> None:
        with self._cond:
            self._present = False
            self._generation += 1
            self._attached = None
            self._to_host.clear()
            self._from_host.clear()
            self._cond.notify_all()

    def restore(self) -> None:
        if not self._present:
            self.create()

    close = vanish

    def fileno(self) -> int | None:
        return None

    def write(self, data: bytes) -> int:
        with self._cond:
            if not self._present:
                return 0
            n = min(len(data), TTY_BUFFER - len(self._to_host))
            if n > 0:
                self._to_host += data[:n]
                self._cond.notify_all()
            return max(n, 0)

    def read(self) -> bytes:
        with self._cond:
            out = bytes(self._from_host)
            self._from_host.clear()
            return out

    def pending(self) -> int:
        with self._cond:
            return len(self._to_host)

    # --- host side (the host's serial object)
    def host_open(self, exclusive: bool) -> int:
        with self._cond:
            if not self._present:
                raise SerialException(f"could not open port {self.name}: no such device")
            if exclusive and self._attached == self._generation:
                raise SerialException(
                    f"[Errno 11] Could not exclusively lock port {self.name}: "
                    "Resource temporarily unavailable"
                )
            self._attached = self._generation
            self._to_host.clear()  # like pyserial's flush at open
            return self._generation

    def host_close(self, token: int) -> None:
        with self._cond:
            if self._attached == token:
                self._attached = None

    def _check(self, token: int) -> None:
        if token != self._generation or not self._present:
            raise SerialException(
                "device reports readiness to read but returned no data "
                "(device disconnected or multiple access on port?)"
            )

    def host_in_waiting(self, token: int) -> int:
        with self._cond:
            self._check(token)
            return len(self._to_host)

    def host_read(self, token: int, size: int, timeout: float | None) -> bytes:
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while True:
                self._check(token)
                if self._to_host:
                    out = bytes(self._to_host[:size])
                    del self._to_host[:size]
                    if not self._to_host:
                        self._wake()  # a lock-stepped emulator may go on at once
                    return out
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return b""
                self._cond.wait(left if left is not None else 0.1)

    def host_write(self, token: int, data: bytes) -> int:
        with self._cond:
            self._check(token)
            self._from_host += data
        self._wake()
        return len(data)

    def host_reset_input(self, token: int) -> None:
        with self._cond:
            self._check(token)
            self._to_host.clear()

    def host_cancel(self) -> None:
        with self._cond:
            self._cond.notify_all()


_SESSIONS: dict[tuple[str, str], MemoryEndpoint] = {}
_SESSIONS_LOCK = threading.Lock()


def register(session: str, endpoint: MemoryEndpoint) -> None:
    """Make ``endpoint`` reachable as ``chekanemu://<endpoint.name>?session=<session>``."""
    with _SESSIONS_LOCK:
        _SESSIONS[(session, endpoint.name)] = endpoint


def unregister(session: str) -> None:
    with _SESSIONS_LOCK:
        for k in [k for k in _SESSIONS if k[0] == session]:
            del _SESSIONS[k]


def lookup(session: str, port: str) -> MemoryEndpoint:
    with _SESSIONS_LOCK:
        ep = _SESSIONS.get((session, port))
    if ep is None:
        raise SerialException(f"no emulator port {port!r} in session {session!r}")
    return ep


def memory_url(port: str, session: str) -> str:
    return f"chekanemu://{port}?session={session}"
