"""``python -m bench``: every benchmark in one run, printed as tables."""

import subprocess
import sys
from pathlib import Path

here = Path(__file__).resolve().parent
for script, args in (
    ("calibration_bench.py", []),
    ("archive_bench.py", ["--n", "200", "--map-n", "4"]),
):
    print(f"\n=== {script} {' '.join(args)} ===", flush=True)
    subprocess.run([sys.executable, str(here / script), *args], check=False)
