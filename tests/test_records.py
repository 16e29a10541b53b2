"""Tests of the chekan-record/1 reader and writers (chekan.records) and chekan.records.inputs."""

from __future__ import annotations

import math
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from chekan.errors import FormatError
from chekan.records import (
    DEFAULT_COLUMNS,
    IncompleteLineWarning,
    Record,
    RecordWriter,
    _fast_block,
    _slow_block,
    _synthetic,
    read_record,
    write_record,
)
from chekan.records.inputs import input_kind, read_input

SPEC_EXAMPLE = """\
# format: chekan-record/1
# serial: 46
# instrument: Chekan-AM
# model: Shelf
# platform_serial: 123456
# started: 2015-07-09T06:00:00Z
# g_local_mgal: 981922.05
# latitude_deg: 60.0
# sample_rate_hz: 1
t_s,m1_pix,m2_pix,tilt_x_arcsec,tilt_y_arcsec,temp_c,step
0,1031.2214,1012.9020,0.3,-0.8,45.002,0
1,1031.2290,1012.8977,0.1,-0.6,45.002,0
2,1031.2251,1012.9103,-0.2,-0.7,45.003,0
"""

HEAD = """\
# format: chekan-record/1
# serial: 46
# g_local_mgal: 981922.05
t_s,m1_pix,m2_pix,tilt_x_arcsec,tilt_y_arcsec,step,temp_c
"""  # header is line 4; the first data row is line 5

ROWS = [
    "0,1031.2214,1012.9020,0.30,-0.80,0,45.002",
    "1,1031.2290,1012.8977,0.10,-0.60,0,45.002",
    "2,1031.2251,1012.9103,-0.20,-0.70,,45.003",
    "3,1031.2300,1012.9000,0.00,0.00,1,45.004",
]


def put(tmp_path: Path, text: str | bytes, name: str = "rec.csv") -> Path:
    """Write ``text`` byte for byte (no newline translation) and return the path."""
    p = tmp_path / name
    p.write_bytes(text.encode("utf-8") if isinstance(text, str) else text)
    return p


def body(*rows: str, end: str = "\n") -> str:
    """HEAD followed by rows joined by newlines, then ``end``."""
    return HEAD + "\n".join(rows) + end


def expect_error(path: Path, line: int | None, *fragments: str) -> FormatError:
    """Read ``path`` expecting a FormatError at ``line`` mentioning every fragment."""
    with pytest.raises(FormatError) as info:
        read_record(path)
    err = info.value
    msg = str(err)
    assert path.name in msg
    assert err.line == line, msg
    if line is not None:
        assert f"{path}:{line}:" in msg
    for frag in fragments:
        assert frag in msg, msg
    return err


# --------------------------------------------------------------------------- happy paths


def test_spec_example_parses(tmp_path: Path) -> None:
    rec = read_record(put(tmp_path, SPEC_EXAMPLE))
    assert rec.n == 3
    assert rec.serial == "46"
    assert rec.g_local_mgal == 981922.05
    assert rec.sample_rate_hz == 1.0
    assert rec.started == "2015-07-09T06:00:00Z"
    assert list(rec.meta)[:3] == ["format", "serial", "instrument"]
    assert rec.meta["platform_serial"] == "123456"
    np.testing.assert_array_equal(rec.t_s, [0, 1, 2])
    np.testing.assert_array_equal(rec.m1_pix, [1031.2214, 1031.2290, 1031.2251])
    np.testing.assert_array_equal(rec.m2_pix, [1012.9020, 1012.8977, 1012.9103])
    np.testing.assert_array_equal(rec.tilt_x_arcsec, [0.3, 0.1, -0.2])
    np.testing.assert_array_equal(rec.tilt_y_arcsec, [-0.8, -0.6, -0.7])
    np.testing.assert_array_equal(rec.temp_c, [45.002, 45.002, 45.003])
    np.testing.assert_array_equal(rec.step, [0, 0, 0])
    assert rec.step.dtype == np.int64 and rec.t_s.dtype == np.float64
    assert rec.warnings == []
    # defaults of absent keys
    assert rec.ccd_center_pix == 1024.0
    assert rec.ccd_range_pix == (0.0, 2048.0)
    assert rec.b_prior == (None, None)


