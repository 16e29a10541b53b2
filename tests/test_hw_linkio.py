"""Link layer (hw.linkio): framing over pyserial URLs, raw log, reopen, back-off; fault text."""

from __future__ import annotations

import pytest
import serial

from hw.errors import GaveUp, LinkLost
from hw.faults import parse_faults
from hw.linkio import Backoff, Link, RawLog, open_port, reopen, url_scheme
from hw.nmea import encode


class FakeClock:
    def __init__(self):
        self.t = 100.0
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.t

    def sleep(self, d: float) -> None:
        self.sleeps.append(d)
        self.t += d


def test_loop_url_round_trip_and_partial_lines():
    link = Link("loop://", "loop")
    link.open()
    line = encode("PLT", 1, "0.1", "-0.2", "HOLD")
    link.write(b"junk" + line[:10])
    got = link.read_sentences()
    while True:  # read until the loop is drained
        more = link.read_sentences()
        if not more and not link._ser.in_waiting:
            break
        got += more
    assert got == []  # a partial sentence is not returned
    link.write(line[10:])
    got = []
    for _ in range(20):
        got += link.read_sentences()
        if got:
            break
    assert [s.type for s in got] == ["PLT"]
    assert link.parser.stats["garbage_bytes"] == 4
    link.close()
    with pytest.raises(LinkLost):
        link.read_sentences()


def test_exclusive_only_where_supported():
    assert url_scheme("/dev/ttyUSB0") == "" and url_scheme("socket://h:1") == "socket"
    s = open_port("loop://")  # loop:// gets no exclusive flag and opens fine
    assert s.is_open and not s.exclusive
    s.close()


def test_open_failure_is_link_lost(tmp_path):
    link = Link(str(tmp_path / "missing"), "sensor")
    with pytest.raises(LinkLost) as e:
        link.open()
    assert "missing" in str(e.value)


def test_reopen_backs_off_then_succeeds():
    clock = FakeClock()
    fails = [3]

    def opener(url, **kw):
        if fails[0] > 0:
            fails[0] -= 1
            raise serial.SerialException("no such device")
        return serial.serial_for_url("loop://", timeout=0)

    link = Link("x", "sensor", opener=opener, clock=clock)
    n = reopen(
        link, give_up_at=clock() + 60, backoff=Backoff(0.1, 2, 1), clock=clock, sleep=clock.sleep
    )
    assert n == 4 and link.is_open
    assert clock.sleeps == [0.1, 0.2, 0.4, 0.8]
    link.close()


def test_reopen_gives_up():
    clock = FakeClock()

    def opener(url, **kw):
        raise serial.SerialException("gone")

    link = Link("x", "platform", opener=opener, clock=clock)
    with pytest.raises(GaveUp) as e:
        reopen(link, give_up_at=clock() + 5, clock=clock, sleep=clock.sleep, down_since=90.0)
    assert clock() == pytest.approx(105.0)
    assert e.value.port == "platform" and e.value.attempts >= 4 and e.value.down_s >= 15


def test_raw_log_lines_with_port_prefix(tmp_path):
    log = RawLog(tmp_path / "raw.log")
    log.received("sensor", b"$GRV,1*00\r\n$GR")
    log.received("sensor", b"V,2*00\r\n\xff\x00\n")
    log.sent("platform", b"$PLQ,ID*6C\r\n")
    log.received("platform", b"partial")
    log.close()
    lines = (tmp_path / "raw.log").read_text().splitlines()
    assert lines == [
        "sensor< $GRV,1*00",
        "sensor< $GRV,2*00",
        "sensor< \\xff\\x00",
        "platform> $PLQ,ID*6C",
        "platform<~ partial",
    ]


def test_fault_plan_text():
    f = parse_faults(
        "garbage=0.01; badsum=0.02 drop=0.005;stall=sensor@600+30;vanish=both@900+20;"
        "fault=1200+40;tilterr=BUSY@3;therm=5+1;seed=7"
    )
    assert (f.garbage, f.badsum, f.drop, f.seed) == (0.01, 0.02, 0.005, 7)
    assert (
        f.stalled("sensor", 600) and not f.stalled("sensor", 630) and not f.stalled("platform", 610)
    )
    assert f.vanished("sensor", 910) and f.vanished("platform", 910)
    assert f.platform_fault(1239.9) and not f.platform_fault(1240)
    assert f.tilt_error(3) == "BUSY" and f.tilt_error(2) is None and f.therm(5)
    assert parse_faults("").empty
    for bad in ("garbage=2", "stall=600+30", "tilterr=NOPE@1", "what=1", "drop"):
        with pytest.raises(ValueError, match="faults"):
            parse_faults(bad)
