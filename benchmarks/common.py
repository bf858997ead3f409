"""Shared timing helpers for the benchmarks (not collected by pytest)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["Result", "print_results", "time_per_call"]


@dataclass(frozen=True)
class Result:
    """One measurement, with its same-run baseline and the issue's target."""

    name: str
    """What was measured."""
    value: float
    """Measured value, in ``unit``."""
    unit: str
    """Unit of ``value`` (e.g. "us/call", "M configs/s")."""
    baseline: float | None = None
    """The same quantity for the baseline, measured in the same run."""
    baseline_name: str = ""
    """What the baseline is."""
    target: str = ""
    """The target from the issue, as text."""
    met: bool | None = None
    """Whether the target is met (None: no target)."""

    @property
    def ratio(self) -> float | None:
        """baseline / value for times (higher is better for us), None without baseline."""
        if self.baseline is None or self.value == 0:
            return None
        return self.baseline / self.value


def time_per_call(fn: Callable[[], object], min_time: float = 0.2, repeat: int = 5) -> float:
    """Best-of-``repeat`` seconds per call of ``fn``, each repeat lasting >= ``min_time``."""
    n = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        dt = time.perf_counter() - t0
        if dt >= min_time / 4:
            break
        n *= 4
    n = max(1, int(n * min_time / max(dt, 1e-9)))
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def print_results(results: list[Result]) -> None:
    for r in results:
        base = ""
        if r.baseline is not None:
            rt = r.ratio
            base = f"  baseline {r.baseline:.4g} {r.unit} ({r.baseline_name})"
            if rt is not None:
                base += f", ratio {rt:.1f}x"
        tgt = ""
        if r.target:
            tgt = f"  target {r.target}: {'met' if r.met else 'MISSED'}"
        print(f"  {r.name}: {r.value:.4g} {r.unit}{base}{tgt}")