def test_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    n = 500
    t = np.cumsum(rng.choice([0.5, 1.0, 1.25, 2.0, 0.001], n)) + 0.0
    m1 = 1000 + rng.normal(0, 30, n)
    m2 = 1000 + rng.normal(0, 30, n)
    tx = rng.normal(0, 100, n)
    ty = rng.normal(0, 18000, n)
    step = rng.integers(-1, 36, n)
    temp = 45 + rng.normal(0, 0.01, n)
    for a in (m1, m2, tx, ty, temp):
        a[rng.integers(0, n, 20)] = np.nan
    meta = {
        "serial": "46",
        "g_local_mgal": "981922.05",
        "site": "Санкт-Петербург, lab 3",
        "x_custom_key": "kept: as is",
        "ccd_range_pix": "12 2030",
        "b1_prior": "6.98",
    }
    rec = Record(meta, t, m1, m2, tx, ty, step, temp)
    p = tmp_path / "rt.csv"
    write_record(p, rec)
    text = p.read_text(encoding="utf-8")
    assert text.startswith("# format: chekan-record/1\n# serial: 46\n")
    back = read_record(p)
    assert back.meta == {"format": "chekan-record/1", **meta}
    assert list(back.meta) == ["format", *meta]
    np.testing.assert_allclose(back.t_s, t, atol=5e-4, rtol=0)
    for got, want, tol in (
        (back.m1_pix, m1, 5e-5),
        (back.m2_pix, m2, 5e-5),
        (back.tilt_x_arcsec, tx, 5e-3),
        (back.tilt_y_arcsec, ty, 5e-3),
        (back.temp_c, temp, 5e-4),
    ):
        assert np.array_equal(np.isnan(got), np.isnan(want))
        np.testing.assert_allclose(got, want, atol=tol * 1.0001, rtol=0)
    np.testing.assert_array_equal(back.step, step)
    assert back.ccd_range_pix == (12.0, 2030.0)
    assert back.b_prior == (6.98, None)
    # a second round trip is byte-identical
    write_record(tmp_path / "rt2.csv", back)
    assert (tmp_path / "rt2.csv").read_bytes() == p.read_bytes()


def test_number_formatting(tmp_path: Path) -> None:
    rec = Record(
        {"serial": "7", "g_local_mgal": "981000"},
        [0, 1.5, 2.25, 3.0004, 4.1239],
        [1.0, np.nan, 2.123456, -0.5, 3],
        [1, 2, 3, 4, 5],
        [0.125, np.nan, 1, 2, 3],
        [0, 0, 0, 0, 0],
        [0, -1, 3, 3, 4],
        None,
    )
    p = tmp_path / "f.csv"
    write_record(p, rec)
    lines = p.read_text().splitlines()
    assert lines[3] == "t_s,m1_pix,m2_pix,tilt_x_arcsec,tilt_y_arcsec,step"
    assert lines[4] == "0,1.0000,1.0000,0.12,0.00,0"
    assert lines[5] == "1.5,,2.0000,,0.00,"
    assert lines[6].startswith("2.25,2.1235,")
    assert lines[7].startswith("3,")
    assert lines[8].startswith("4.124,")
    assert read_record(p).temp_c is None


def test_columns_in_other_order_and_unknown_columns(tmp_path: Path) -> None:
    text = (
        "# format: chekan-record/1\n# g_local_mgal: 981922.05\n# serial: 46\n"
        "# some_future_key: 1\n"
        "note,step,tilt_y_arcsec,utc,m2_pix,t_s,tilt_x_arcsec,m1_pix\n"
        "hello world,0,-0.8,2015-07-09T06:00:00Z,1012.9020,0,0.3,1031.2214\n"
        "é,,-0.6,x,1012.8977,1,0.1,\n"
    )
    rec = read_record(put(tmp_path, text))
    assert rec.n == 2
    assert rec.temp_c is None
    np.testing.assert_array_equal(rec.t_s, [0, 1])
    np.testing.assert_array_equal(rec.m1_pix, [1031.2214, np.nan])
    np.testing.assert_array_equal(rec.m2_pix, [1012.9020, 1012.8977])
    np.testing.assert_array_equal(rec.tilt_x_arcsec, [0.3, 0.1])
    np.testing.assert_array_equal(rec.tilt_y_arcsec, [-0.8, -0.6])
    np.testing.assert_array_equal(rec.step, [0, -1])
    assert rec.meta["some_future_key"] == "1"


