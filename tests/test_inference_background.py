"""Imports started ahead of their use (:func:`chekan.runtime.background.imports_in_background`)."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from chekan.runtime.background import imports_in_background

ROOT = Path(__file__).resolve().parents[1]


def test_a_failed_background_import_is_raised_by_its_future():
    fut = imports_in_background(["json", "chekan_no_such_module_xyz"], "test")
    with pytest.raises(ModuleNotFoundError, match="chekan_no_such_module_xyz"):
        fut.result(timeout=60)


def test_background_imports_are_in_the_process_once_the_future_is_done():
    # a fresh interpreter: here emcee and scipy.stats are already imported by other tests
    code = textwrap.dedent(
        """
        import sys
        from chekan.runtime.background import imports_in_background
        assert "emcee" not in sys.modules and "scipy.stats" not in sys.modules
        fut = imports_in_background(["emcee", "inference.sampling"], "imports")
        assert fut.result(timeout=120) is None
        print(all(m in sys.modules for m in ("emcee", "scipy.stats", "inference.sampling")))
        """
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}
    proc = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "True"
