"""A development check of the short calibration's rings (docs/calibration.md, section 7):
spins turned either way on one development catheter per family, ours and ``short+rings``
with the rings turned both ways (the default) and one way (``both_ways=False``).

``eval spin`` runs the paper's spin only (the knobs turn counter-clockwise); this script
also spins the other way (``spin_trajectory(direction=+1)``), which the one-way rings do not
hold. It reports the true pose's RMS errors (mm, deg) against the intended pose, as
``eval spin`` computes them (``_rmse``); the EM tracker's are left out (the script does not
register the tracker as the evaluation does). Development catheters only (210-229).

    python docs/figures/check_short_rings_sense.py default,nonlinear-play 213 OUT.json

Records: ``docs/figures/short_rings_sense_213.json`` (methods of e2fb282, 2026-11-24).
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import replace

from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.short import fit_short_rings, short_ring_plan
from icenav.eval import spin as S
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import spin_trajectory


def main() -> None:
    fams, seed, out_path = sys.argv[1].split(","), int(sys.argv[2]), sys.argv[3]
    if not 210 <= seed <= 229:
        raise SystemExit("development catheters only (210-229)")
    out = []
    for fam in fams:
        cal = S.calibrate(seed, fam, short_rings=True)
        rig, tracker = S.make_rig(seed, "straight", fam)
        rig.reset()
        one_way = short_ring_plan(both_ways=False)
        rec = run_visits(plan_visits(one_way.plan), rig.move, tracker)
        one = fit_short_rings(one_way, rec, cal.simplified.calibration_set)
        cals = {
            "dense+hysteresis": (S.OURS, cal),
            "short+rings": (S.SHORT_RINGS, cal),
            "short+rings one-way": (S.SHORT_RINGS, replace(cal, short_rings=one)),
        }
        for bend in (20, 40, 60):
            for direction in (-1, 1):
                q = spin_trajectory(
                    [math.radians(bend), 0, 0, 0], 360, include_end=True, direction=direction
                ).q_model
                for name, (cond, c) in cals.items():
                    cmd = S._commands(cond, q, c, None)
                    rig, tracker = S.make_rig(seed, "straight", fam)
                    true, _ = S.run_spin(rig, tracker, cmd)
                    mm, deg = S._rmse(true, forward(q, check=False))
                    sense = "ccw" if direction == -1 else "cw"
                    out.append(
                        {
                            "plant": fam,
                            "seed": seed,
                            "bend_deg": bend,
                            "knobs": sense,
                            "condition": name,
                            "true_position_mm": mm,
                            "true_rotation_deg": deg,
                        }
                    )
                    print(f"{fam} {seed} {bend} {sense:3s} {name:20s} {mm:.2f} mm {deg:.2f} deg")
    with open(out_path, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