def test_crlf_bom_blank_trailing_lines(tmp_path: Path) -> None:
    text = ("\ufeff" + body(*ROWS)).replace("\n", "\r\n") + "\r\n  \r\n\n"
    rec = read_record(put(tmp_path, text))
    assert rec.n == 4 and rec.warnings == []
    assert rec.meta["format"] == "chekan-record/1"
    np.testing.assert_array_equal(rec.step, [0, 0, -1, 1])


def test_no_data_rows_is_valid(tmp_path: Path) -> None:
    rec = read_record(put(tmp_path, HEAD))
    assert rec.n == 0 and rec.t_s.shape == (0,) and rec.temp_c is not None
    rec = read_record(put(tmp_path, HEAD.rstrip("\n")))  # header without newline
    assert rec.n == 0


def test_last_line_without_newline_but_complete_is_kept(tmp_path: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_record(put(tmp_path, body(*ROWS, end="")))
    assert rec.n == 4 and rec.warnings == []


def test_exponents_and_blanks_take_the_slow_path_with_same_values(tmp_path: Path) -> None:
    rows = [
        "0, 1.0312214e3 ,1012.9020,3E-1,-0.8,0,45.002",
        "1.0,+1031.229,1012.8977,0.1,-6e-1, 0 ,45.002",
    ]
    rec = read_record(put(tmp_path, body(*rows)))
    np.testing.assert_array_equal(rec.m1_pix, [1031.2214, 1031.229])
    np.testing.assert_array_equal(rec.tilt_x_arcsec, [0.3, 0.1])
    np.testing.assert_array_equal(rec.tilt_y_arcsec, [-0.8, -0.6])
    np.testing.assert_array_equal(rec.step, [0, 0])


def test_fast_parser_agrees_with_float() -> None:
    rng = np.random.default_rng(7)
    n = 4000
    fields = []
    for _ in range(n):
        kind = rng.integers(0, 6)
        if kind == 0:
            s = ""
        elif kind == 1:
            s = f"{rng.normal(0, 10 ** rng.integers(0, 8)):.{rng.integers(0, 7)}f}"
        elif kind == 2:
            s = str(rng.integers(-(10**14), 10**14))
        elif kind == 3:
            s = rng.choice(["-0", "1.", ".5", "-.5", "000123.4500", "0.00000000000001"])
        elif kind == 4:
            digits = "".join(rng.choice(list("0123456789"), 15))
            k = rng.integers(0, 16)
            s = digits[:k] + "." + digits[k:]
        else:
            s = f"{rng.uniform(-1e5, 1e5):.4f}"
        fields.append(s)
    t = [str(i) for i in range(n)]
    lines = [f"{t[i]},{fields[i]},{fields[-i - 1]}" for i in range(n)]
    block = ("\n".join(lines) + "\n").encode()
    want = {"t_s": 0, "m1_pix": 1, "m2_pix": 2, "step": 0}
    fast = _fast_block(block, n, 3, want)
    slow, err = _slow_block(block, 3, want)
    assert fast is not None and err is None
    expect = np.array([float(s) if s else np.nan for s in fields])
    for name, arr in (("m1_pix", expect), ("m2_pix", expect[::-1])):
        assert np.array_equal(fast[name], arr, equal_nan=True)
        assert np.array_equal(slow[name], arr, equal_nan=True)
        # same sign of zero too
        assert np.array_equal(np.signbit(fast[name]), np.signbit(arr))


def test_max_rows(tmp_path: Path) -> None:
    p = put(tmp_path, body(*ROWS))
    assert read_record(p, max_rows=0).n == 0
    rec = read_record(p, max_rows=2)
    np.testing.assert_array_equal(rec.t_s, [0, 1])
    assert read_record(p, max_rows=100).n == 4


def test_33000_rows(tmp_path: Path) -> None:
    rec = _synthetic(33_000)
    p = tmp_path / "big.csv"
    t0 = time.perf_counter()
    write_record(p, rec)
    assert time.perf_counter() - t0 < 2.0
    t0 = time.perf_counter()
    back = read_record(p)
    elapsed = time.perf_counter() - t0
    assert back.n == 33_000
    assert back.t_s.sum() == 33_000 * 32_999 / 2
    assert np.isnan(back.m1_pix).sum() == np.isnan(rec.m1_pix).sum() > 0
    np.testing.assert_allclose(np.nansum(back.m1_pix), np.nansum(np.round(rec.m1_pix, 4)))
    np.testing.assert_allclose(back.m2_pix.sum(), np.round(rec.m2_pix, 4).sum())
    np.testing.assert_allclose(back.tilt_x_arcsec.sum(), np.round(rec.tilt_x_arcsec, 2).sum())
    np.testing.assert_allclose(back.temp_c.sum(), np.round(rec.temp_c, 3).sum())
    assert back.step.sum() == rec.step.sum()
    assert (back.step == -1).sum() == (rec.step == -1).sum() > 0
    assert elapsed < 1.5  # ~0.04 s on a laptop; generous for loaded CI machines


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    ("meta_line", "fragment"),
    [
        ("#serial: 46", "malformed metadata line"),
        ("# Serial: 46", "malformed metadata line"),
        ("# serial 46", "malformed metadata line"),
        ("# serial:46", "malformed metadata line"),
        ("#  serial: 46", "malformed metadata line"),
        ("# serial-no: 46", "malformed metadata line"),
    ],
)
def test_malformed_metadata_line(tmp_path: Path, meta_line: str, fragment: str) -> None:
    text = HEAD.replace("# serial: 46", meta_line)
    expect_error(put(tmp_path, text), 2, fragment)


