"""The test profile's summary (tests/profile_summary.py) and the store's record of what it
compiled for which structure (chekan.runtime.store.ExecutableStore.compiles)."""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import pytest
from profile_summary import summary

from chekan.runtime.store import ExecutableStore


def test_the_summary_sums_files_and_counts_structures(tmp_path: Path) -> None:
    f = tmp_path / "profile.tsv"
    f.write_text(
        "tests/a.py::t1\t2.0\t3\t1.0\t3\tS(h=4);S(h=8)\n"
        "tests/a.py::t2\t1.5\t0\t0.0\t0\t\n"
        "tests/b.py::t1\t9.0\t2\t1.0\t2\tS(h=8)\n"
        "tests/c.py::t1\t0.5\t0\t0.0\n",  # an older profile's line: no compile columns
        encoding="utf-8",
    )
    text = summary(f)
    lines = text.splitlines()
    assert lines[0] == "13 s in tests (summed over workers), 3 files"
    assert lines[1].split() == ["9.0", "s", "tests/b.py"]
    assert lines[2].split() == ["3.5", "s", "tests/a.py"]
    assert "5 executables compiled for 2 model structures:" in text
    assert "S(h=8)  (first: tests/a.py::t1)" in text
    f.write_text("tests/a.py::t1\t2.0\n", encoding="utf-8")
    with pytest.raises(SystemExit, match=r"profile.tsv:1: not a line"):
        summary(f)


def test_the_store_names_the_scope_of_what_it_compiled() -> None:
    store = ExecutableStore(None, "fp")
    one = store.scoped("structure one")
    one.jit("double", lambda x: 2 * x)(jnp.ones(3))
    one.jit("double", lambda x: 2 * x)(jnp.ones(3))  # the same key: no second compile
    store.jit("triple", lambda x: 3 * x)(jnp.ones(2))
    assert store.compiles == [("structure one", "double"), ("", "triple")]
    assert one.compiles is store.compiles
