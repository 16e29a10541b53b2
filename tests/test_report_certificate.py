"""The certificate as a reader meets it (issues 32 and 33 §6): a decision rule wherever
pass or fail is said, figure 2's residuals about the fitted model with the model's band,
tables not split over pages, and parameters named as in the budget table."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from chekan.report import build_report
from chekan.report.document import Para

DATA = Path(__file__).resolve().parent / "data" / "report"
BAYES_JSON = DATA / "bayes_result.json"


def _bayes() -> dict:
    return json.loads(BAYES_JSON.read_text(encoding="utf-8"))


@pytest.mark.parametrize("lang", ["en", "ru"])
@pytest.mark.parametrize("tolerance", [1e-6, 10.0])
def test_every_pass_or_fail_states_its_decision_rule(lang, tolerance):
    rep = build_report(_bayes(), lang=lang, tolerance_percent=tolerance, figures=False)
    blocks = rep.blocks
    verdicts = [
        i for i, b in enumerate(blocks) if isinstance(b, Para) and b.kind in ("pass", "fail")
    ]
    assert len(verdicts) == 2  # the summary and the conclusion
    assert {blocks[i].kind for i in verdicts} == {"fail" if tolerance < 1 else "pass"}
    for i in verdicts:
        after = [b.text for b in blocks[i + 1 : i + 4] if isinstance(b, Para)]
        assert any("ILAC-G8:09/2019, 4.2.1" in text for text in after), blocks[i].text
