"""pyserial URL handler ``chekanemu://<port>?session=<name>``: the in-process emulator.

Registered by ``serial.protocol_handler_packages.append("hw")`` (done when
:mod:`hw.linkio` is imported); ``serial.serial_for_url`` then imports this module
and uses :class:`Serial`. ``<port>`` is ``sensor`` or ``platform``; the session is
the name given to :class:`hw.emulator.InProcessEmulator` (default ``default``).
Timeouts are host time (like pyserial's own); the emulator keeps its own clock.
"""

from __future__ import annotations

import urllib.parse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from hw.endpoints import MemoryEndpoint, lookup


class Serial(SerialBase):
    """A serial port whose other end is a :class:`~hw.endpoints.MemoryEndpoint`."""

    is_open: bool  # set by SerialBase (pyserial has no type hints)

    def __init__(self, *args, **kwargs):
        self._ep: MemoryEndpoint | None = None
        self._token = -1
        super().__init__(*args, **kwargs)

    def from_url(self, url: str) -> tuple[str, str]:
        parts = urllib.parse.urlsplit(url)
        if parts.scheme != "chekanemu" or not parts.netloc:
            raise SerialException(f"expected chekanemu://<port>?session=<name>, got {url!r}")
        q = urllib.parse.parse_qs(parts.query)
        unknown = set(q) - {"session"}
        if unknown:
            raise SerialException(f"{url}: unknown option(s) {sorted(unknown)}")
        return parts.netloc, q.get("session", ["default"])[0]

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        port, session = self.from_url(self.portstr)
        ep = lookup(session, port)
        self._token = ep.host_open(bool(self._exclusive))
        self._ep = ep
        self.is_open = True

    def close(self) -> None:
        if self._ep is not None:
            self._ep.host_close(self._token)
        self._ep = None
        self.is_open = False

    def _reconfigure_port(self, *args, **kwargs) -> None:
        pass

    def _ep_or_raise(self) -> MemoryEndpoint:
        if not self.is_open or self._ep is None:
            raise PortNotOpenError()
        return self._ep

    @property
    def in_waiting(self) -> int:
        return self._ep_or_raise().host_in_waiting(self._token)

    def read(self, size: int = 1) -> bytes:
        return self._ep_or_raise().host_read(self._token, size, self._timeout)

    def write(self, data) -> int:
        return self._ep_or_raise().host_write(self._token, bytes(data))

    def reset_input_buffer(self) -> None:
        self._ep_or_raise().host_reset_input(self._token)

    def reset_output_buffer(self) -> None:
        self._ep_or_raise()

    def cancel_read(self) -> None:
        if self._ep is not None:
            self._ep.host_cancel()

    @property
    def out_waiting(self) -> int:
        return 0

    def _update_break_state(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True
