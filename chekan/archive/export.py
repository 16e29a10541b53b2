r"""The scale-factor history of one gravimeter as dated periods, for survey software.

``chekan history SERIAL --export gravtools|csv FILE`` (:func:`write_export`).

**Periods.** Each archived verification (one value per input, chosen as the history
chooses it: :func:`chekan.archive.history.select_points`) starts a period on its date; the
period ends the day before the next verification's date, and the last one on
``valid_until`` (default :data:`OPEN_END`, GravTools' own date for "no end"). Periods are
inclusive at both ends and never overlap, as GravTools requires. Verifications of one
date are one period whose b is their inverse-variance weighted mean, its sd widened by the
Birge ratio :math:`\max(1, \sqrt{\chi^2/(n-1)})` where they disagree; the comment names
them all.

**gravtools**: BEV GravTools' gravimeter file: a JSON list of gravimeters, each with
``type``, ``manufacturer``, ``serial_number``, ``code``, ``height_offset_m`` (a float),
``description`` (strings) and ``calibration``, a list of periods ``start_date``,
``end_date`` (``YYYY-MM-DD``, UTC dates), ``linear_factor`` (a number) and ``comment``.
GravTools scales a reading g of an epoch whose date lies in a period as
``g_scaled = linear_factor × g``: the factor is dimensionless. A Chekan-AM reads a
position m on its CCD (pix), and its gravity increment is Δg = b·Δm + a·Δm² (the
quadratic term is not carried: GravTools has no place for it), so a reading in mGal exists
only through a scale chosen to convert the pixels, :math:`b_\text{ref}`; chekan exports

.. math::

   \text{linear\_factor} = b_k / b_\text{ref}\quad
   (\text{then } \text{linear\_factor} \times b_\text{ref}\,\Delta m = b_k\,\Delta m),

:math:`b_k` the system's scale factor (mGal/pix) of the period, :math:`b_\text{ref}` the
scale with which the survey's pixel readings were converted to mGal (``reference_b``; default the
first period's b, so that the first factor is 1 and the others are its changes); the file's
description states it. GravTools keeps one linear factor per gravimeter, and a Chekan-AM
has two quartz systems: a file carries one (``system``), named in its description.

**csv**: one row per period with both systems' b and sd (mGal/pix, ``repr``: exact round
trip; empty where a verification has no value), method, sessions, record SHA-256 and a
comment (:data:`CSV_COLUMNS`; several sessions or hashes are separated by ``;``).

An existing output file is replaced only by an export of the same kind
(:func:`check_export`): never a gravimeter file edited by hand or written by
another program, which may hold other instruments.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from chekan.errors import ChekanError

FORMATS = ("gravtools", "csv")
SYSTEMS = (1, 2)
#: GravTools' end date of a period without end (``settings.DEFAULT_CALIBRATION_END_DATE``).
OPEN_END = _dt.date(2100, 1, 1)
INSTRUMENT_TYPE = "Chekan-AM"
MANUFACTURER = "CSRI Elektropribor"
#: GravTools' one-letter code of an instrument type it does not know.
UNKNOWN_CODE = "?"
#: Start of every gravimeter description chekan writes: how an export is told from other files.
GRAVTOOLS_MARK = "chekan export (gravtools):"
CSV_COLUMNS = (
    "serial",
    "start_date",
    "end_date",
    "b1_mgal_per_pix",
    "b1_sd_mgal_per_pix",
    "b2_mgal_per_pix",
    "b2_sd_mgal_per_pix",
    "method",
    "session_ids",
    "record_sha256",
    "comment",
)
_FACTOR_DECIMALS = 10  # 1e-10 of the factor: far below any verification's sd
_SNIFF_BYTES = 1 << 20


@dataclass(frozen=True)
class Verification:
    """The verifications of one date: per system ``b{k}`` its (mean, sd) in mGal/pix."""

    date: _dt.date
    b: dict[str, tuple[float, float]]
    methods: tuple[str, ...]
    session_ids: tuple[int, ...]
    record_sha256: tuple[str, ...]
    merged: dict[str, int] = field(default_factory=dict)  # b{k}: sessions averaged (> 1)


@dataclass(frozen=True)
class Period:
    start: _dt.date
    end: _dt.date
    verification: Verification


def _weighted(values: list[tuple[float, float]]) -> tuple[float, float]:
    """Inverse-variance weighted mean and its sd, widened by the Birge ratio (n > 1)."""
    w = [1.0 / s**2 for _, s in values]
    mean = sum(wi * v for wi, (v, _) in zip(w, values, strict=True)) / sum(w)
    sd = 1.0 / math.sqrt(sum(w))
    if len(values) > 1:
        chi2 = sum(wi * (v - mean) ** 2 for wi, (v, _) in zip(w, values, strict=True))
        sd *= max(1.0, math.sqrt(chi2 / (len(values) - 1)))
    return mean, sd


def verifications(
    archive, serial: str, *, method: str | None = None
) -> tuple[list[Verification], list[str]]:
    """The dated verifications of ``serial`` (b1, b2), oldest first, and the selection's notes."""
    from chekan.archive.history import select_points

    rows = archive.parameter_rows(str(serial))
    if not rows:
        raise ChekanError(f"archive {archive.path}: no sessions of instrument {serial!r}")
    sha = {r["session_id"]: r["input_sha256"] for r in rows}
    points, notes = select_points(rows, ("b1", "b2"), method)
    by_date: dict[str, dict[str, list]] = {}
    for name, pts in points.items():
        for p in pts:
            by_date.setdefault(p.date, {}).setdefault(name, []).append(p)
    out = []
    for date in sorted(by_date):
        named = by_date[date]
        pts = sorted(
            {p.session_id: p for ps in named.values() for p in ps}.values(),
            key=lambda p: p.session_id,
        )
        out.append(
            Verification(
                date=_dt.date.fromisoformat(date),
                b={k: _weighted([(p.mean, p.sd) for p in ps]) for k, ps in sorted(named.items())},
                methods=tuple(dict.fromkeys(p.method for p in pts)),
                session_ids=tuple(p.session_id for p in pts),
                record_sha256=tuple(dict.fromkeys(sha[p.session_id] for p in pts)),
                merged={k: len(ps) for k, ps in named.items() if len(ps) > 1},
            )
        )
    return out, notes


