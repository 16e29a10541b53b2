"""The live page's HTTP server: the page, its vendored uPlot, and a server-sent-event stream.

Standard library only (:class:`http.server.ThreadingHTTPServer`): the page is read-only,
has a handful of viewers at most, and its updates flow one way, which is what
server-sent events (a long ``text/event-stream`` response) are for; one thread per
viewer is plenty, and an acquisition PC needs no web framework installed.

Routes: ``/`` the page, ``/static/…`` uPlot, ``/events`` the stream (``init`` with all
rows so far and the status, then ``rows`` and ``status`` as the files grow),
``/api/status`` and ``/api/rows?from=N`` for scripts.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs, urlparse

from chekan.errors import ChekanError
from chekan.live.state import LiveState

POLL_S = 0.5
KEEPALIVE_S = 15.0

_TYPES = {".js": "text/javascript", ".css": "text/css", ".html": "text/html; charset=utf-8"}


def parse_address(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` → (host, port); host defaults to 127.0.0.1, port 0 = any free port."""
    host, sep, port = str(text).rpartition(":")
    if not sep:
        host = "127.0.0.1"
    host = host.strip("[]") or "127.0.0.1"
    try:
        p = int(port)
    except ValueError:
        raise ChekanError(
            f"--live {text!r}: expected [HOST:]PORT, e.g. 8050 or 0.0.0.0:8050"
        ) from None
    if not 0 <= p <= 65535:
        raise ChekanError(f"--live {text!r}: port must be 0…65535")
    return host, p


def _static(name: str) -> bytes:
    return resources.files("chekan.live").joinpath("static", name).read_bytes()


def _dumps(obj) -> str:
    return json.dumps(obj, ensure_ascii=False, separators=(",", ":"), allow_nan=False)


