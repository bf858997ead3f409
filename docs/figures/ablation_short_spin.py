"""A development ablation, not the method (docs/calibration.md section 7, session 10):
``short+rings`` as it is (``rings``) against one change of its plan, each with and without
the play prior (``+prior``), every variant its own recording of its plan on the same
catheter (rig reset between), spun as ``eval spin``'s ``short+rings`` is. Sets:

- ``spin``: *spin rings* (``spin4``: the roll turned against the knobs,
  ``short_ring_plan(spin=True)``, four tracker samples a stop), and ours
  (``dense+hysteresis``) on the same catheter;
- ``average``: four tracker samples averaged at each ring stop (``rings4``);
- ``radii``: the rings on the spins' own knob radii, 20 / 40 / 60 deg (``at-spins``; a
  diagnosis of F between the rings, not a method: it would fit the protocol's bends);
- ``radii15``: rings at 15 / 45 / 75 deg of knob radius (``r15``: one inside the smallest
  bend spun);
- ``straight``: the straight roll sweep +-10 deg in 5 deg steps (``fine``, the same 13
  moves as +-30 deg in 15 deg steps).

Reports EM and true RMS errors of the paper's spin at 20 / 40 / 60 deg and writes them as
JSON (``rows``: variant -> [EM mm, EM deg, true mm, true deg] per bend). Development
catheters only (210-229)::

    python docs/figures/ablation_short_spin.py default 210 [OUT.json [SET]]
"""

from __future__ import annotations

import json
import math
import sys
from typing import Any

from ablation_rows import variant_rows

from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.short import fit_short_rings, short_ring_plan
from icenav.eval import spin as S

fam, seed = sys.argv[1], int(sys.argv[2])
out_path = sys.argv[3] if len(sys.argv) > 3 else None
which = sys.argv[4] if len(sys.argv) > 4 else "spin"
SETS: dict[str, list[tuple[str, dict[str, Any]]]] = {
    "spin": [("rings", {"spin": False, "n_average": 1}), ("spin4", {"spin": True, "n_average": 4})],
    "average": [("rings", {}), ("rings4", {"n_average": 4})],
    "radii": [
        ("rings", {}),
        ("at-spins", {"radii": tuple(math.radians(a) for a in (20.0, 40.0, 60.0))}),
    ],
    "radii15": [
        ("rings", {}),
        ("r15", {"radii": tuple(math.radians(a) for a in (15.0, 45.0, 75.0))}),
    ],
    "straight": [("rings", {}), ("fine", {"straight": (math.radians(10.0), math.radians(5.0))})],
}
if not 210 <= seed <= 229:
    raise SystemExit("development catheters only (210-229)")

rig, tracker = S.make_rig(seed, "straight", fam)
five = S.run_calibration("five_point", rig, tracker).calibration_set
ours = S.run_calibration("dense+hysteresis", rig, tracker).details if which == "spin" else None
prior = S.family_play_prior(fam)
variants: dict[str, Any] = {}
for name, kw in SETS[which]:
    rig.reset()
    plan = short_ring_plan(**kw)
    rec = run_visits(plan_visits(plan.plan), rig.move, tracker)
    variants[name] = fit_short_rings(plan, rec, five)
    variants[name + "+prior"] = fit_short_rings(plan, rec, five, prior=prior)

rows = variant_rows(rig, tracker, variants, ours, label=f"{fam} {seed} ")
if out_path:
    with open(out_path, "w") as fh:
        json.dump({"family": fam, "seed": seed, "set": which, "rows": rows}, fh, indent=1)
