"""Sentence encoding and the never-raising parser (hw.nmea), with hypothesis fuzzing."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hw.nmea import (
    ALL_TYPES,
    MAX_SENTENCE,
    REASONS,
    Grv,
    Plt,
    Query,
    Reply,
    SentenceError,
    SentenceParser,
    checksum,
    encode,
    format_number,
    parse_sentence,
)

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def frame(body: str) -> bytes:
    return b"$" + body.encode() + b"*%02X\r\n" % checksum(body)


def test_encode_checksum_matches_nmea():
    assert encode("GRQ", "ID") == b"$GRQ,ID*65\r\n"
    assert checksum("GPGGA,1") == checksum(b"GPGGA,1")
    line = encode("PLQ", "TILT", 6600.0, -0.5)
    assert line == b"$PLQ,TILT,6600,-0.5*%02X\r\n" % checksum(b"PLQ,TILT,6600,-0.5")
    assert encode("GRV", 1, None, "", 45.0, "SAT").startswith(b"$GRV,1,,,45,SAT*")


@pytest.mark.parametrize("bad", ["a,b", "x*y", "$", "é", "a\nb"])
def test_encode_rejects_forbidden_fields(bad):
    with pytest.raises(ValueError):
        encode("GRA", bad)
    with pytest.raises(ValueError):
        encode("grv", 1)


def test_format_number_has_no_exponent():
    assert format_number(1e-7) == "0"
    assert format_number(1.25e6) == "1250000"
    assert format_number(-0.0) == "0"
    with pytest.raises(ValueError):
        format_number(float("nan"))


def test_typed_sentences():
    p = SentenceParser(ALL_TYPES)
    data = (
        frame("GRV,65535,1031.2214,1012.9020,45.002,OK")
        + frame("GRV,0,,,45.001,SAT")
        + frame("GRV,1,1031.1,1012.8,45.3,THERM")
        + frame("PLT,7,0.30,-6600.12,HOLD")
        + frame("GRA,ID,46,Shelf,2.1")
        + frame("PLA,TILT,ERR,RANGE")
        + frame("PLQ,TILT,1,2")
    )
    out = p.feed(data)
    assert [type(s) for s in out] == [Grv, Grv, Grv, Plt, Reply, Reply, Query]
    g = out[0]
    assert (g.seq, g.m1, g.m2, g.temp, g.status) == (65535, 1031.2214, 1012.902, 45.002, "OK")
    assert out[1].m1 is None and out[1].m2 is None and out[1].status == "SAT"
    assert out[2].status == "THERM" and out[2].m1 == 1031.1
    assert (out[3].seq, out[3].x, out[3].y, out[3].state) == (7, 0.3, -6600.12, "HOLD")
    assert out[4].key == "ID" and out[4].args == ("46", "Shelf", "2.1")
    assert out[5].is_error and out[5].fields[2] == "RANGE"
    assert out[6].args == ("1", "2")
    assert p.dropped == 0 and p.accepted == 7


def test_bare_newline_lowercase_checksum_and_split_feeds():
    p = SentenceParser()
    line = frame("PLT,1,2,3,MOVE").replace(b"\r\n", b"\n")
    lower = line.replace(line[-3:-1], line[-3:-1].lower())
    got = []
    for b in line + lower:
        got += p.feed(bytes([b]))
    assert len(got) == 2 and p.dropped == 0


def test_counters_per_reason():
    p = SentenceParser()
    good = frame("GRV,1,2,3,4,OK")
    bad_sum = good.replace(good[-4:-2], b"%02X" % (int(good[-4:-2], 16) ^ 1))
    data = (
        b"noise"  # 5 garbage bytes
        + bad_sum  # bad_checksum
        + b"$GRV,1,2,3,4,OK\r\n"  # torn: no '*'
        + b"$GRV,1,2"  # torn: a new '$' before the end
        + frame("GRV,1,2,3,4,OK")
        + b"$GRV,1,\xff,3,4,OK*00\r\n"  # non_ascii
        + frame("GRV,1,abc,3,4,OK")  # unparsable_fields
        + frame("GRV,70000,1,3,4,OK")  # unparsable (seq out of range)
        + frame("GRV,1,nan,3,4,OK")  # unparsable (not a decimal)
        + frame("XYZ,1,2")  # unknown_type
        + b"$"
        + b"A" * (MAX_SENTENCE + 10)  # overlong
        + b"\r\n"
        + frame("PLT,2,0,0,HOLD")
    )
    out = p.feed(data)
    assert [s.type for s in out] == ["GRV", "PLT"]
    assert p.stats == {
        "bad_checksum": 1,
        "torn": 2,
        "non_ascii": 1,
        "unparsable_fields": 3,
        "unknown_type": 1,
        "garbage_bytes": 5,
        "overlong": 1,
    }
    assert set(p.stats) == set(REASONS)


def test_buffer_stays_bounded():
    p = SentenceParser()
    for _ in range(200):
        p.feed(b"$" + b"x" * 100)  # never terminated: each '$' tears the previous
        assert len(p._buf) <= MAX_SENTENCE + 1
    p.feed(b"y" * 10_000)
    assert len(p._buf) == 0
    assert p.stats["overlong"] >= 1


def test_parse_sentence_raises_with_reason():
    with pytest.raises(SentenceError) as e:
        parse_sentence(b"$GRV,1*00")
    assert e.value.reason == "bad_checksum"


fields = st.text(
    alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E, exclude_characters="$*,"),
    max_size=12,
)


@FUZZ
@given(st.binary(max_size=600), st.integers(1, 64))
def test_random_bytes_never_raise(data, chunk):
    p = SentenceParser(ALL_TYPES)
    for i in range(0, len(data), chunk):
        p.feed(data[i : i + chunk])
    assert len(p._buf) <= MAX_SENTENCE + 1
    assert all(v >= 0 for v in p.stats.values())


valid_grv = st.builds(
    lambda seq, m1, m2, t, status: encode("GRV", seq, f"{m1:.4f}", f"{m2:.4f}", f"{t:.3f}", status),
    st.integers(0, 65535),
    st.floats(0, 2048),
    st.floats(0, 2048),
    st.floats(-10, 80),
    st.sampled_from(["OK", "THERM"]),
)
valid_plt = st.builds(
    lambda seq, x, y, s: encode("PLT", seq, f"{x:.2f}", f"{y:.2f}", s),
    st.integers(0, 65535),
    st.floats(-21600, 21600),
    st.floats(-21600, 21600),
    st.sampled_from(["MOVE", "HOLD", "FAULT"]),
)
garbage = st.binary(max_size=40)


@FUZZ
@given(
    st.lists(st.tuples(garbage, st.one_of(valid_grv, valid_plt)), min_size=1, max_size=15),
    st.integers(1, 50),
    st.booleans(),
)
def test_valid_sentences_in_garbage_are_all_recovered(items, chunk, bare_lf):
    stream = b""
    expected = []
    for junk, line in items:
        if bare_lf:
            line = line.replace(b"\r\n", b"\n")
        stream += junk + line
        expected.append(line.rstrip(b"\r\n"))
    p = SentenceParser()
    got = []
    for i in range(0, len(stream), chunk):
        got += p.feed(stream[i : i + chunk])
    got_lines = [encode(s.type, *s.fields).rstrip(b"\r\n") for s in got]
    # every valid sentence comes out, in order (garbage could at worst add sentences)
    it = iter(got_lines)
    assert all(any(g == e for g in it) for e in expected)


@FUZZ
@given(st.sampled_from(["GRA", "PLA", "GRQ", "PLQ"]), st.lists(fields, min_size=1, max_size=5))
def test_round_trip(type_, flds):
    flds[0] = "K" + flds[0].upper().replace(" ", "")[:5]
    flds[0] = "".join(c for c in flds[0] if c.isalnum() or c == "_") or "K"
    if not flds[0][0].isalpha():
        flds[0] = "K" + flds[0]
    line = encode(type_, *flds)
    s = parse_sentence(line)
    assert s.type == type_ and list(s.fields) == flds
    assert encode(s.type, *s.fields) == line
