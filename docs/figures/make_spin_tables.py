"""Markdown tables of docs/results.md (Table I) from the records of ``icenav eval spin``.

The records are made by (about 4 minutes on 2 cores each):

    icenav eval spin --seeds 110-119 --vessel all --jobs 2 \\
        --json docs/figures/spin_seeds110-119.json --plots docs/figures
    icenav eval spin --seeds 110-119 --vessel all --jobs 2 --conditions dense+hysteresis \\
        --in-situ --json docs/figures/spin_seeds110-119_in_situ.json
    icenav eval spin --seeds 0-9 --vessel all --jobs 2 --conditions none,dense,simplified \\
        --json docs/figures/spin_seeds0-9_paper_methods.json

This script only reads them and prints the tables (run: python docs/figures/make_spin_tables.py).
"""

from __future__ import annotations

import json
from pathlib import Path

from icenav.eval.spin import SpinRecord
from icenav.eval.spin_report import paper_table, summarize, vessel_effect

HERE = Path(__file__).parent
BENDS = (20, 40, 60)


def load(name: str) -> list[SpinRecord]:
    path = HERE / name
    if not path.exists():
        print(f"({path.name} not found: run the command in this script's docstring)")
        return []
    return [SpinRecord(**r) for r in json.loads(path.read_text())]


def straight_table(records: list[SpinRecord]) -> None:
    paper = paper_table()
    cells = summarize(records)
    conds = [c for c in dict.fromkeys(r.condition for r in records)]
    print("| condition | 20 deg | 40 deg | 60 deg |\n|---|---|---|---|")
    for cond in conds:
        row = [cond]
        for i, b in enumerate(BENDS):
            c = cells[("straight", cond, b)]
            ref = f" ({paper[cond][i][0]}, {paper[cond][i][1]})" if cond in paper else ""
            row.append(
                f"{c.position_mm:.1f} mm, {c.rotation_deg:.1f} deg "
                f"[{c.true_position_mm:.1f}, {c.true_rotation_deg:.1f}]{ref} / "
                f"{c.worst_position_mm:.1f}, {c.worst_rotation_deg:.1f}"
            )
        print("| " + " | ".join(row) + " |")


def curved_table(records: list[SpinRecord], label: str = "") -> None:
    cells = summarize(records)
    eff = vessel_effect(records)
    conds = [c for c in dict.fromkeys(r.condition for r in records)]
    print("| vessel | condition | 20 deg | 40 deg | 60 deg |\n|---|---|---|---|---|")
    for vessel in ("moderate", "steep"):
        for cond in conds:
            if (vessel, cond, BENDS[0]) not in cells:
                continue
            row = [vessel, cond + label]
            for b in BENDS:
                c, e = cells[(vessel, cond, b)], eff[(vessel, cond, b)]
                row.append(
                    f"{c.position_mm:.1f} mm, {c.rotation_deg:.1f} deg "
                    f"({e.position_mm:+.2f}, {e.rotation_deg:+.1f}; worst "
                    f"{e.worst_position_mm:+.1f}, {e.worst_rotation_deg:+.1f}) "
                    f"[{c.true_position_mm:.1f}, "
                    f"{c.true_rotation_deg:.1f}]"
                )
            print("| " + " | ".join(row) + " |")


def per_catheter(records: list[SpinRecord]) -> None:
    conds = [c for c in dict.fromkeys(r.condition for r in records)]
    by = {(r.seed, r.condition, r.bend_deg): r for r in records if r.vessel == "straight"}
    print("| catheter | " + " | ".join(conds) + " |\n" + "|---" * (len(conds) + 1) + "|")
    for seed in sorted({r.seed for r in records}):
        cols = [
            ", ".join(
                f"{by[(seed, c, b)].position_rmse_mm:.1f}/{by[(seed, c, b)].rotation_rmse_deg:.1f}"
                for b in BENDS
            )
            for c in conds
        ]
        print(f"| {seed} | " + " | ".join(cols) + " |")


if __name__ == "__main__":
    held_out = load("spin_seeds110-119.json")
    if held_out:
        print("## straight vessel, mean EM [true] (paper) / worst\n")
        straight_table(held_out)
        print("\n## per catheter, straight (EM mm/deg at 20, 40, 60)\n")
        per_catheter(held_out)
        print("\n## curved vessels, calibrated straight: mean EM (adds; worst) [true]\n")
        curved_table(held_out)
    in_situ = load("spin_seeds110-119_in_situ.json")
    if in_situ:
        print("\n## curved vessels, ours re-identified in the vessel (--in-situ)\n")
        curved_table(in_situ, label=", re-identified in the vessel")
    tuning = load("spin_seeds0-9_paper_methods.json")
    if tuning:
        print("\n## tuning seeds 0-9, the paper's methods: what the vessel adds\n")
        curved_table(tuning)
