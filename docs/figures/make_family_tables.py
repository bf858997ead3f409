"""Markdown tables of docs/results.md (plant families) from the records of ``icenav eval spin``.

The held-out records are made by ONE run each. Catheters 325-329 (round 6, session 10; the
freeze commit is in docs/results.md; on the busy 2-core machine shared by four engineers),
as two commands so that a late finish could be cut after 327, their records merged into
``families_seeds325-329.json``:

    nice -n 10 icenav eval spin --plant-family all --seeds 325-327 --jobs 2 \\
        --conditions none,dense,dense+hysteresis,short+rings,short+rings+prior \\
        --json docs/figures/families_seeds325-327.json
    (the same with --seeds 328-329 --json docs/figures/families_seeds328-329.json)

and, the rounds before (now spent): ``--seeds 320-324`` (round 5, at 38cea1a, the same
conditions), ``--seeds 315-319`` (round 4, at bcf73ae, without
``short+rings+prior``), ``--seeds 310-314`` (round 3, at 2bf7dc3, the same conditions),
``--seeds 305-309`` (methods frozen at 899b631, without ``short+rings``) and ``--seeds
300-304`` (at b41cbd4), their records in ``docs/figures/families_seeds3*.json``.

This script only reads them and prints the tables and the issue's targets
(run: python docs/figures/make_family_tables.py [records.json]); with ``--compare
BEFORE.json AFTER.json`` it prints ours (``dense+hysteresis``, EM) before -> after per family
and bend, e.g. on the development catheters 210-212
(``docs/figures/families_dev210-212_before.json``, ``..._after.json``: the same command
with ``--seeds 210-212 --conditions dense+hysteresis`` at bcf97b2 and at 899b631; round 3:
``families_dev210-214_before.json`` / ``..._after.json`` on 210-214; session 8:
``families_dev210-212_s8_{before,after}.json``, ours with the AP knob's plays only and with
the plays over the knob plane; session 9's map before / after are in
``families_dev210-212_s9_diagnosis_{before,after}.json``, made by
``diagnose_family_spins.py``); with
``--short FULL.json SHORT.json`` the short calibrations against ours on the same catheters
(and how many family x bend cells are within 25 % of ours).
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


def compare(before: list[SpinRecord], after: list[SpinRecord]) -> None:
    """Ours before -> after: mean EM position (mm) and rotation (deg) per family and bend."""
    b_cells, a_cells = summarize_plants(before), summarize_plants(after)
    print("| family | 20 deg | 40 deg | 60 deg |\n|---|---|---|---|")
    for plant in dict.fromkeys(r.plant for r in after):
        row = []
        for bend in BENDS:
            b = b_cells.get((plant, "straight", OURS, bend))
            a = a_cells.get((plant, "straight", OURS, bend))
            if a is None or b is None:
                row.append("-")
                continue
            row.append(
                f"{b.position_mm:.2f} -> {a.position_mm:.2f} mm, "
                f"{b.rotation_deg:.2f} -> {a.rotation_deg:.2f} deg"
            )
        print(f"| `{plant}` | " + " | ".join(row) + " |")


def short_ratios(full: list[SpinRecord], short: list[SpinRecord]) -> None:
    """Each short condition against ours (mean EM over the same catheters): position and
    rotation, and their ratio to ours (the issue: within 25 %, i.e. <= 1.25)."""
    f_cells, s_cells = summarize_plants(full), summarize_plants(short)
    within: dict[str, list[int]] = {}
    print("| family | condition | 20 deg | 40 deg | 60 deg |\n|---|---|---|---|---|")
    for plant in dict.fromkeys(r.plant for r in short):
        for cond in dict.fromkeys(r.condition for r in short):
            row = []
            for bend in BENDS:
                f = f_cells.get((plant, "straight", OURS, bend))
                c = s_cells.get((plant, "straight", cond, bend))
                if f is None or c is None:
                    row.append("-")
                    continue
                n = within.setdefault(cond, [0, 0, 0])
                n[0] += c.position_mm <= 1.25 * f.position_mm
                n[1] += c.rotation_deg <= 1.25 * f.rotation_deg
                n[2] += 1
                row.append(
                    f"{c.position_mm:.1f} mm, {c.rotation_deg:.1f} deg "
                    f"({c.position_mm / f.position_mm:.1f}x, "
                    f"{c.rotation_deg / f.rotation_deg:.1f}x)"
                )
            print(f"| `{plant}` | {cond} | " + " | ".join(row) + " |")
    for cond, (pos, rot, cells) in within.items():
        if cond != OURS:
            print(
                f"\n{cond}: within 25 % of ours in {pos} of {cells} cells in position, "
                f"{rot} in rotation"
            )


def main() -> None:
    if len(sys.argv) == 4 and sys.argv[1] == "--short":
        full, short = load(Path(sys.argv[2])), load(Path(sys.argv[3]))
        if full and short:
            print("short calibrations (EM mean) and their ratio to ours on the same catheters\n")
            short_ratios(full, short)
        return
    if len(sys.argv) == 4 and sys.argv[1] == "--compare":
        before, after = load(Path(sys.argv[2])), load(Path(sys.argv[3]))
        if before and after:
            seeds = sorted({r.seed for r in after})
            print(f"ours (EM mean over catheters {seeds}), before -> after\n")
            compare(before, after)
        return
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "families_seeds320-324.json"
    records = load(path)
    if records:
        seeds = sorted({r.seed for r in records})
        print(f"catheters {seeds}, straight vessel; EM mean [true mean] / worst EM\n")
        matrix(records)
        targets(records)


if __name__ == "__main__":
    main()
