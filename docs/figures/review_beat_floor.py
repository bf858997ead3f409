"""The twin's consecutive-beat similarity ceiling and ROI floor at the saved views of a still
catheter, against the beat-to-beat shape's ``sigma_d`` (P6; `docs/digital-twin.md` 9.3b).

    python docs/figures/review_beat_floor.py [--sd 0,0.5,1.0] [--pairs 100:0,...] [--beats 6]

For each development pair (catheter:patient, in vivo) the bench of ``icenav eval recovery``
drives the catheter to the three valve views, holds it still for the cycle window and takes
``--beats`` + 1 consecutive ECG-gated beats (the evaluation's 128-px pictures): the mean
raw similarity of consecutive beats (the ceiling) and the mean ROI error between them (the
floor), as ``run_recovery`` measures them at every saved view. The paper: 89.8 % and 2.0 mm.
Writes ``docs/figures/review_beat_floor.json`` (one row per sd, pair and view).
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

import icenav.sim.conditions as conditions
from icenav.eval.recovery import TARGETS, RecoveryConfig, raw_similarity, roi_error
from icenav.eval.recovery_bench import Bench

HERE = Path(__file__).parent
PAPER = (0.898, 2.0)
"""The paper's consecutive-beat similarity and ROI floor (mm)."""


def measure(sd: float, cat: int, pat: int, beats: int) -> list[dict[str, float | int | str]]:
    """Ceiling and floor at the three views of one pair with ``shape_sd_mm`` = ``sd``."""
    saved = conditions.CONDITIONS["in-vivo"]
    rhythm = replace(saved.rhythm, shape_sd_mm=sd)  # type: ignore[arg-type]
    conditions.CONDITIONS["in-vivo"] = replace(saved, rhythm=rhythm)
    try:
        b = Bench(RecoveryConfig(seed=cat, patient=pat, condition="in-vivo", rounds=2))
    finally:
        conditions.CONDITIONS["in-vivo"] = saved
    rows: list[dict[str, float | int | str]] = []
    for name in TARGETS:
        b.drive(b.operator.move_to(b.views[name]))
        b.drive(b.operator.dwell(0.5))
        b.hold_still(b.cycle_window_s)
        clips = [b.acquire() for _ in range(beats + 1)]
        pairs = list(zip(clips, clips[1:], strict=False))
        sims = [raw_similarity(c1, c0) for c0, c1 in pairs]
        rois = [r for r in (roi_error(c1, c0, name) for c0, c1 in pairs) if math.isfinite(r)]
        rows.append(dict(sd_mm=sd, catheter=cat, patient=pat, view=name,
                         ceiling=float(np.mean(sims)),
                         roi_floor_mm=float(np.mean(rois)) if rois else math.nan))  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sd", default="0,0.4,0.5,0.6,0.7,1.0,1.3")
    ap.add_argument("--pairs", default="100:0,101:1,102:2,103:3,104:4")
    ap.add_argument("--beats", type=int, default=6)
    args = ap.parse_args()
    rows = []
    for sd in (float(x) for x in args.sd.split(",")):
        for pair in args.pairs.split(","):
            cat, pat = (int(x) for x in pair.split(":"))
            rows += measure(sd, cat, pat, args.beats)
        sel = [r for r in rows if r["sd_mm"] == sd]
        print(
            f"| {sd:g} mm | {100 * np.mean([r['ceiling'] for r in sel]):.1f} % "
            f"| {np.nanmean([r['roi_floor_mm'] for r in sel]):.2f} mm | {len(sel)} |",
            flush=True,
        )
    print(f"| paper | {100 * PAPER[0]:.1f} % | {PAPER[1]} mm | |")
    (HERE / "review_beat_floor.json").write_text(json.dumps({"rows": rows}, indent=1))


if __name__ == "__main__":
    main()
