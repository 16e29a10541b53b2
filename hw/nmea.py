"""NMEA-style sentences of the sensor and the platform: encode, checksum, robust parsing.

A sentence is ``$<body>*HH\\r\\n`` with ``HH`` the XOR of the body's bytes, two
upper-case hex digits (``docs/specs/serial-protocol.md``). :class:`SentenceParser`
is fed raw bytes in arbitrary chunks and returns typed sentences; it never raises
on bad input: it skips garbage before a ``$``, resynchronises on every ``$``,
accepts ``\\r\\n`` and a bare ``\\n``, keeps a bounded buffer, and drops (and counts
by reason in :attr:`SentenceParser.stats`) everything it cannot use.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass

MAX_SENTENCE = 256  # bytes from '$' to '\n'; longer lines are dropped as "overlong"
SEQ_MOD = 65536

REASONS = (
    "bad_checksum",  # wrong or malformed checksum
    "torn",  # no '*' before the end of line, or a new '$' before the end of line
    "non_ascii",  # bytes >= 0x80 or control characters inside a sentence
    "unparsable_fields",  # a known sentence type whose fields do not parse
    "unknown_type",  # a well-formed sentence of a type nobody asked for (ignored)
    "garbage_bytes",  # bytes outside any sentence (CR/LF not counted)
    "overlong",  # a '$' followed by more than MAX_SENTENCE bytes without end of line
)

_TYPE_RE = re.compile(r"[A-Z][A-Z0-9]{1,9}")
_NUM_RE = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_UINT_RE = re.compile(r"\d{1,9}")
_WORD_RE = re.compile(r"[A-Z][A-Z0-9_]*")
_HEX = frozenset(b"0123456789ABCDEFabcdef")
_FORBIDDEN = frozenset("$*,\r\n")


# --------------------------------------------------------------------------- encoding


def checksum(body: bytes | str) -> int:
    """XOR of every byte of ``body`` (the text between ``$`` and ``*``)."""
    if isinstance(body, str):
        body = body.encode("ascii")
    c = 0
    for b in body:
        c ^= b
    return c


def format_number(v: float, decimals: int = 6) -> str:
    """A finite number as plain decimal text (no exponent), trailing zeros trimmed."""
    v = float(v)
    if not math.isfinite(v):
        raise ValueError(f"cannot send a non-finite number ({v!r})")
    s = f"{v:.{decimals}f}"
    if "." in s:
        s = s.rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _field(v: object) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        raise TypeError("booleans are not sentence fields")
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return format_number(v)
    s = str(v)
    bad = [c for c in s if c in _FORBIDDEN or not (" " <= c <= "~")]
    if bad:
        raise ValueError(f"field {s!r} contains forbidden character {bad[0]!r}")
    return s


def encode(type: str, *fields: object) -> bytes:
    """``encode("GRQ", "ID")`` → ``b"$GRQ,ID*65\\r\\n"``. ``None`` gives an empty field."""
    if not _TYPE_RE.fullmatch(type):
        raise ValueError(f"bad sentence type {type!r}")
    body = ",".join([type, *(_field(f) for f in fields)]).encode("ascii")
    return b"$" + body + b"*%02X\r\n" % checksum(body)


# --------------------------------------------------------------------------- typed sentences


@dataclass(frozen=True)
class Sentence:
    """A checked sentence: its type (``GRV``…) and its fields after the type."""

    type: str
    fields: tuple[str, ...]

    @property
    def key(self) -> str:
        """First field (what replies are matched by): ``ID``, ``RATE``, ``TILT``…"""
        return self.fields[0] if self.fields else ""


@dataclass(frozen=True)
class Grv(Sentence):
    """One sensor sample: ``$GRV,seq,m1,m2,temp,status``; m1/m2 are None when SAT or empty."""

    seq: int = 0
    m1: float | None = None
    m2: float | None = None
    temp: float | None = None
    status: str = "OK"


@dataclass(frozen=True)
class Plt(Sentence):
    """One platform status: ``$PLT,seq,x_arcsec,y_arcsec,state`` (MOVE, HOLD, FAULT)."""

    seq: int = 0
    x: float = 0.0
    y: float = 0.0
    state: str = "HOLD"


@dataclass(frozen=True)
class Reply(Sentence):
    """A reply ``$GRA,…`` / ``$PLA,…``: ``key`` is the first field, ``args`` the rest."""

    @property
    def args(self) -> tuple[str, ...]:
        return self.fields[1:]

    @property
    def is_error(self) -> bool:
        return len(self.fields) >= 2 and self.fields[1] == "ERR"


@dataclass(frozen=True)
class Query(Sentence):
    """A host query or command ``$GRQ,…`` / ``$PLQ,…`` (parsed by the emulator)."""

    @property
    def args(self) -> tuple[str, ...]:
        return self.fields[1:]


def _num(s: str, name: str) -> float:
    if not _NUM_RE.fullmatch(s):
        raise ValueError(f"{name}: {s!r} is not a number")
    v = float(s)
    if not math.isfinite(v):
        raise ValueError(f"{name}: {s!r} is not finite")
    return v


def _opt_num(s: str, name: str) -> float | None:
    return None if s == "" else _num(s, name)


def _seq(s: str) -> int:
    if not _UINT_RE.fullmatch(s) or int(s) >= SEQ_MOD:
        raise ValueError(f"seq: {s!r} is not an integer 0..65535")
    return int(s)


def _word(s: str, name: str) -> str:
    if not _WORD_RE.fullmatch(s):
        raise ValueError(f"{name}: {s!r} is not a status word")
    return s


def parse_grv(type: str, f: tuple[str, ...]) -> Grv:
    if len(f) < 5:
        raise ValueError(f"GRV needs 5 fields, got {len(f)}")
    status = _word(f[4], "status")
    m1, m2 = _opt_num(f[1], "m1"), _opt_num(f[2], "m2")
    if status == "SAT":
        m1 = m2 = None
    return Grv(type, f, seq=_seq(f[0]), m1=m1, m2=m2, temp=_opt_num(f[3], "temp"), status=status)


def parse_plt(type: str, f: tuple[str, ...]) -> Plt:
    if len(f) < 4:
        raise ValueError(f"PLT needs 4 fields, got {len(f)}")
    return Plt(
        type, f, seq=_seq(f[0]), x=_num(f[1], "x"), y=_num(f[2], "y"), state=_word(f[3], "state")
    )


def parse_reply(type: str, f: tuple[str, ...]) -> Reply:
    if not f or not _WORD_RE.fullmatch(f[0]):
        raise ValueError("reply without a key")
    return Reply(type, f)


def parse_query(type: str, f: tuple[str, ...]) -> Query:
    if not f or not _WORD_RE.fullmatch(f[0]):
        raise ValueError("query without a key")
    return Query(type, f)


Parser = Callable[[str, tuple[str, ...]], Sentence]
HOST_TYPES: Mapping[str, Parser] = {
    "GRV": parse_grv,
    "PLT": parse_plt,
    "GRA": parse_reply,
    "PLA": parse_reply,
}
DEVICE_TYPES: Mapping[str, Parser] = {"GRQ": parse_query, "PLQ": parse_query}
ALL_TYPES: Mapping[str, Parser] = {**HOST_TYPES, **DEVICE_TYPES}


class SentenceError(ValueError):
    """A line that is not a usable sentence; ``reason`` is one of :data:`REASONS`."""

    def __init__(self, reason: str, detail: str = ""):
        self.reason = reason
        super().__init__(f"{reason}: {detail}" if detail else reason)


def parse_sentence(line: bytes, types: Mapping[str, Parser] = ALL_TYPES) -> Sentence:
    """Parse one line (with or without ``$`` and end of line); raise :class:`SentenceError`."""
    if line.startswith(b"$"):
        line = line[1:]
    line = line.rstrip(b"\r\n")
    if any(b >= 0x7F or b < 0x20 for b in line):
        raise SentenceError("non_ascii")
    if b"$" in line:
        raise SentenceError("torn", "a '$' inside the sentence")
    star = line.rfind(b"*")
    if star < 0:
        raise SentenceError("torn", "no '*'")
    body, cs = line[:star], line[star + 1 :].rstrip(b" \t")
    if len(cs) != 2 or not all(c in _HEX for c in cs):
        raise SentenceError("bad_checksum", f"malformed checksum {cs!r}")
    if int(cs, 16) != checksum(body):
        raise SentenceError("bad_checksum", f"{cs.decode()} != {checksum(body):02X}")
    parts = body.decode("ascii").split(",")
    parse = types.get(parts[0])
    if parse is None:
        raise SentenceError("unknown_type", parts[0][:16])
    try:
        return parse(parts[0], tuple(parts[1:]))
    except ValueError as e:
        raise SentenceError("unparsable_fields", str(e)) from None


class SentenceParser:
    """Incremental, never-raising parser of a byte stream into typed sentences."""

    def __init__(self, types: Mapping[str, Parser] = HOST_TYPES, max_len: int = MAX_SENTENCE):
        self.types = types
        self.max_len = max_len
        self.stats: dict[str, int] = dict.fromkeys(REASONS, 0)
        self.accepted = 0
        self.last_error: str = ""
        self._buf = bytearray()

    @property
    def dropped(self) -> int:
        """Lines dropped for any reason (garbage bytes are not lines and not included)."""
        return sum(v for k, v in self.stats.items() if k != "garbage_bytes")

    def _garbage(self, seg: bytes | bytearray) -> None:
        n = len(seg) - seg.count(b"\r") - seg.count(b"\n")
        self.stats["garbage_bytes"] += n

    def reset(self) -> None:
        """Forget a partial sentence (e.g. on reopen); it is counted as torn."""
        if self._buf.startswith(b"$"):
            self.stats["torn"] += 1
        else:
            self._garbage(self._buf)
        self._buf.clear()

    def feed(self, data: bytes) -> list[Sentence]:
        """Add bytes; return the complete, valid sentences they finish (in order)."""
        buf = self._buf
        buf += data
        out: list[Sentence] = []
        pos = 0
        n = len(buf)
        while pos < n:
            if buf[pos] != 0x24:  # '$'
                d = buf.find(b"$", pos)
                end = n if d < 0 else d
                self._garbage(buf[pos:end])
                pos = end
                continue
            nl = buf.find(b"\n", pos + 1)
            dl = buf.find(b"$", pos + 1)
            if dl >= 0 and (nl < 0 or dl < nl):
                self.stats["torn"] += 1
                self.last_error = "torn: a new '$' before the end of line"
                pos = dl
                continue
            if nl < 0:
                if n - pos > self.max_len:
                    self.stats["overlong"] += 1
                    self.last_error = f"overlong: more than {self.max_len} bytes"
                    pos = n
                break
            line = bytes(buf[pos + 1 : nl])
            pos = nl + 1
            if len(line) > self.max_len:
                self.stats["overlong"] += 1
                continue
            try:
                out.append(parse_sentence(line, self.types))
                self.accepted += 1
            except SentenceError as e:
                self.stats[e.reason] += 1
                self.last_error = str(e)
        del buf[:pos]
        return out
