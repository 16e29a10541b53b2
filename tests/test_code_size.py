"""The code's size limits: no module over ~700 lines anywhere (the developers' guide), and
in the joint model and the model-agnostic estimation (``chekan/joint/``, ``inference/``) no
module over 450 lines and no function over 80 (issue 55: small rooms with one job)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("chekan", "inference", "hw", "bench")
TIGHT = ("chekan/joint", "inference")


def _modules(*folders: str) -> list[Path]:
    found = [p for f in folders for p in sorted((ROOT / f).rglob("*.py"))]
    assert found, f"no Python modules under {folders}"
    return found


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def test_no_module_over_700_lines() -> None:
    big = {str(p.relative_to(ROOT)): _lines(p) for p in _modules(*PACKAGES) if _lines(p) > 700}
    assert not big, big


def test_the_joint_model_and_inference_have_small_modules_and_functions() -> None:
    big, long = {}, {}
    for p in _modules(*TIGHT):
        name = str(p.relative_to(ROOT))
        if _lines(p) > 450:
            big[name] = _lines(p)
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = (node.end_lineno or node.lineno) - node.lineno + 1
                if n > 80:
                    long[f"{name}:{node.lineno} {node.name}"] = n
    assert not big, big
    assert not long, long
