"""Regenerate every figure of docs/ (``make docs``): runs docs/figures/make_*.py in turn."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

here = Path(__file__).parent / "figures"
for script in sorted(here.glob("make_*.py")):
    print(f"== {script.name}", flush=True)
    runpy.run_path(str(script), run_name="__main__")
sys.exit(0)
