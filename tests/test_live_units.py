"""The live page's units and clock in a real browser under an en-US locale (issue 57 §5)."""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import threading
from pathlib import Path

import numpy as np
import pytest

from chekan.live import calib
from chekan.live.state import LiveState

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--lang=en-US",
]
STOP_UTC = "2026-11-25T14:05:41.0Z"  # an afternoon: en-US would print "09:05 AM" in New York


class _MapAtOnce(calib.MapRunner):
    """The page worker's job run in this process at once (calib.estimate_map patched)."""

    def submit(self, round_no, record):
        self.results.append(calib._map_job(record, round_no))


def _journal_of(rec, path: Path) -> None:
    """A journal of ``rec`` as ``acquire`` writes it: each step done, the run completed at
    ``STOP_UTC``."""
    events = [{"event": "run_start", "utc": "2026-11-25T11:00:00.0Z", "plan": []}]
    for k in np.unique(rec.step[rec.step >= 0]):
        t = float(rec.t_s[rec.step == k][-1])
        events.append({"event": "step_done", "step": int(k), "t_s": t})
    events.append({"event": "run_stop", "utc": STOP_UTC, "status": "completed", "exit_code": 0})
    Path(f"{path}.journal.jsonl").write_text(
        "".join(json.dumps(e) + "\n" for e in events), encoding="utf-8"
    )


def _sci_value(cell: str) -> tuple[float, float]:
    """(mean, sd) of a cell written as the console writes a: ``1.2693e-04 ± 2.70e-06``."""
    m = re.fullmatch(r"(-?\d\.\d{4}e[+-]\d\d) ± (\d\.\d\de[+-]\d\d)", cell.strip())
    assert m, cell
    return float(m[1]), float(m[2])


@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} absent (make browser)")
@pytest.mark.timeout(300)
def test_a_in_mgal_per_pix2_dg_with_units_and_a_24_hour_utc_clock(
    short_session, tmp_path, monkeypatch
):
    sync_api = pytest.importorskip("playwright.sync_api")
    from chekan.live.server import LiveServer
    from chekan.pipeline import CalibrationOptions, calibrate
    from chekan.records import read_record

    path, rec, _ = short_session
    mine = tmp_path / "rec.csv"
    shutil.copyfile(path, mine)
    _journal_of(rec, mine)
    result = calibrate(read_record(mine), CalibrationOptions(method="classical", progress=False))
    a = result["parameters"]["a"]
    assert result["parameters"]["a"]["unit"] == "mGal/pix^2"
    # the MAP column shows a result's b₁, b₂, a (a classical one: a real MAP takes minutes)
    monkeypatch.setattr(
        calib, "estimate_map", lambda record: {k: result["parameters"][k] for k in calib.PARAMS}
    )
    st = LiveState(mine, map_runner=_MapAtOnce(), stall_s=1.0)
    srv = LiveServer(("127.0.0.1", 0), st)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    threading.Thread(target=srv.follow, kwargs={"poll_s": 0.1}, daemon=True).start()
    profile = tempfile.mkdtemp(prefix="chekan-chromium-")
    try:
        with sync_api.sync_playwright() as pw:
            ctx = pw.chromium.launch_persistent_context(
                profile,
                executable_path=CHROMIUM,
                args=CHROMIUM_ARGS,
                headless=True,
                locale="en-US",
                timezone_id="America/New_York",
                viewport={"width": 1500, "height": 1000},
            )
            page = ctx.new_page()
            page.goto(srv.url)
            assert page.evaluate("navigator.language") == "en-US"
            page.wait_for_function(
                "Number(document.body.dataset.mapRounds || 0) >= 1"
                " && document.querySelector('#cl-dg th') !== null",
                timeout=60_000,
            )
            # a in mGal/pix², as the result, the console and the certificate give it
            heads = page.locator("#map th").all_inner_texts()
            assert heads[3] == "a, mGal/pix²", heads
            mean, sd = _sci_value(page.locator("#map .map-a").last.inner_text())
            assert mean == pytest.approx(a["mean"], rel=1e-4)
            assert sd == pytest.approx(a["sd"], rel=1e-2)
            assert (
                page.locator("#map .map-a").last.inner_text().startswith(format(a["mean"], ".4e"))
            )
            cl_a = page.locator("#cl-b tr", has_text="a, ").inner_text()
            assert cl_a.startswith("a, mGal/pix²"), cl_a
            mean, sd = _sci_value(page.locator("#cl-b .cl-a").inner_text())
            assert mean == pytest.approx(a["mean"], rel=1e-4)
            assert sd == pytest.approx(a["sd"], rel=1e-2)
            assert "µGal" not in page.locator("body").inner_text()
            for v in (-7.8e-5, 1.34e-4, 0.0, 12.5, 1.23456e-12):  # the console's format
                assert page.evaluate(f"sci({v!r}, 4)") == format(v, ".4e"), v
            # every column of Δg and δg says its unit; b too
            dg_heads = page.locator("#cl-dg th").all_inner_texts()
            with_g = [h for h in dg_heads if "Δg" in h or "δg" in h]
            assert len(with_g) == 4 and all(h.endswith(", mGal") for h in with_g), dg_heads
            b_heads = page.locator("#cl-b th").all_inner_texts()
            assert b_heads[1:] == ["b₁, mGal/pix", "b₂, mGal/pix"], b_heads
            # the end in 24-hour UTC, whatever the browser's locale and time zone
            assert page.locator("#end-lbl").inner_text() == "ended at"
            end = page.locator("#end").inner_text()
            assert end == "14:05 UTC 2026-11-25", end
            now = page.evaluate("[new Date().toISOString(), wall(new Date().toISOString())]")
            assert now[1] == f"{now[0][11:16]} UTC", now  # today's date goes without saying
            for d in _screenshot_dirs(tmp_path):
                page.screenshot(path=str(d / "live_page_units.png"), full_page=True)
            page.evaluate(  # one angle paired so far: the classical fit holds a at 0
                "() => { const c = {...S.status.classical, a: 0, a_sd: null, a_fixed: true};"
                " showStatus({...S.status, classical: c}); }"
            )
            assert page.locator("#cl-b .cl-a").inner_text() == "0 (held)"  # not 0 ± –
            ctx.close()
    finally:
        srv.stop()
        srv.server_close()
        shutil.rmtree(profile, ignore_errors=True)
    assert (tmp_path / "live_page_units.png").stat().st_size > 10_000


def _screenshot_dirs(tmp_path: Path) -> list[Path]:
    dirs = [tmp_path]
    if os.environ.get("CHEKAN_ARTEFACTS"):
        d = Path(os.environ["CHEKAN_ARTEFACTS"])
        d.mkdir(parents=True, exist_ok=True)
        dirs.append(d)
    return dirs
