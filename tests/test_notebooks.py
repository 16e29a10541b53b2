"""The notebooks under notebooks/: stored clean, and every cell runs.

Every ``notebooks/*.ipynb`` is picked up at collection time (a notebook added later is
tested without touching this file) and executed top to bottom with nbclient on the
``python3`` kernel, in a temporary working directory; a cell that raises fails the test
with that cell's source and traceback. The kernel must be this interpreter (the venv's
ipykernel spec launches ``python``, which jupyter_client replaces with ``sys.executable``):
``test_kernel_runs_this_interpreter`` checks it.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOK_DIR = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
KERNEL = "python3"
CELL_TIMEOUT_S = 600
ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def _client(nb, cwd: Path):
    return nbclient.NotebookClient(
        nb,
        kernel_name=KERNEL,
        timeout=CELL_TIMEOUT_S,
        resources={"metadata": {"path": str(cwd)}},
    )


@pytest.fixture
def kernel_env(tmp_path, monkeypatch):
    """The kernel's working directory; the kernel inherits the environment, so its temporary
    folders (the notebooks write into ``tempfile.mkdtemp()``) and IPython's history land under
    ``tmp_path`` too."""
    for var, sub in (("TMPDIR", "tmp"), ("IPYTHONDIR", ".ipython")):
        (tmp_path / sub).mkdir()
        monkeypatch.setenv(var, str(tmp_path / sub))
    work = tmp_path / "work"
    work.mkdir()
    return work


def test_notebooks_are_found():
    assert NOTEBOOKS, f"no notebooks found in {NOTEBOOK_DIR}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_stored_without_outputs(path):
    """Notebooks are committed clean: no outputs, no execution counts, valid nbformat 4."""
    nb = nbformat.read(path, as_version=nbformat.NO_CONVERT)
    assert nb.nbformat == 4, f"{path.name}: nbformat {nb.nbformat}, expected 4"
    nbformat.validate(nb)
    dirty = [
        i
        for i, c in enumerate(nb.cells)
        if c.cell_type == "code" and (c.get("outputs") or c.get("execution_count") is not None)
    ]
    assert not dirty, (
        f"{path.name}: cells {dirty} have outputs or execution counts; clear them before "
        "committing (e.g. jupyter nbconvert --clear-output --inplace, or nbformat)"
    )
    assert nb.metadata.get("kernelspec", {}).get("name", KERNEL) == KERNEL


def test_kernel_runs_this_interpreter(kernel_env):
    """The ``python3`` kernel that runs the notebooks is the interpreter running the tests."""
    nb = nbformat.v4.new_notebook(
        cells=[
            nbformat.v4.new_code_cell(
                "import os, sys, tempfile\n"
                "print(sys.prefix, os.getcwd(), tempfile.gettempdir(), sep='\\n')"
            )
        ]
    )
    _client(nb, kernel_env).execute()
    out = "".join(o.get("text", "") for o in nb.cells[0].outputs).split("\n")
    assert Path(out[0]).resolve() == Path(sys.prefix).resolve(), (
        f"the {KERNEL!r} kernel runs in {out[0]}, the tests in {sys.prefix}: another kernel "
        "spec shadows the venv's (jupyter kernelspec list)"
    )
    assert Path(out[1]).resolve() == kernel_env.resolve()
    assert Path(out[2]).resolve() == (kernel_env.parent / "tmp").resolve()


def _failing_cell(nb) -> int | None:
    for i, c in enumerate(nb.cells):
        if c.cell_type == "code" and any(o.output_type == "error" for o in c.get("outputs", [])):
            return i
    return None


@pytest.mark.slow
@pytest.mark.timeout(1800)
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, kernel_env):
    nb = nbformat.read(path, as_version=4)
    try:
        _client(nb, kernel_env).execute()
    except nbclient.exceptions.CellExecutionError as e:
        i = _failing_cell(nb)
        where = f"cell {i}" if i is not None else "a cell"
        pytest.fail(f"{path.name}: {where} raised\n{ANSI.sub('', str(e))}", pytrace=False)
    except nbclient.exceptions.CellTimeoutError as e:
        pytest.fail(f"{path.name}: a cell ran past {CELL_TIMEOUT_S} s: {e}", pytrace=False)
