"""The reference data a clone carries: the paper's protocol and the specifications of the
formats, byte for byte the project's contracts where the steering copy is beside the clone."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SPECS = ("legacy-protocol.md", "record-format.md", "results-json.md", "serial-protocol.md")


def test_the_clone_carries_the_paper_protocol_and_the_specs() -> None:
    assert (ROOT / "examples" / "calibr_46_protocol.csv").is_file()
    for name in SPECS:
        assert (ROOT / "docs" / "specs" / name).is_file(), name


@pytest.mark.parametrize(
    "ours, theirs",
    [("examples/calibr_46_protocol.csv", "reference/calibr_46_protocol.csv")]
    + [(f"docs/specs/{n}", f"specs/{n}") for n in SPECS],
)
def test_copies_equal_the_contracts_beside_the_clone(ours: str, theirs: str) -> None:
    """Where ../shared (the contracts' own copy) stands beside the clone, ours equal it; a
    clone alone has nothing to compare with and checks only that its copy is there."""
    contract = ROOT.parent / "shared" / theirs
    if contract.is_file():
        same = (ROOT / ours).read_bytes() == contract.read_bytes()
        assert same, f"{ours} differs from {contract}"
    else:
        assert (ROOT / ours).is_file()
