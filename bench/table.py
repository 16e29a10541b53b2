"""Rows of benchmark figures, each beside its reference measured in the same run."""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

NO_REFERENCE = "—"


@dataclass
class Row:
    """One figure: ``figure`` is ours, ``reference`` the reference tool's (or ``—``).

    ``values`` keeps the raw numbers (seconds, sessions/s, differences) for the JSON.
    """

    label: str
    figure: str
    reference: str = NO_REFERENCE
    note: str = ""
    values: dict[str, Any] = field(default_factory=dict)


def format_table(rows: list[Row], title: str = "") -> str:
    """One aligned plain-text table."""
    head = ("figure", "measured", "reference (same run)", "note")
    cells = [head] + [(r.label, r.figure, r.reference, r.note) for r in rows]
    w = [max(len(c[i]) for c in cells) for i in range(3)]
    lines = [title] if title else []
    for k, c in enumerate(cells):
        lines.append(f"{c[0]:<{w[0]}}  {c[1]:>{w[1]}}  {c[2]:>{w[2]}}  {c[3]}".rstrip())
        if k == 0:
            lines.append("  ".join("-" * x for x in w) + "  ----")
    return "\n".join(lines)


def environment() -> dict[str, Any]:
    """Where the figures were measured (the load average matters on a shared machine)."""
    import chekan

    env: dict[str, Any] = {
        "date": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "chekan": chekan.__version__,
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "load_average_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }
    try:
        import jax

        env["jax"] = jax.__version__
        env["jax_platform"] = jax.devices()[0].platform
    except Exception:  # JAX missing or not initialisable: the figures still stand
        pass
    return env


def environment_line(env: dict[str, Any]) -> str:
    return (
        f"chekan {env['chekan']}, Python {env['python']}, JAX {env.get('jax', '?')} on "
        f"{env.get('jax_platform', '?')}, {env['cpus']} CPU(s), "
        f"load average {env['load_average_1min']:.1f} at the start"
    )


def write_json(path: str | os.PathLike, rows: list[Row], **extra: Any) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {**extra, "rows": [asdict(r) for r in rows]}
    path.write_text(json.dumps(data, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
    return path


def report(
    rows: list[Row],
    title: str,
    env: dict[str, Any],
    json_path: str | os.PathLike | None = None,
    settings: dict[str, Any] | None = None,
) -> None:
    """Print a script's table and the machine's line; also write them to ``json_path``."""
    print(format_table(rows, title))
    print(environment_line(env))
    if json_path:
        write_json(json_path, rows, environment=env, settings=settings or {})
