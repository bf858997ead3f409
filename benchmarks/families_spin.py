"""The paper's spin (``icenav eval spin``) on each plant family: a smoke run of the plug-ins.

    python -m benchmarks.families_spin [--seeds 200-209] [--families all] [--conditions none]

For each family of :data:`icenav.sim.families.FAMILIES` and each catheter seed, the current
``icenav.eval.spin`` pipeline runs unchanged (:func:`icenav.eval.spin.evaluate_catheter`:
calibrate in the straight vessel if a condition needs it, spin at 20 / 40 / 60 deg, EM
tracked); only the plant it builds is swapped for the family's, at the one seam the
evaluation has today (``icenav.eval.spin._make_plant(seed, vessel)``; the ``--plant`` /
``--plant-family`` options replace this). It prints mean (min..max) over the seeds per
family, condition and bend, beside the paper's Table I. Each made plant and tracker is
checked against the plug-in protocol first (:func:`icenav.sim.plugins.make_plant`).

Seeds: 200-209 are the families' development catheters (docs/digital-twin.md, "Plant
families"); do not run held-out seeds through this while methods are being developed.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import Any
from unittest import mock

import numpy as np

from icenav.eval import spin as eval_spin
from icenav.eval.spin_cli import parse_seeds
from icenav.sim.families import FAMILIES, family
from icenav.sim.plugins import make_plant

TABLE_I_NONE_MM = {20: 5.5, 40: 11.0, 60: 14.8}
"""The paper's Table I, condition none, position RMSE (mm) at 20 / 40 / 60 deg."""


def run_family(name: str, seeds: Sequence[int], conditions: Sequence[str]) -> list[Any]:
    """``evaluate_catheter`` on each seed with the family's plants; the SpinRecords."""
    factory = family(name)

    def make(seed: int, vessel: str) -> tuple[Any, Any]:
        return make_plant(factory, seed, vessel)

    records = []
    with mock.patch.object(eval_spin, "_make_plant", make):
        for seed in seeds:
            run = eval_spin.evaluate_catheter(seed, ("straight",), conditions=conditions)
            records += run.records
    return records


def summarise(name: str, records: Sequence[Any], conditions: Sequence[str]) -> list[str]:
    lines = []
    for cond in conditions:
        for bend in (20, 40, 60):
            rows = [r for r in records if r.condition == cond and r.bend_deg == bend]
            pos = np.array([r.position_rmse_mm for r in rows])
            rot = np.array([r.rotation_rmse_deg for r in rows])
            true = np.array([r.true_position_rmse_mm for r in rows])
            paper = f" (Table I {TABLE_I_NONE_MM[bend]})" if cond == "none" else ""
            lines.append(
                f"  {name:<34s} {cond:<18s} {bend:>2d} deg: {pos.mean():5.2f} mm "
                f"({pos.min():.2f}..{pos.max():.2f}) [true {true.mean():5.2f}]{paper}, "
                f"{rot.mean():5.2f} deg ({rot.min():.2f}..{rot.max():.2f})"
            )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.families_spin", description=__doc__)
    p.add_argument("--seeds", default="200-209", help="catheter seeds (default 200-209)")
    p.add_argument("--families", default="all", help="comma-separated names or 'all'")
    p.add_argument("--conditions", default="none", help="eval spin conditions (default none)")
    args = p.parse_args(argv)
    seeds = parse_seeds(args.seeds)
    names = list(FAMILIES) if args.families == "all" else args.families.split(",")
    conditions = [c.strip() for c in args.conditions.split(",") if c.strip()]
    print(f"families {names}; seeds {seeds}; conditions {conditions}")
    t0 = time.perf_counter()
    for name in names:
        t = time.perf_counter()
        records = run_family(name, seeds, conditions)
        for line in summarise(name, records, conditions):
            print(line)
        print(f"  ({name}: {time.perf_counter() - t:.0f} s)", flush=True)
    print(f"total {time.perf_counter() - t0:.0f} s; EM-tracked RMSE, mean (min..max) of seeds")
    return 0


if __name__ == "__main__":
    sys.exit(main())