def test_wrong_format(tmp_path: Path) -> None:
    p = put(tmp_path, HEAD.replace("chekan-record/1", "chekan-record/2"))
    expect_error(p, 1, "chekan-record/2", "expected 'chekan-record/1'")
    p = put(tmp_path, HEAD.replace("chekan-record/1", "chekan-protocol/1"))
    expect_error(p, 1, "chekan-protocol/1")


@pytest.mark.parametrize("key", ["format", "serial", "g_local_mgal"])
def test_missing_required_key(tmp_path: Path, key: str) -> None:
    lines = [ln for ln in body(*ROWS).splitlines() if not ln.startswith(f"# {key}:")]
    expect_error(put(tmp_path, "\n".join(lines) + "\n"), None, "missing required", repr(key))


def test_bad_g_local_and_duplicate_key(tmp_path: Path) -> None:
    expect_error(
        put(tmp_path, body(*ROWS).replace("981922.05", "9.8e5 mGal")),
        3,
        "g_local_mgal",
        "'9.8e5 mGal' is not a finite number",
    )
    text = HEAD.replace("# serial: 46\n", "# serial: 46\n# serial: 47\n")
    expect_error(put(tmp_path, text), 3, "duplicate metadata key 'serial'", "line 2")


@pytest.mark.parametrize(
    "column", ["t_s", "m1_pix", "m2_pix", "tilt_x_arcsec", "tilt_y_arcsec", "step"]
)
def test_missing_required_column(tmp_path: Path, column: str) -> None:
    header = ",".join(c for c in DEFAULT_COLUMNS if c != column)
    text = HEAD.replace(",".join(DEFAULT_COLUMNS), header)
    expect_error(put(tmp_path, text), 4, f"missing required column {column!r}")


def test_duplicate_column(tmp_path: Path) -> None:
    text = HEAD.replace(",temp_c", ",m1_pix")
    expect_error(put(tmp_path, text), 4, "duplicate column 'm1_pix'", "positions 2 and 7")


def test_no_header(tmp_path: Path) -> None:
    text = "# format: chekan-record/1\n# serial: 46\n# g_local_mgal: 1\n"
    expect_error(put(tmp_path, text), 4, "no column header")
    expect_error(put(tmp_path, text + "\n0,1,2,3,4,0,5\n"), 4, "found an empty line")
    expect_error(put(tmp_path, b""), None, "empty file")