def periods(verifs: list[Verification], valid_until: _dt.date | None = None) -> list[Period]:
    """Each verification from its date to the day before the next; the last to ``valid_until``."""
    end = valid_until or OPEN_END
    vs = sorted(verifs, key=lambda v: v.date)
    if vs and end < vs[-1].date:
        raise ChekanError(
            f"--valid-until {end.isoformat()} is before the last verification "
            f"({vs[-1].date.isoformat()}): the last period would end before it starts"
        )
    out = []
    for i, v in enumerate(vs):
        stop = vs[i + 1].date - _dt.timedelta(days=1) if i + 1 < len(vs) else end
        out.append(Period(v.date, stop, v))
    return out


def _describe(v: Verification, key: str) -> str:
    """``b1 = 6.982462 ± 0.00050 mGal/pix`` with its sessions, method and records."""
    mean, sd = v.b[key]
    merged = f", weighted mean of {v.merged[key]} verifications" if key in v.merged else ""
    return (
        f"{key} = {mean:.7g} ± {sd:#.2g} mGal/pix (standard uncertainty{merged}; method "
        f"{'+'.join(v.methods)}, session {', '.join(map(str, v.session_ids))}, record sha256 "
        f"{'; '.join(v.record_sha256)})"
    )


def gravtools_document(
    serial: str,
    verifs: list[Verification],
    *,
    system: int,
    reference_b: float | None = None,
    height_offset_m: float | None = None,
    valid_until: _dt.date | None = None,
) -> tuple[list[dict[str, Any]], list[str]]:
    """GravTools' gravimeter file (a list of one gravimeter) for quartz ``system``, and notes."""
    key = f"b{system}"
    notes = []
    have = [v for v in verifs if key in v.b]
    for v in verifs:
        if key not in v.b:
            notes.append(f"verification {v.date.isoformat()} has no {key}: not in the export")
    if not have:
        raise ChekanError(f"instrument {serial!r}: no verification gives {key} with an sd")
    per = periods(have, valid_until)
    if reference_b is None:
        b_ref = per[0].verification.b[key][0]
        ref_of = f"{key} of the first verification, {per[0].start.isoformat()}"
    else:
        b_ref, ref_of = float(reference_b), "given"
    notes.append(f"linear_factor = {key}/b_ref with b_ref = {b_ref:.7g} mGal/pix ({ref_of})")
    if height_offset_m is None:
        notes.append(
            "height_offset_m written as 0.0: chekan does not know the offset between the "
            "instrument's top and its sensor; give --height-offset-m"
        )
    calibration = [
        {
            "start_date": p.start.isoformat(),
            "end_date": p.end.isoformat(),
            "linear_factor": round(p.verification.b[key][0] / b_ref, _FACTOR_DECIMALS),
            "comment": f"verification {p.start.isoformat()}: {_describe(p.verification, key)}",
        }
        for p in per
    ]
    description = (
        f"{GRAVTOOLS_MARK} {INSTRUMENT_TYPE} no. {serial}, quartz system {system}. "
        f"linear_factor = {key}/b_ref with b_ref = {b_ref!r} mGal/pix ({ref_of}): the scale "
        "with which the pixel readings were converted to the readings (mGal) that the factor "
        f"multiplies. Quadratic term not included. Last period ends {per[-1].end.isoformat()}"
        + (" (no end known)." if valid_until is None else ".")
    )
    doc = {
        "type": INSTRUMENT_TYPE,
        "manufacturer": MANUFACTURER,
        "serial_number": str(serial),
        "code": UNKNOWN_CODE,
        "height_offset_m": float(height_offset_m or 0.0),
        "description": description,
        "calibration": calibration,
    }
    return [doc], notes


