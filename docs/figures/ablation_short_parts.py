"""A development ablation, not the method (docs/results.md, "Short calibration, where its
error comes from"): ``short+rings`` with one of its parts replaced by what the full
calibration (ours, ``dense+hysteresis``) measured on the same catheter, to read how much of
the short calibration's excess error each missing measurement explains.

Variants, each spun as ``eval spin``'s ``short+rings`` is (twist pre-shaped, F+/F- by the
sense turned, the roll's play inverse at the intended bend):

- ``short``: the short calibration as it is;
- ``+length0``: without the section's length (the model's length, as before session 8);
- ``+plays``: the roll's and the twist's plays of ours (four sweeps, laws chosen by held-out
  residual) instead of the short one's two coarse sweeps (lines);
- ``+bias``: the tracker's field bias of ours (the roll circles) removed from the five
  points' and the ring stops' tips before F is built (F then aims the true tip, as ours);
- ``+plays+bias``: both;
- ``ours``: ``dense+hysteresis`` itself.

Reports EM and true RMS errors of the paper's spin at 20 / 40 / 60 deg. Development catheters
only (210-229)::

    python docs/figures/ablation_short_parts.py default 210 [OUT.json]
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from typing import Any

import numpy as np
from ablation_rows import variant_rows

from icenav.calibration.plans import Recording
from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.short import ShortRingCalibration, fit_short_rings, short_ring_plan
from icenav.eval import spin as S

fam, seed = sys.argv[1], int(sys.argv[2])
out_path = sys.argv[3] if len(sys.argv) > 3 else None
if not 210 <= seed <= 229:
    raise SystemExit("development catheters only (210-229)")

rig, tracker = S.make_rig(seed, "straight", fam)
five = S.run_calibration("five_point", rig, tracker).calibration_set
ours = S.run_calibration("dense+hysteresis", rig, tracker).details
rig.reset()
rplan = short_ring_plan()
rec = run_visits(plan_visits(rplan.plan), rig.move, tracker)
bias = ours.tracker_bias


def unbiased(recording: Recording) -> Recording:
    t = np.array(recording.tip2base)
    ok = recording.measured
    t[ok] = bias.correct_poses(t[ok])
    return Recording(plan=recording.plan, tip2base=t, attempts=recording.attempts)


plays = ours.hysteresis.compensator
variants: dict[str, ShortRingCalibration] = {
    "short": fit_short_rings(rplan, rec, five),
    "+length0": fit_short_rings(rplan, rec, five, fit_length=False),
}
variants["+plays"] = replace(variants["short"], hysteresis=plays)
with_bias = fit_short_rings(rplan, unbiased(rec), bias.correct_calibration(five))
variants["+bias"] = with_bias
variants["+plays+bias"] = replace(with_bias, hysteresis=plays)
print(
    f"{fam} {seed}: section length scale short {variants['short'].section.scale:.4f}, "
    f"ours {ours.transmission.section.scale:.4f}",
    flush=True,
)


def short_commands(sr: Any, q_model: Any) -> Any:
    """As ``icenav.eval.spin`` commands ``short+rings``."""
    return S.short_ring_commands(sr, q_model)


rows = variant_rows(rig, tracker, variants, ours, short_commands=short_commands)
if out_path:
    with open(out_path, "w") as fh:
        json.dump({"family": fam, "seed": seed, "rows": rows}, fh, indent=1)
