"""Markdown tables of docs/results.md (plant families) from the records of ``icenav eval spin``.

The held-out records are made by ONE run (methods frozen at commit b41cbd4; 32 minutes
on a busy 2-core machine):

    nice icenav eval spin --plant-family all --seeds 300-304 --jobs 2 \\
        --conditions none,dense,dense+hysteresis \\
        --json docs/figures/families_seeds300-304.json

This script only reads them and prints the tables and the issue's targets
(run: python docs/figures/make_family_tables.py [records.json]).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from icenav.eval.spin import SpinRecord
from icenav.eval.spin_report import paper_table, summarize_plants

HERE = Path(__file__).parent
BENDS = (20, 40, 60)
OURS = "dense+hysteresis"


def load(path: Path) -> list[SpinRecord]:
    if not path.exists():
        print(f"({path} not found: run the command in this script's docstring)")
        return []
    return [SpinRecord(**r) for r in json.loads(path.read_text())]


def matrix(records: list[SpinRecord]) -> None:
    cells = summarize_plants(records)
    plants = list(dict.fromkeys(r.plant for r in records))
    conds = list(dict.fromkeys(r.condition for r in records))
    print("| family | condition | 20 deg | 40 deg | 60 deg |\n|---|---|---|---|---|")
    for plant in plants:
        for cond in conds:
            row = []
            for b in BENDS:
                c = cells.get((plant, "straight", cond, b))
                row.append(
                    "-"
                    if c is None
                    else f"{c.position_mm:.1f} mm, {c.rotation_deg:.1f} deg "
                    f"[{c.true_position_mm:.1f}, {c.true_rotation_deg:.1f}] / "
                    f"{c.worst_position_mm:.1f}, {c.worst_rotation_deg:.1f}"
                )
            name = f"**{cond}**" if cond == OURS else cond
            print(f"| `{plant}` | {name} | " + " | ".join(row) + " |")


def targets(records: list[SpinRecord]) -> None:
    cells = summarize_plants(records)
    paper_dense = paper_table()["dense"]
    print("\n| family | ours < 2.0 mm, < 4.0 deg (mean) | worst < 2.5 mm, < 5 deg | "
          "<= 0.6x paper's dense in position at 40 / 60 (below it at 20) |")  # fmt: skip
    print("|---|---|---|---|")
    for plant in dict.fromkeys(r.plant for r in records):
        mean_ok, worst_ok, ratio_ok = [], [], []
        for i, b in enumerate(BENDS):
            c = cells.get((plant, "straight", OURS, b))
            if c is None:
                continue
            mean_ok.append(c.position_mm < 2.0 and c.rotation_deg < 4.0)
            worst_ok.append(c.worst_position_mm < 2.5 and c.worst_rotation_deg < 5.0)
            limit = paper_dense[i][0] * (1.0 if b == 20 else 0.6)
            ratio_ok.append(c.position_mm <= limit)
        print(f"| `{plant}` | {_marks(mean_ok)} | {_marks(worst_ok)} | {_marks(ratio_ok)} |")


def _marks(oks: list[bool]) -> str:
    return " / ".join("met" if ok else "**missed**" for ok in oks)


def main() -> None:
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "families_seeds300-304.json"
    records = load(path)
    if records:
        seeds = sorted({r.seed for r in records})
        print(f"catheters {seeds}, straight vessel; EM mean [true mean] / worst EM\n")
        matrix(records)
        targets(records)


if __name__ == "__main__":
    main()