@pytest.mark.parametrize(
    ("row", "fragment"),
    [
        ("2,1031.2251,1012.9103,-0.20,-0.70,", "row has 6 fields, header has 7"),
        ("2,1031.2251,1012.9103,-0.20,-0.70,0,45.003,9", "row has 8 fields, header has 7"),
        ("2,abc,1012.9103,-0.20,-0.70,0,45.003", "field m1_pix: 'abc' is not a number"),
        ("2,1031.2251,1012.9103,-0.20,-0.70,0,nan", "field temp_c: 'nan' is not a number"),
        ("2,1031.2251,1012.9103,1_0,-0.70,0,45", "field tilt_x_arcsec: '1_0' is not a number"),
        ("2,1031.2251,1012.9103,-0.20,1e999,0,45", "field tilt_y_arcsec: '1e999' is not a finite"),
        ("2,1031.2251,1012.9103,-0.20,-0.70,1.5,45", "field step: '1.5' is not a non-negative"),
        ("2,1031.2251,1012.9103,-0.20,-0.70,-1,45", "field step: '-1' is not a non-negative"),
        ("2,1031.2251,1012.9103,-0.20,-0.70,x,45", "field step: 'x' is not a non-negative"),
        (",1031.2251,1012.9103,-0.20,-0.70,0,45", "field t_s is empty"),
        ("inf,1031.2251,1012.9103,-0.20,-0.70,0,45", "field t_s: 'inf' is not a number"),
        ("0.5,1031.2251,1012.9103,-0.20,-0.70,0,45", "t_s goes backwards (0.5 after 1.0)"),
        ("", "empty line"),
        ("2;1031.2251;1012.9103;-0.20;-0.70;0;45", "row has 1 field, header has 7"),
    ],
)
def test_bad_row_in_the_middle(tmp_path: Path, row: str, fragment: str) -> None:
    rows = [*ROWS[:2], row, *ROWS[3:]]
    expect_error(put(tmp_path, body(*rows)), 7, fragment)


def test_time_backwards_message(tmp_path: Path) -> None:
    rows = ["1234,1,1,1,1,0,1", "1235,1,1,1,1,0,1", "1234,1,1,1,1,0,1", "1236,1,1,1,1,0,1"]
    expect_error(put(tmp_path, body(*rows)), 7, "t_s goes backwards (1234.0 after 1235.0)")


def test_error_in_last_line_with_newline_is_not_skipped(tmp_path: Path) -> None:
    rows = [*ROWS, "4,1031.2"]
    expect_error(put(tmp_path, body(*rows)), 9, "row has 2 fields, header has 7")


def test_first_error_wins_over_torn_last_line(tmp_path: Path) -> None:
    rows = [ROWS[0], "1,zz,1,1,1,0,1", *ROWS[2:], "4,1031.2"]
    expect_error(put(tmp_path, body(*rows, end="")), 6, "'zz' is not a number")


# --------------------------------------------------------------------------- incomplete last line


@pytest.mark.parametrize(
    ("tail", "why"),
    [
        ("4,1031.2", "row has 2 fields"),
        ("4,1031.2251,1012.9103,-0.20,-0.70,1,45.0-", "'45.0-' is not a number"),
        ("4,1031.2251,1012.9103,-0.2", "row has 4 fields"),
        ("2,1031.2251,1012.9103,-0.20,-0.70,1,45", "t_s goes backwards (2.0 after 3.0)"),
        ("4,1031.2251,1012.9103,-0.20,-0.70,1,\xe9", "'é' is not a number"),
    ],
)
def test_incomplete_last_line_is_skipped(tmp_path: Path, tail: str, why: str) -> None:
    p = put(tmp_path, body(*ROWS, tail, end=""))
    with pytest.warns(IncompleteLineWarning, match="incomplete last line skipped") as rec_w:
        rec = read_record(p)
    assert rec.n == 4
    np.testing.assert_array_equal(rec.t_s, [0, 1, 2, 3])
    assert len(rec.warnings) == 1
    assert f"{p}:9:" in rec.warnings[0] and why in rec.warnings[0]
    assert str(rec_w[0].message) == rec.warnings[0]


def test_torn_utf8_in_last_line(tmp_path: Path) -> None:
    raw = body(*ROWS).encode() + b"5,1,1,1,1,1," + b"\xd0"
    with pytest.warns(IncompleteLineWarning):
        rec = read_record(put(tmp_path, raw))
    assert rec.n == 4


@pytest.mark.parametrize(
    "tail",
    [b"\0" * 512, b"\0" * 512 + b"\n", b"4,1031.2\0\0\0\0", b"4,1031.2251,1012.9103,-0.20,-0.7\0"],
)
def test_nul_padded_last_line_is_skipped(tmp_path: Path, tail: bytes) -> None:
    p = put(tmp_path, body(*ROWS).encode() + tail)
    with pytest.warns(IncompleteLineWarning, match=r"rec\.csv:9: incomplete last line"):
        rec = read_record(p)
    assert rec.n == 4 and len(rec.warnings) == 1


