"""Run every benchmark module (``python -m benchmarks [name ...]``) and print a table.

Each ``benchmarks/bench_*.py`` has ``main() -> list[Result]``; a Result reports a measured
time beside a baseline measured in the same run, and the target from the issue.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
from pathlib import Path

from benchmarks.common import print_results


def run(selected: list[str]) -> int:
    here = Path(__file__).parent
    names = sorted(m.name for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_"))
    if selected:
        names = [n for n in names if any(s in n for s in selected)]
    all_results = []
    for name in names:
        module = importlib.import_module(f"benchmarks.{name}")
        print(f"== {name}", flush=True)
        results = module.main()
        print_results(results)
        all_results.extend(results)
    missed = [r for r in all_results if r.met is False]
    print(f"\n{len(all_results)} measurements, {len(missed)} missed their target")
    return 0


if __name__ == "__main__":
    sys.exit(run(sys.argv[1:]))
