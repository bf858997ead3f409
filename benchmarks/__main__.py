"""Run every benchmark module (``python -m benchmarks [name ...]``: a name picks the module
``bench_<name>`` if there is one, else every module containing it) and print a table.

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
        # a selector naming a module exactly ("controller" = bench_controller) picks it alone;
        # otherwise every module whose name contains it ("races", "spin")
        names = [
            n
            for n in names
            if any(
                n in (s, f"bench_{s}") or (s in n and f"bench_{s}" not in names) for s in selected
            )
        ]
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