def test_incomplete_line_in_the_middle_is_an_error(tmp_path: Path) -> None:
    rows = [ROWS[0], "1,1031.2", *ROWS[2:]]
    expect_error(put(tmp_path, body(*rows, end="")), 6, "row has 2 fields")
    raw = body(ROWS[0]).encode() + b"\0\0\0\n" + body(*ROWS[1:]).split(HEAD)[1].encode()
    expect_error(put(tmp_path, raw), 6, "row has 1 field,")


# --------------------------------------------------------------------------- properties


def test_meta_properties_validate_lazily(tmp_path: Path) -> None:
    text = HEAD.replace(
        "# g_local_mgal: 981922.05\n",
        "# g_local_mgal: 981922.05\n# ccd_range_pix: 0 to 2048\n# sample_rate_hz: fast\n"
        "# b2_prior: 6.88\n# ccd_center_pix: 1000.5\n# started: yesterday\n",
    )
    rec = read_record(put(tmp_path, text + ROWS[0] + "\n"))  # unparsed until asked
    assert rec.n == 1
    with pytest.raises(FormatError, match=r"rec\.csv:4: metadata ccd_range_pix"):
        _ = rec.ccd_range_pix
    with pytest.raises(FormatError, match=r"rec\.csv:5: metadata sample_rate_hz"):
        _ = rec.sample_rate_hz
    with pytest.raises(FormatError, match=r"rec\.csv:8: metadata started"):
        _ = rec.started
    assert rec.b_prior == (None, 6.88)
    assert rec.ccd_center_pix == 1000.5


def test_record_constructor_checks_lengths() -> None:
    with pytest.raises(ValueError, match="m2_pix has 2 values"):
        Record(
            {"serial": "1", "g_local_mgal": "1"},
            [0, 1, 2],
            [1, 2, 3],
            [1, 2],
            [0] * 3,
            [0] * 3,
            [0] * 3,
        )


# --------------------------------------------------------------------------- RecordWriter


META = {"serial": "46", "g_local_mgal": "981922.05", "started": "2015-07-09T06:00:00Z"}


def test_writer_streams_rows(tmp_path: Path) -> None:
    p = tmp_path / "live.csv"
    with RecordWriter(p, META, fsync_interval_s=0.0) as w:
        w.write_row(0, 1031.2214, 1012.902, 0.3, -0.8, 0, 45.002)
        # every line is on disk (flushed) before close
        assert p.read_text().endswith("0,1031.2214,1012.9020,0.30,-0.80,0,45.002\n")
        w.write_row(1, None, float("nan"), 0.1, -0.6, None, None)
        w.write_rows([2, 3], [1.0, 2.0], [3.0, 4.0], [0, 0], [0, 0], [1, np.nan], [45, np.nan])
        with pytest.raises(ValueError, match="backwards"):
            w.write_row(2.5, 1, 1, 1, 1, 1, 1)
    assert w.closed
    rec = read_record(p)
    assert rec.n == 4 and rec.meta["started"] == META["started"]
    assert next(iter(rec.meta)) == "format"
    np.testing.assert_array_equal(rec.step, [0, -1, 1, -1])
    assert np.isnan(rec.m1_pix[1]) and np.isnan(rec.temp_c[1]) and np.isnan(rec.temp_c[3])
    with pytest.raises(FileExistsError):
        RecordWriter(p, META)


def test_writer_rejects_bad_meta(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="g_local_mgal"):
        RecordWriter(tmp_path / "a.csv", {"serial": "1"})
    with pytest.raises(ValueError, match="lower case"):
        RecordWriter(tmp_path / "b.csv", {**META, "Bad Key": "1"})
    with pytest.raises(ValueError, match="one line"):
        RecordWriter(tmp_path / "c.csv", {**META, "site": "a\nb"})
    assert not list(tmp_path.iterdir())


