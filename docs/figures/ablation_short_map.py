"""A development measurement (docs/calibration.md section 7, session 12): ``short+rings``
with and without the product line's priors, every variant fitted on the SAME recording of
the short calibration's plan, and ours (``dense+hysteresis``) on the same catheter, spun as
``eval spin`` spins them (20 / 40 / 60 deg, EM and true). Variants:

- ``rings``: ``short+rings`` (no prior);
- ``plays``: the play prior only (``short+rings+prior`` until session 12);
- ``plays+map``: both (``short+rings+prior`` since session 12; M1 of
  :mod:`icenav.calibration.map_prior`);
- with ``all`` as a fourth argument also ``map`` (the map prior alone) and
  ``plays+map-scaled`` (both, the line's deviation scaled to the samples, M2); with
  ``plays`` ``map+ours-plays`` (a diagnosis, not a method: the map prior's F with ours'
  roll and twist plays, those of the full calibration's seven sweeps on the same catheter).

Writes ``{"family", "seed", "set": "map", "rows": variant -> [EM mm, EM deg, true mm, true
deg] per bend}`` (``make_short_spin_table.py`` reads a list of them under ``records``).
Development catheters only (210-214, 218-229; 215-217 made the priors)::

    python docs/figures/ablation_short_map.py default 210 [OUT.json [all | plays]]
"""

from __future__ import annotations

import dataclasses
import json
import sys
from typing import Any

from ablation_rows import variant_rows

from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.short import fit_short_rings, short_ring_plan
from icenav.eval import spin as S

fam, seed = sys.argv[1], int(sys.argv[2])
out_path = sys.argv[3] if len(sys.argv) > 3 else None
if not (210 <= seed <= 214 or 218 <= seed <= 229):
    raise SystemExit("development catheters only (210-214, 218-229)")

rig, tracker = S.make_rig(seed, "straight", fam)
five = S.run_calibration("five_point", rig, tracker).calibration_set
ours = S.run_calibration("dense+hysteresis", rig, tracker).details
prior = S.family_play_prior(fam)
rig.reset()
plan = short_ring_plan()
rec = run_visits(plan_visits(plan.plan), rig.move, tracker)
variants: dict[str, Any] = {
    "rings": fit_short_rings(plan, rec, five),
    "plays": fit_short_rings(plan, rec, five, prior=prior),
    "plays+map": fit_short_rings(plan, rec, five, prior=prior, map_prior=prior.map),
}
extra = sys.argv[4] if len(sys.argv) > 4 else ""
if extra == "plays":
    variants["map+ours-plays"] = dataclasses.replace(
        variants["plays+map"], hysteresis=ours.hysteresis.compensator
    )
if extra == "all":
    variants["map"] = fit_short_rings(plan, rec, five, map_prior=prior.map)
    variants["plays+map-scaled"] = fit_short_rings(
        plan, rec, five, prior=prior, map_prior=prior.map, map_scaled=True
    )
rows = variant_rows(rig, tracker, variants, ours, label=f"{fam} {seed} ", width=16)
if out_path:
    with open(out_path, "w") as fh:
        json.dump({"family": fam, "seed": seed, "set": "map", "rows": rows}, fh, indent=1)
