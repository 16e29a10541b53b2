"""Drivers against the emulator over real pseudo-terminals (and the in-process URL scheme)."""

from __future__ import annotations

import itertools
import os
import time

import pytest

from hw.drivers import PlatformDriver, SensorDriver
from hw.emulator import InProcessEmulator, PtyEmulator
from hw.errors import DeviceError, LinkLost
from hw.faults import parse_faults
from hw.linkio import Link, reopen


def wait_hold(p: PlatformDriver, after_rx: int, timeout_s: float = 10.0):
    deadline = time.monotonic() + timeout_s
    states = []
    while time.monotonic() < deadline:
        got = p.next_status(0.5)
        if got is None:
            continue
        rx, plt = got
        if rx > after_rx:
            if not states or states[-1] != plt.state:
                states.append(plt.state)
            if plt.state == "HOLD":
                return plt, states
    raise AssertionError(f"no HOLD (states {states})")


@pytest.fixture(scope="module")
def emu(tmp_path_factory):
    d = tmp_path_factory.mktemp("pty")
    e = PtyEmulator(str(d / "sensor"), str(d / "platform"), speed=100, seed=2, seq_start=65530)
    with e:
        yield e


@pytest.fixture
def drivers(emu):
    s = SensorDriver(Link(emu.sensor_url, "sensor"))
    p = PlatformDriver(Link(emu.platform_url, "platform"))
    s.start()
    p.start()
    yield s, p
    s.close()
    p.close()


def test_stable_symlinks_point_at_ptys(emu):
    assert os.path.islink(emu.sensor_url)
    assert os.readlink(emu.sensor_url).startswith("/dev/pts/")
    assert os.readlink(emu.platform_url) != os.readlink(emu.sensor_url)


def test_id_rate_and_samples_wrap(drivers, emu):
    s, p = drivers
    info = s.identify()
    assert (info.serial, info.model) == ("SIM-1", "Shelf") and info.firmware
    assert s.rate() == 1.0
    assert p.identify().serial == "SIM-PLATFORM"
    seqs = []
    while len(seqs) < 5:
        g = s.next_sample(2.0)
        assert g is not None
        seqs.append(g.seq)
        assert g.status == "OK" and 900 < g.m1 < 1100 and 40 < g.temp < 50
    assert all((b - a) % 65536 == 1 for a, b in itertools.pairwise(seqs))


def test_tilt_move_hold_and_level(drivers, emu):
    _s, p = drivers
    rx = p.tilt(0, 3600)
    plt, states = wait_hold(p, rx)
    assert states[0] == "MOVE" and states[-1] == "HOLD"
    assert plt.y == pytest.approx(3600, abs=3) and plt.x == pytest.approx(0, abs=3)
    assert emu.emulator.platform.target == (0.0, 3600.0)
    err = emu.emulator.platform.holds[-1].readout_error_arcsec
    true_y = emu.emulator.platform.true_attitude(emu.emulator.t)[1]
    assert true_y == pytest.approx(3600 - err[1])
    rx = p.level()
    wait_hold(p, rx)
    assert emu.emulator.platform.target == (0.0, 0.0)


def test_tilt_range_error(drivers):
    _, p = drivers
    with pytest.raises(DeviceError) as e:
        p.tilt(0, 21601)
    assert e.value.reason == "RANGE" and "TILT" in str(e.value)


def test_exclusive_second_opener_fails(drivers, emu):
    other = Link(emu.sensor_url, "sensor")
    with pytest.raises(LinkLost, match="lock"):
        other.open()


def test_port_vanishes_and_comes_back(tmp_path):
    plan = parse_faults("vanish=sensor@20+30")
    with PtyEmulator(
        str(tmp_path / "s"), str(tmp_path / "p"), speed=100, seed=1, faults=plan
    ) as emu:
        link = Link(emu.sensor_url, "sensor", read_timeout_s=0.02)
        link.open()
        old = os.readlink(emu.sensor_url)
        with pytest.raises(LinkLost):
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:
                link.read_sentences()
        assert not os.path.exists(emu.sensor_url)  # the symlink went with the device
        n = reopen(link, give_up_at=time.monotonic() + 5)
        assert n >= 1 and os.path.islink(emu.sensor_url)
        got = []
        while not got:
            got = link.read_sentences()
        assert got[0].type == "GRV" and got[0].seq >= 50  # seq kept counting while gone
        link.close()
        assert old.startswith("/dev/pts/")


def test_in_process_url_scheme():
    with InProcessEmulator("drivers-test", speed=0, seed=4) as emu:
        assert emu.sensor_url == "chekanemu://sensor?session=drivers-test"
        s = SensorDriver(Link(emu.sensor_url, "sensor"))
        p = PlatformDriver(Link(emu.platform_url, "platform"))
        s.start()
        p.start()
        try:
            assert s.identify().serial == "SIM-1"
            with pytest.raises(LinkLost, match="lock"):
                Link(emu.sensor_url, "sensor").open()
            rx = p.tilt(-1800, 0)
            wait_hold(p, rx)
            with pytest.raises(DeviceError, match="RANGE"):
                p.tilt(-30000, 0)
        finally:
            s.close()
            p.close()