def test_append_after_torn_line_keeps_everything(tmp_path: Path) -> None:
    p = tmp_path / "run.csv"
    with RecordWriter(p, META) as w:
        for i in range(5):
            w.write_row(i, 1031 + i / 10, 1012, 0.1, 0.2, 0, 45)
    torn = b"5,1031.5000,1012.00"
    with open(p, "ab") as f:
        f.write(torn)
    with pytest.warns(IncompleteLineWarning):
        assert read_record(p).n == 5
    with RecordWriter(p, None, append=True) as w:
        assert w.torn_path == f"{p}.torn-1"
        assert w.last_t == 4.0
        with pytest.raises(ValueError, match="backwards"):
            w.write_row(3, 1, 1, 1, 1, 1, 1)
        w.write_row(5, 1031.5, 1012, 0.1, 0.2, 1, 45)
        w.write_rows(
            np.arange(6, 10), np.full(4, 1031.0), np.full(4, 1012.0), *np.zeros((3, 4)), None
        )
    assert Path(f"{p}.torn-1").read_bytes() == torn
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_record(p)
    np.testing.assert_array_equal(rec.t_s, np.arange(10))
    np.testing.assert_array_equal(rec.step, [0] * 5 + [1] + [0] * 4)
    assert np.isnan(rec.temp_c[6:]).all()
    # a second crash: a NUL-padded tail goes to .torn-2
    with open(p, "ab") as f:
        f.write(b"\0" * 64)
    with RecordWriter(p, {"serial": "46"}, append=True) as w:
        assert w.torn_path == f"{p}.torn-2"
        w.write_row(10, 1, 1, 1, 1, 2, 1)
    assert Path(f"{p}.torn-2").read_bytes() == b"\0" * 64
    assert read_record(p).n == 11


def test_append_checks_header_and_meta(tmp_path: Path) -> None:
    p = put(tmp_path, body(*ROWS))
    with pytest.raises(FormatError, match="columns"):
        RecordWriter(p, None, append=True, columns=DEFAULT_COLUMNS[:6])
    with pytest.raises(ValueError, match="differs"):
        RecordWriter(p, {"serial": "47"}, append=True)
    with pytest.raises(ValueError, match="not in the existing record"):
        RecordWriter(p, {"site": "x"}, append=True)
    h = put(tmp_path, HEAD.rstrip("\n"), "header_only.csv")  # complete header, no newline
    with RecordWriter(h, None, append=True) as w:
        assert w.torn_path is None
        w.write_row(0, 1, 1, 1, 1, 0, 1)
    assert read_record(h).n == 1
    torn_header = put(tmp_path, HEAD[:-20], "torn_header.csv")
    with pytest.raises(FormatError, match="columns"):
        RecordWriter(torn_header, None, append=True)
    q = tmp_path / "new.csv"
    with RecordWriter(q, META, append=True) as w:  # append to a missing file starts it
        w.write_row(0, 1, 1, 1, 1, 0)
    assert read_record(q).n == 1


def test_write_record_is_atomic(tmp_path: Path) -> None:
    p = put(tmp_path, body(*ROWS))
    before = p.read_bytes()
    bad = Record(
        {"serial": "1", "g_local_mgal": "1"}, [1, 0], [1, 1], [1, 1], [0, 0], [0, 0], [0, 0]
    )
    with pytest.raises(ValueError, match="backwards"):
        write_record(p, bad)
    assert p.read_bytes() == before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["rec.csv"]


# --------------------------------------------------------------------------- inputs


def test_read_input_dispatches(tmp_path: Path) -> None:
    p = put(tmp_path, SPEC_EXAMPLE)
    assert input_kind(p) == "record"
    assert isinstance(read_input(p), Record)
    q = put(tmp_path, HEAD.replace("chekan-record/1", "chekan-result/1"), "x.csv")
    with pytest.raises(FormatError, match=r"x\.csv:1: unknown format 'chekan-result/1'"):
        read_input(q)
    r = put(tmp_path, "t_s,m1_pix\n0,1\n", "plain.csv")
    with pytest.raises(FormatError, match=r"plain\.csv: no '# format:'"):
        input_kind(r)


def test_bench_runs(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    from bench.records_bench import main as _bench

    p = put(tmp_path, SPEC_EXAMPLE)
    _bench([str(p)])
    out = capsys.readouterr().out
    assert "rows/s" in out and "3 rows" in out
    assert math.isfinite(float(out.split(":")[-1].split()[0].replace(",", "")))
