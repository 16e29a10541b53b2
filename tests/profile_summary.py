"""Summary of a ``CHEKAN_TEST_PROFILE`` file (``tests/conftest.py``): the suite's seconds
per test file, heaviest first, and the model structures its tests compiled, each with the
first test that compiled it. Usage: ``python tests/profile_summary.py FILE [--top N]``."""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path


def summary(path: Path, top: int = 15) -> str:
    """The text printed for the profile in ``path``."""
    per_file: dict[str, float] = defaultdict(float)
    compiled = 0
    first: dict[str, str] = {}
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        cols = line.split("\t")
        if len(cols) < 4:
            raise SystemExit(f"{path}:{n}: not a line of CHEKAN_TEST_PROFILE: {line!r}")
        per_file[cols[0].split("::")[0]] += float(cols[1])
        if len(cols) >= 6:
            compiled += int(cols[4])
            for label in filter(None, cols[5].split(";")):
                first.setdefault(label, cols[0])
    total = sum(per_file.values())
    lines = [f"{total:.0f} s in tests (summed over workers), {len(per_file)} files"]
    for name, sec in sorted(per_file.items(), key=lambda kv: -kv[1])[:top]:
        lines.append(f"  {sec:7.1f} s  {name}")
    lines.append(f"{compiled} executables compiled for {len(first)} model structures:")
    lines += [f"  {label}  (first: {test})" for label, test in first.items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("profile", type=Path)
    ap.add_argument("--top", type=int, default=15)
    args = ap.parse_args(argv)
    print(summary(args.profile, args.top))
    return 0


if __name__ == "__main__":
    sys.exit(main())
