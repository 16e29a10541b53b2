"""The compiled engine of the joint model (issue 28): one engine per structure, one cache,
cleared on request; the model modules hold no compiled state of their own."""

from __future__ import annotations

import ast
from pathlib import Path

from chekan.joint import clear_caches, engine_for, problem_for
from chekan.joint.layout import ModelStructure

ROOT = Path(__file__).resolve().parents[1]


def test_one_engine_per_structure_until_cleared():
    st = ModelStructure(4, 12, 5)
    e = engine_for(st)
    assert engine_for(ModelStructure(4, 12, 5)) is e and problem_for(st) is e.problem
    assert engine_for(ModelStructure(5, 12, 5)) is not e
    clear_caches()
    assert engine_for(st) is not e and engine_for(st).problem.structure == st


def test_only_the_engine_caches_or_compiles():
    """No module of chekan/joint but the engine uses functools.cache or the executable store."""
    offenders = []
    for p in sorted((ROOT / "chekan" / "joint").glob("*.py")):
        if p.name == "engine.py":
            continue
        tree = ast.parse(p.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr in ("cache", "lru_cache"):
                offenders.append(f"{p.name}: functools.{node.attr}")
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                "chekan.runtime.store"
            ):
                offenders.append(f"{p.name}: imports {node.module}")
    assert offenders == []
