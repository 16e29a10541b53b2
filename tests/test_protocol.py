"""Tests of the chekan-protocol/1 reader (chekan.records.protocol) and its dispatch in
chekan.records.inputs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from chekan.errors import FormatError
from chekan.records import IncompleteLineWarning
from chekan.records.inputs import input_kind, read_input
from chekan.records.protocol import Protocol, read_protocol

REFERENCE = Path(__file__).resolve().parents[1] / "examples" / "calibr_46_protocol.csv"

HEAD = """\
# format: chekan-protocol/1
# serial: 46
# a_mgal_per_pix2: 7.828e-5
# b_r1_s1: 6.980343
# b_r1_s2: 6.882650
angle,da_ref_mgal,dg_r1_s1,dg_r1_s2
"""  # header is line 6; the first row is line 7

ROWS = [
    "1°50',502.63,504.05,503.64",
    "2°30',934.57,935.07,934.51",
    "3°10',1499.32,1499.88,1499.11",
]


def put(tmp_path: Path, text: str | bytes, name: str = "prot.csv") -> Path:
    """Write ``text`` byte for byte and return the path."""
    p = tmp_path / name
    p.write_bytes(text.encode("utf-8") if isinstance(text, str) else text)
    return p


def body(*rows: str, head: str = HEAD, end: str = "\n") -> str:
    """``head`` followed by rows joined by newlines, then ``end``."""
    return head + "\n".join(rows) + end


def expect_error(path: Path, line: int | None, *fragments: str) -> None:
    """Reading ``path`` raises a FormatError at ``line`` naming the file and every fragment."""
    with pytest.raises(FormatError) as info:
        read_protocol(path)
    msg = str(info.value)
    assert info.value.line == line, msg
    assert msg.startswith(f"{path}:{line}:" if line is not None else f"{path}:"), msg
    for frag in fragments:
        assert frag in msg, msg


@pytest.fixture
def reference() -> Protocol:
    return read_protocol(REFERENCE)


def test_reference_protocol(reference: Protocol) -> None:
    p = reference
    assert p.serial == "46"
    assert p.n == 8 and p.angle_deg.shape == (8,)
    assert p.angle_text[0] == "1°50'" and p.angle_text[7] == "5°10'"
    assert p.angle_deg[7] == pytest.approx(5 + 10 / 60, abs=1e-12)
    assert p.angle_deg[7] == pytest.approx(5.1666667, abs=1e-6)
    assert p.da_ref_mgal[0] == 502.63
    assert p.da_ref_mgal[-1] == 3989.59
    assert p.rounds == (1, 2) and p.systems == (1, 2)
    assert p.dg_mgal.shape == (2, 2, 8)
    assert p.dg_mgal[0, 0, 0] == 504.05
    assert p.dg_mgal[0, 1, 0] == 503.64
    assert p.dg_mgal[1, 0, 7] == 3989.74
    assert p.dg_mgal[1, 1, 7] == 3990.58
    assert p.b_mgal_per_pix.shape == (2, 2)
    assert p.b_mgal_per_pix[1, 1] == 6.881965
    assert p.b_mgal_per_pix[0, 0] == 6.980343
    assert p.a_mgal_per_pix2 == 7.828e-5
    assert p.g_local_mgal is None
    assert p.g_local_or_fitted() == pytest.approx(981922.05, abs=0.05)
    assert p.meta["platform_serial"] == "123456"
    assert p.warnings == []


def test_reference_via_read_input(reference: Protocol) -> None:
    assert input_kind(REFERENCE) == "protocol"
    q = read_input(REFERENCE)
    assert isinstance(q, Protocol)
    np.testing.assert_array_equal(q.dg_mgal, reference.dg_mgal)


@pytest.mark.parametrize(
    "text", ["5°10'", "5°10'00\"", "5d10m", "5d10m0s", "5°10′", "±5°10'", "-5°10'", "5.16666666667"]
)
def test_angle_notations(tmp_path: Path, text: str) -> None:
    p = read_protocol(put(tmp_path, body(f"{text},3989.59,3988.84,3990.67")))
    assert p.angle_deg[0] == pytest.approx(5 + 10 / 60, abs=1e-9)
    assert p.angle_text == [text]


def test_g_local_from_metadata_and_fit(tmp_path: Path) -> None:
    head = HEAD.replace("# serial: 46\n", "# serial: 46\n# g_local_mgal: 981900.5\n")
    p = read_protocol(put(tmp_path, body(*ROWS, head=head)))
    assert p.g_local_mgal == 981900.5 and p.g_local_or_fitted() == 981900.5
    # exact synthetic table: the fit recovers g
    g = 981234.5
    rows = [f"{a},{g * 2 * math.sin(math.radians(a) / 2) ** 2!r},1,1" for a in (1.0, 2.5, 5.0)]
    q = read_protocol(put(tmp_path, body(*rows), "fit.csv"))
    assert q.g_local_or_fitted() == pytest.approx(g, rel=1e-12)


def test_partial_table_empty_cells_unknown_columns(tmp_path: Path) -> None:
    head = (
        "# format: chekan-protocol/1\n# serial: 7\n# a_mgal_per_pix2: 0\n"
        "# b_r2_s1: 7.0\n# b_r1_s1: 6.9\n# b_r9_s9: 1\n# operator: someone\n"
        "remark,dg_r2_s1,angle,dg_r1_s1,da_ref_mgal\n"
    )
    rows = ["ok,503.06,1°50',,502.63", "bad day,934.85,2°30',935.07,934.57"]
    p = read_protocol(put(tmp_path, body(*rows, head=head)))
    assert p.rounds == (1, 2) and p.systems == (1,)
    assert p.dg_mgal.shape == (2, 1, 2)
    np.testing.assert_array_equal(p.dg_mgal[0, 0], [np.nan, 935.07])
    np.testing.assert_array_equal(p.dg_mgal[1, 0], [503.06, 934.85])
    np.testing.assert_array_equal(p.b_mgal_per_pix, [[6.9], [7.0]])
    assert p.meta["b_r9_s9"] == "1" and p.meta["operator"] == "someone"


def test_crlf_and_bom(tmp_path: Path) -> None:
    text = "\ufeff" + body(*ROWS).replace("\n", "\r\n") + "\r\n"
    p = read_protocol(put(tmp_path, text))
    assert p.n == 3 and p.serial == "46"


# --------------------------------------------------------------------------- errors


def test_wrong_format(tmp_path: Path) -> None:
    expect_error(
        put(tmp_path, body(*ROWS).replace("chekan-protocol/1", "chekan-record/1")),
        1,
        "format is 'chekan-record/1', expected 'chekan-protocol/1'",
    )


@pytest.mark.parametrize("key", ["serial", "a_mgal_per_pix2", "format"])
def test_missing_required_key(tmp_path: Path, key: str) -> None:
    text = "".join(ln for ln in body(*ROWS).splitlines(True) if not ln.startswith(f"# {key}:"))
    expect_error(put(tmp_path, text), None, "missing required metadata key", repr(key))


def test_non_numeric_a(tmp_path: Path) -> None:
    text = body(*ROWS).replace("7.828e-5", "7.8x")
    expect_error(put(tmp_path, text), 3, "a_mgal_per_pix2", "'7.8x'")


def test_dg_column_without_b_names_both(tmp_path: Path) -> None:
    text = body(*ROWS).replace("# b_r1_s2: 6.882650\n", "")
    expect_error(put(tmp_path, text), 5, "'dg_r1_s2'", "'b_r1_s2'")


@pytest.mark.parametrize(
    ("header", "fragment"),
    [
        ("ang,da_ref_mgal,dg_r1_s1,dg_r1_s2", "missing required column 'angle'"),
        ("angle,da_ref,dg_r1_s1,dg_r1_s2", "missing required column 'da_ref_mgal'"),
        ("angle,da_ref_mgal,dg1,dg2", "no measured-increment columns"),
        ("angle,da_ref_mgal,dg_r1_s1,dg_r1_s1", "duplicate column 'dg_r1_s1'"),
        ("angle,da_ref_mgal,dg_r1_s1,dg_r01_s1", "same round and system"),
    ],
)
def test_bad_header(tmp_path: Path, header: str, fragment: str) -> None:
    text = body(*ROWS).replace("angle,da_ref_mgal,dg_r1_s1,dg_r1_s2", header)
    expect_error(put(tmp_path, text), 6, fragment)


@pytest.mark.parametrize(
    ("row", "fragment"),
    [
        ("2°70',934.57,935.07,934.51", 'field angle: not an angle: "2°70\'"'),
        ("two degrees,934.57,935.07,934.51", "not an angle"),
        (",934.57,935.07,934.51", "field angle is empty"),
        ("2°30',934.57 mGal,935.07,934.51", "field da_ref_mgal: '934.57 mGal' is not a number"),
        ("2°30',,935.07,934.51", "field da_ref_mgal is empty"),
        ("2°30',934.57,935,07,934.51", "row has 5 fields, header has 4"),
        ("2°30',934.57,935.07", "row has 3 fields, header has 4"),
        ("2°30',934.57,abc,934.51", "field dg_r1_s1: 'abc' is not a number"),
        ("2°30',934.57,935.07,inf", "field dg_r1_s2: 'inf' is not a number"),
    ],
)
def test_bad_row(tmp_path: Path, row: str, fragment: str) -> None:
    expect_error(put(tmp_path, body(ROWS[0], row, ROWS[2])), 8, fragment)


def test_bad_last_line_with_newline_is_an_error(tmp_path: Path) -> None:
    expect_error(put(tmp_path, body(*ROWS, "3°40',2010.00")), 10, "row has 2 fields")


def test_no_rows(tmp_path: Path) -> None:
    expect_error(put(tmp_path, HEAD), None, "no data rows")


@pytest.mark.parametrize("tail", [b"3\xc2\xb040',2010.0", b"3\xc2", b"\0" * 100])
def test_incomplete_last_line_is_skipped(tmp_path: Path, tail: bytes) -> None:
    path = put(tmp_path, body(*ROWS).encode() + tail)
    with pytest.warns(IncompleteLineWarning, match=r"prot\.csv:10: incomplete last line"):
        p = read_protocol(path)
    assert p.n == 3 and len(p.warnings) == 1
    assert p.dg_mgal.shape == (1, 2, 3)
