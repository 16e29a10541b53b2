"""Print the stacks that crashed test processes left in a folder (``CHEKAN_CRASH_DIR``,
``tests/conftest.py``): every thread of each, the thread that crashed last.

    python tests/crash_report.py FOLDER
"""

from __future__ import annotations

import re
import sys
from pathlib import Path


def report(folder: Path) -> str:
    """The non-empty logs in ``folder``, each with its crashing thread's stack last."""
    parts = []
    for log in sorted(folder.glob("*.log")):
        text = log.read_text(errors="replace").strip()
        if not text:
            continue
        blocks = re.split(r"\n(?=(?:Thread|Current thread) 0x)", text)
        head, threads = blocks[0], blocks[1:]
        threads = [re.sub(r"\n\s*Extension modules:.*", "", b, flags=re.S) for b in threads]
        current = [b for b in threads if b.startswith("Current thread")]
        others = [b for b in threads if not b.startswith("Current thread")]
        parts.append("\n".join([f"== {log.stem} died: {head}", *others, *current]))
    return "\n\n".join(parts)


if __name__ == "__main__":
    text = report(Path(sys.argv[1]))
    print(text or f"no crashed process left its stacks in {sys.argv[1]}")
