"""Speed of the plant families: a 360-sample spin at 60 deg on each family's plant.

Baseline, measured in the same run: the same spin on the default twin (``CatheterPlant``).
The rate-dependent plant integrates its ramp and its 0.3 s settle after every move, the
distributed-friction plant ten plays per joint; the ratio says what a family costs the
evaluations that run on it.
"""

from __future__ import annotations

import math

from benchmarks.common import Result, time_per_call
from icenav.sim.families import FAMILIES, PLANT_FAMILIES
from icenav.sim.tuning import spin_trajectory


def main() -> list[Result]:
    spin = spin_trajectory(math.radians(60.0))

    def spin_time(name: str) -> float:
        plant, _ = FAMILIES[name](0, "straight")

        def run() -> None:
            plant.reset()
            plant.move_along(spin)

        return time_per_call(run, min_time=0.3, repeat=3)

    base = spin_time("default")
    results = []
    for name in PLANT_FAMILIES:
        if name == "default":
            continue
        t = spin_time(name)
        results.append(
            Result(
                f"360-sample spin at 60 deg, {name}",
                t * 1e3,
                "ms",
                baseline=base * 1e3,
                baseline_name="the default twin's spin",
            )
        )
    return results