class _Handler(BaseHTTPRequestHandler):
    server: LiveServer  # type: ignore[assignment]
    protocol_version = "HTTP/1.1"

    def log_message(self, format, *args):  # quiet: the terminal belongs to the acquisition
        pass

    def _send(self, code: int, body: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def do_GET(self):
        url = urlparse(self.path)
        st = self.server.state
        try:
            if url.path in ("/", "/index.html"):
                self._send(200, _static("page.html"), _TYPES[".html"])
            elif url.path.startswith("/static/"):
                name = url.path.removeprefix("/static/")
                if "/" in name or name not in self.server.static_names:
                    self._send(404, b"not found", "text/plain")
                    return
                self._send(200, _static(name), _TYPES.get(Path(name).suffix, "text/plain"))
            elif url.path == "/api/status":
                self._send(200, _dumps(st.status()).encode(), "application/json")
            elif url.path == "/api/rows":
                text = parse_qs(url.query).get("from", ["0"])[0]
                if not text.isdigit():  # a client's mistake: say so, never a traceback
                    self._send(400, b"from must be a row number (0, 1, 2, ...)", "text/plain")
                    return
                self._send(200, _dumps(st.rows_since(int(text))).encode(), "application/json")
            elif url.path == "/events":
                self._events()
            else:
                self._send(404, b"not found", "text/plain")
        except (BrokenPipeError, ConnectionResetError):
            pass

    def _events(self) -> None:
        st = self.server.state
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        self.close_connection = True

        def send(event: str, data) -> None:
            self.wfile.write(f"event: {event}\ndata: {_dumps(data)}\n\n".encode())
            self.wfile.flush()

        with st.changed:
            seen = st.version  # before the status: an update landing meanwhile is sent again
        rows = st.rows_since(0)
        sent = rows["n"]
        send("init", {"rows": rows, "status": st.status()})
        last = time.monotonic()
        while not self.server.stopping.is_set():
            with st.changed:
                st.changed.wait(timeout=1.0)
                version = st.version
            if version != seen:
                seen = version
                if st.n > sent:
                    rows = st.rows_since(sent)
                    sent = rows["n"]
                    send("rows", rows)
                send("status", st.status())
                last = time.monotonic()
            elif time.monotonic() - last > KEEPALIVE_S:
                self.wfile.write(b": keepalive\n\n")
                self.wfile.flush()
                last = time.monotonic()


class LiveServer(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, address: tuple[str, int], state: LiveState):
        super().__init__(address, _Handler)
        self.state = state
        self.stopping = threading.Event()
        self.static_names = {
            p.name for p in resources.files("chekan.live").joinpath("static").iterdir()
        }

    def handle_error(self, request, client_address) -> None:
        """A client that goes away mid-request is no error of the server's; anything else is
        one line on stderr, never a traceback."""
        err = sys.exc_info()[1]
        if isinstance(err, ConnectionError | TimeoutError):
            return
        print(f"chekan live: request from {client_address[0]}: {err!r}", file=sys.stderr)

    @property
    def open_to_network(self) -> bool:
        """Bound to every interface (``0.0.0.0``, ``::``), not to loopback alone."""
        return self.server_address[0] in ("0.0.0.0", "", "::")

    @property
    def url(self) -> str:
        """Where to open the page on this machine (``127.0.0.1`` for an all-interfaces bind)."""
        host, port = self.server_address[:2]
        shown = "127.0.0.1" if self.open_to_network else str(host)
        return f"http://{shown}:{port}/"

    @property
    def bound(self) -> str:
        """The address actually bound, ``HOST:PORT``."""
        host, port = self.server_address[:2]
        return str(host) + f":{port}"

    def follow(self, poll_s: float = POLL_S) -> None:
        """Update the state from the files until :meth:`stop` (runs in its own thread)."""
        while not self.stopping.is_set():
            try:
                self.state.update()
            except Exception as e:  # keep serving what we have; say why once per kind
                msg = f"{type(e).__name__}: {e}"
                if msg != getattr(self, "_last_error", None):
                    self._last_error = msg
                    print(f"chekan live: update failed: {msg}", file=sys.stderr, flush=True)
            self.stopping.wait(poll_s)

    def stop(self) -> None:
        self.stopping.set()
        self.shutdown()
        self.state.map.close()


def serve(
    record: str | Path,
    address: str = "127.0.0.1:0",
    *,
    owner_pid: int | None = None,
    linger_s: float | None = None,
    program=None,
    announce=print,
) -> int:
    """Serve the live page of ``record`` until Ctrl-C, or (``owner_pid``/``linger_s``) until the
    run is over: its ``run_stop`` is journalled (or the owner process is gone and the record
    stopped growing), the last MAP is done, and ``linger_s`` more seconds have passed."""
    host, port = parse_address(address)
    state = LiveState(record, program=program)
    try:
        srv = LiveServer((host, port), state)
    except OSError as e:
        raise ChekanError(f"--live {address}: cannot listen: {e}") from None
    line = f"live page {srv.url} (pid {os.getpid()}, bound to {srv.bound}, following {record})"
    if srv.open_to_network:  # one announcement: the acquisition relays both lines
        line += (
            f"\nwarning: the live page listens on every interface ({srv.bound}): anyone on "
            "the network can read it (read-only)"
        )
    announce(line)
    threading.Thread(target=srv.serve_forever, name="live-http", daemon=True).start()
    follower = threading.Thread(target=srv.follow, name="live-follow", daemon=True)
    follower.start()
    over_since = None
    try:
        while True:
            time.sleep(0.5)
            if linger_s is None:
                continue
            owner_gone = owner_pid is not None and not _alive(owner_pid)
            over = state.run_stop is not None or (owner_gone and state.quiet_s() > 30.0)
            idle = state.map.busy_round is None
            if over and idle:
                over_since = over_since or time.monotonic()
                if time.monotonic() - over_since >= linger_s:
                    break
            else:
                over_since = None
    except KeyboardInterrupt:
        pass
    finally:
        srv.stop()
        srv.server_close()
    return 0


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
