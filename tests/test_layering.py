"""The layers of the package: ``inference`` is model-agnostic estimation and knows nothing of
the domain (issue 28)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def test_inference_imports_nothing_from_the_domain():
    offenders = {
        str(p.relative_to(ROOT)): sorted(
            m for m in _imported_modules(p) if m.split(".")[0] in {"chekan", "hw"}
        )
        for p in sorted((ROOT / "inference").rglob("*.py"))
    }
    assert {k: v for k, v in offenders.items() if v} == {}


def test_journal_events_are_one_typed_contract():
    """Writers and readers of the acquisition journal name events by ``hw.events.Event``
    (no string literals), whose on-disk names stay what old journals hold."""
    import re

    from hw.events import FIELDS, Event

    assert set(FIELDS) == set(Event)
    assert [Event.RUN_START, Event.STEP_DONE, Event.RUN_STOP, Event.SYNC] == [
        "run_start",
        "step_done",
        "run_stop",
        "sync",
    ]
    call = re.compile(r"(?:\.event|_journal)\(\s*\"")
    compare = re.compile(r"(?:kind|\[\"event\"\])\s*==\s*\"")
    files = [*(ROOT / "hw" / "acquisition").glob("*.py"), ROOT / "chekan" / "live" / "state.py"]
    literal = [
        str(p.relative_to(ROOT))
        for p in files
        if call.search(p.read_text(encoding="utf-8")) or compare.search(p.read_text("utf-8"))
    ]
    assert literal == []


def _module_graph() -> dict[str, set[str]]:
    """Module-level imports between the project's modules (``pkg.mod`` → modules)."""
    files = {}
    for top in ("chekan", "inference", "hw"):
        for p in (ROOT / top).rglob("*.py"):
            name = ".".join(p.relative_to(ROOT).with_suffix("").parts)
            files[name.removesuffix(".__init__")] = p
    graph: dict[str, set[str]] = {}
    for name, p in files.items():
        pkg = name if p.name == "__init__.py" else name.rsplit(".", 1)[0]
        deps: set[str] = set()
        for node in ast.parse(p.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.ImportFrom):
                parts = pkg.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1]) if node.level else ""
                mod = ".".join(x for x in (base, node.module or "") if x)
                deps.update(
                    f"{mod}.{a.name}" if f"{mod}.{a.name}" in files else mod for a in node.names
                )
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names)
        graph[name] = {d for d in deps if d in files and d != name}
    return graph


def test_no_import_cycle():
    graph, state, path, cycles = _module_graph(), {}, [], []

    def visit(u: str) -> None:
        state[u] = 1
        path.append(u)
        for v in sorted(graph[u]):
            if state.get(v) == 1:
                cycles.append([*path[path.index(v) :], v])
            elif v not in state:
                visit(v)
        path.pop()
        state[u] = 2

    for u in sorted(graph):
        if u not in state:
            visit(u)
    assert "chekan.joint.likelihood" in graph and cycles == []