def csv_text(serial: str, verifs: list[Verification], valid_until: _dt.date | None = None) -> str:
    """The CSV export (:data:`CSV_COLUMNS`), both systems, one row per period."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for p in periods(verifs, valid_until):
        v = p.verification
        cells: list[str] = [str(serial), p.start.isoformat(), p.end.isoformat()]
        for key in ("b1", "b2"):
            cells += [repr(x) for x in v.b[key]] if key in v.b else ["", ""]
        comment = "; ".join(
            f"{k}: weighted mean of {n} verifications of this date" for k, n in v.merged.items()
        )
        cells += [
            "+".join(v.methods),
            ";".join(map(str, v.session_ids)),
            ";".join(v.record_sha256),
            comment or f"verification {p.start.isoformat()}",
        ]
        w.writerow(cells)
    return buf.getvalue()


def _is_export(path: Path, fmt: str) -> bool:
    """Whether the existing ``path`` is a chekan export in ``fmt`` (read at most 1 MB)."""
    try:
        with open(path, "rb") as f:
            head = f.read(_SNIFF_BYTES)
    except OSError:
        return False
    text = head.decode("utf-8", "replace").lstrip("\ufeff")
    if fmt == "csv":
        return text.split("\n", 1)[0].rstrip("\r") == ",".join(CSV_COLUMNS)
    try:
        doc = json.loads(text)
    except ValueError:
        return False
    return (
        isinstance(doc, list)
        and len(doc) > 0
        and all(
            isinstance(g, dict) and str(g.get("description", "")).startswith(GRAVTOOLS_MARK)
            for g in doc
        )
    )


def check_export(
    path: str | Path,
    fmt: str,
    *,
    system: int | None = None,
    reference_b: float | None = None,
    height_offset_m: float | None = None,
) -> None:
    """Refuse, before any work, what cannot be exported: an unknown format, options of the
    other format, a GravTools file without ``system``, and an existing ``path`` that is not
    a chekan ``fmt`` export."""
    if fmt not in FORMATS:
        raise ChekanError(f"--export: unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if fmt != "gravtools":
        given = [
            o
            for o, v in (
                ("--system", system),
                ("--reference-b", reference_b),
                ("--height-offset-m", height_offset_m),
            )
            if v is not None
        ]
        if given:
            raise ChekanError(
                f"{', '.join(given)}: for --export gravtools only (the {fmt} export carries "
                "both systems' b itself)"
            )
    elif system not in SYSTEMS:
        raise ChekanError(
            "--export gravtools: GravTools keeps one linear factor per gravimeter and a "
            "Chekan-AM has two quartz systems; choose one with --system 1 or --system 2"
        )
    p = Path(path)
    if p.is_dir():
        raise ChekanError(f"{p}: is a folder; --export needs a file name")
    if p.exists() and not _is_export(p, fmt):
        if fmt == "gravtools":
            what = "a GravTools gravimeter file written by chekan"
            why = "a gravimeter file may hold other instruments and values set by hand"
        else:
            what, why = "a CSV export of chekan", "it is another program's or a person's file"
        raise ChekanError(
            f"{p}: exists and is not {what}: refusing to overwrite it ({why}); choose "
            "another output file"
        )


def write_export(
    path: str | Path,
    fmt: str,
    archive,
    serial: str,
    *,
    method: str | None = None,
    system: int | None = None,
    reference_b: float | None = None,
    height_offset_m: float | None = None,
    valid_until: _dt.date | None = None,
) -> tuple[Path, list[str]]:
    """Write the ``fmt`` export of ``serial``'s history to ``path``; returns it and notes."""
    from chekan.files.durable import atomic_output

    check_export(path, fmt, system=system, reference_b=reference_b, height_offset_m=height_offset_m)
    verifs, notes = verifications(archive, serial, method=method)
    if not verifs:
        raise ChekanError(f"instrument {serial!r}: no dated verification with b1 or b2 to export")
    if fmt == "gravtools":
        doc, more = gravtools_document(
            serial,
            verifs,
            system=int(system or 0),
            reference_b=reference_b,
            height_offset_m=height_offset_m,
            valid_until=valid_until,
        )
        text = json.dumps(doc, indent=2, ensure_ascii=False) + "\n"
        notes = notes + more
    else:
        text = csv_text(serial, verifs, valid_until)
    path = Path(path)
    with atomic_output(path, newline="") as f:
        f.write(text)
    return path, notes
