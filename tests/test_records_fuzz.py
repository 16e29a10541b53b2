"""Property tests of the record and protocol readers: whatever the bytes, the only
exception is the project's own (:class:`chekan.errors.ChekanError`, in practice
``FormatError`` naming the file and the line); what is accepted is consistent."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from chekan.errors import ChekanError, FormatError
from chekan.records import read_record
from chekan.records.protocol import read_protocol

RECORD = (
    b"# format: chekan-record/1\n"
    b"# serial: 46\n"
    b"# g_local_mgal: 981922.05\n"
    b"# sample_rate_hz: 1\n"
    b"t_s,m1_pix,m2_pix,tilt_x_arcsec,tilt_y_arcsec,temp_c,step\n"
    b"0,1031.2214,1012.9020,0.3,-0.8,45.002,0\n"
    b"1,1031.2290,1012.8977,0.1,-0.6,45.002,0\n"
    b"2,1031.2251,,-0.2,-0.7,45.003,\n"
)
PROTOCOL = (
    "# format: chekan-protocol/1\n"
    "# serial: 46\n"
    "# a_mgal_per_pix2: 7.828e-5\n"
    "# b_r1_s1: 6.980343\n"
    "# b_r1_s2: 6.882650\n"
    "angle,da_ref_mgal,dg_r1_s1,dg_r1_s2\n"
    "1°50',502.63,504.05,503.64\n"
    "2°30',934.57,935.07,\n"
    "3°10',1499.32,1499.88,1499.11\n"
).encode()

FUZZ = settings(
    max_examples=200,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

# pieces that stress the number and framing rules
TOKENS = [
    b"nan",
    b"NaN",
    b"inf",
    b"-inf",
    b"1e999",
    b"e999",
    b"-0",
    b"1.",
    b".5",
    b"--1",
    b"1e-400",
    b"0" * 5000,
    b"9" * 40,
    b"\xef\xbb\xbf",
    b"\x00",
    b"\xff\xfe",
    b"\r",
    b"\r\n",
    b"\n",
    b",",
    b" ",
    b"\t",
    b"#",
    b"# format: chekan-record/1\n",
    b"# format: chekan-protocol/1\n",
    b"# serial: \n",
    b"# g_local_mgal: inf\n",
    b"# a_mgal_per_pix2: nan\n",
    "5°61'".encode(),
    "−1°50'".encode(),
    "±9999999°".encode(),
]


@st.composite
def mutated(draw: st.DrawFn, base: bytes) -> bytes:
    """``base`` after a few mutations: truncation, garbage, tokens, duplicated or dropped
    lines, a BOM, CRLF line ends."""
    data = base
    for _ in range(draw(st.integers(1, 4))):
        op = draw(
            st.sampled_from(["truncate", "insert", "token", "dup", "drop", "bom", "crlf", "flip"])
        )
        if op == "truncate":
            data = data[: draw(st.integers(0, len(data)))]
        elif op in ("insert", "token"):
            at = draw(st.integers(0, len(data)))
            piece = (
                draw(st.binary(min_size=1, max_size=12))
                if op == "insert"
                else draw(st.sampled_from(TOKENS))
            )
            data = data[:at] + piece + data[at:]
        elif op in ("dup", "drop"):
            lines = data.split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            lines[i : i + 1] = [lines[i], lines[i]] if op == "dup" else []
            data = b"\n".join(lines)
        elif op == "bom":
            data = b"\xef\xbb\xbf" + data
        elif op == "crlf":
            data = data.replace(b"\n", b"\r\n")
        elif data:
            i = draw(st.integers(0, len(data) - 1))
            data = data[:i] + bytes([draw(st.integers(0, 255))]) + data[i + 1 :]
    return data


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def _read(reader, path: Path, data: bytes):
    """``reader(path)`` on ``data``; None when it raised the project's error."""
    path.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return reader(path)
        except ChekanError as e:
            assert isinstance(e, FormatError)
            assert str(e).startswith(str(path)), str(e)
            return None


def _check_record(rec) -> None:
    n = rec.n
    for a in (rec.m1_pix, rec.m2_pix, rec.tilt_x_arcsec, rec.tilt_y_arcsec, rec.step):
        assert len(a) == n
    assert np.all(np.isfinite(rec.t_s))
    assert np.all(np.diff(rec.t_s) >= 0)
    assert np.all(rec.step >= -1)
    assert math.isfinite(rec.g_local_mgal)


def _check_protocol(prot) -> None:
    assert prot.n > 0
    assert np.all(np.isfinite(prot.angle_deg)) and np.all(np.isfinite(prot.da_ref_mgal))
    assert prot.dg_mgal.shape == (len(prot.rounds), len(prot.systems), prot.n)


@FUZZ
@given(data=st.binary(max_size=600))
def test_record_reader_on_arbitrary_bytes(fuzz_dir: Path, data: bytes) -> None:
    rec = _read(read_record, fuzz_dir / "any.csv", data)
    if rec is not None:
        _check_record(rec)


@FUZZ
@given(data=mutated(RECORD))
@example(data=RECORD.replace(b"45.003,\n", b"45.003," + b"0" * 5000 + b"\n"))
@example(data=RECORD.replace(b"-0.8", b"NaN").replace(b"0.1", b"e999"))
def test_record_reader_on_mutated_records(fuzz_dir: Path, data: bytes) -> None:
    rec = _read(read_record, fuzz_dir / "rec.csv", data)
    if rec is not None:
        _check_record(rec)


@FUZZ
@given(data=st.binary(max_size=600))
def test_protocol_reader_on_arbitrary_bytes(fuzz_dir: Path, data: bytes) -> None:
    prot = _read(read_protocol, fuzz_dir / "any_prot.csv", data)
    if prot is not None:
        _check_protocol(prot)


@FUZZ
@given(data=mutated(PROTOCOL))
@example(data=PROTOCOL.replace(b"dg_r1_s2", b"dg_r" + b"0" * 5000 + b"1_s2"))
@example(data=PROTOCOL.replace(b"dg_r1_s2", b"dg_r" + b"7" * 5000 + b"_s2"))
def test_protocol_reader_on_mutated_protocols(fuzz_dir: Path, data: bytes) -> None:
    prot = _read(read_protocol, fuzz_dir / "prot.csv", data)
    if prot is not None:
        _check_protocol(prot)


def test_the_valid_bases_read() -> None:
    """The seeds of the mutations are valid files (else the fuzzing tests little)."""
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        assert read_record(_put(Path(d), "r.csv", RECORD)).n == 3
        assert read_protocol(_put(Path(d), "p.csv", PROTOCOL)).n == 3


def _put(d: Path, name: str, data: bytes) -> Path:
    p = d / name
    p.write_bytes(data)
    return p
