"""A development ablation, not the method (docs/results.md, "Session 9 (development)"):
where the short calibration's 100 moves and its play readings matter. ``short+rings``
variants on one development catheter, each spun as ``eval spin``'s ``short+rings`` (twist
pre-shaped, F+/F- by the sense turned, the roll's play inverse at the intended bend):

- ``base``: the short calibration as it is (10 stops a sense, sweeps in 20 deg steps);
- ``rl7``: one more bent roll sweep along the RL knob (25 deg steps), bought with three
  fewer ring stops a sense (7; 97 moves): the plays in two directions;
- ``s11``: 11 stops a sense, the sweeps in 25 deg steps (100 moves);
- ``oracle``: the plays of the full calibration's seven roll sweeps on the same catheter
  (an upper bound of what any play reading can give the short calibration);
- ``prior``: the family's play prior (``short+rings+prior``, icenav.calibration.play_prior).

Reports EM and true RMS errors of the paper's spin at 20 / 40 / 60 deg. Development catheters
only (210-214)::

    python docs/figures/ablation_short_plays.py FAMILY SEED [VARIANTS]
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import replace
from typing import Any

import numpy as np
from ablation_rows import error_row

from icenav.calibration.hysteresis import fit_hysteresis, hysteresis_plan
from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.short import fit_short_plays, fit_short_rings, short_ring_plan
from icenav.eval import spin as S
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import spin_trajectory

fam, seed = sys.argv[1], int(sys.argv[2])
wanted = sys.argv[3].split(",") if len(sys.argv) > 3 else ["base", "rl7", "s11", "oracle", "prior"]
if not 210 <= seed <= 214:
    raise SystemExit("development catheters 210-214 only (215-217 made the priors)")
rig, tracker = S.make_rig(seed, "straight", fam)
five = S.run_calibration("five_point", rig, tracker).calibration_set


def recorded(plan: Any) -> Any:
    rig.reset()
    return run_visits(plan_visits(plan), rig.move, tracker)


base_plan = short_ring_plan()
rec = recorded(base_plan.plan)
base = fit_short_rings(base_plan, rec, five)
variants = {"base": base}
if "rl7" in wanted:
    p7 = short_ring_plan(n_stops=7, play_directions=(math.pi / 2,), direction_step=math.radians(25))
    variants["rl7"] = fit_short_rings(p7, recorded(p7.plan), five)
if "s11" in wanted:
    p11 = short_ring_plan(n_stops=11, roll_step=math.radians(25))
    variants["s11"] = fit_short_rings(p11, recorded(p11.plan), five)
if "oracle" in wanted:
    hp = hysteresis_plan(joints=(2,))
    variants["oracle"] = replace(base, hysteresis=fit_hysteresis(hp, recorded(hp.plan)).compensator)
if "prior" in wanted:
    prior = S.family_play_prior(fam)
    variants["prior"] = replace(base, hysteresis=fit_short_plays(base_plan, rec, prior))


def short_commands(sr: Any, q_model: Any) -> Any:
    """As ``icenav.eval.spin`` commands ``short+rings``."""
    return S.short_ring_commands(sr, q_model)


rows: dict[str, list[float]] = {}
for name, sr in variants.items():
    e: list[float] = []
    for bend in S.BENDS_DEG:
        sp = spin_trajectory([math.radians(bend), 0.0, 0.0, 0.0], 360, include_end=True)
        intended = forward(sp.q_model, check=False)
        true, em = S.run_spin(rig, tracker, short_commands(sr, sp.q_model))
        ok = np.all(np.isfinite(em.reshape(len(em), -1)), axis=1)
        e += [*S._rmse(em[ok], intended[ok]), *S._rmse(true, intended)]
    rows[name] = e
    print(f"{fam} {seed} {name:7s} " + error_row(e), flush=True)
with open(f"short_plays_{fam}_{seed}.json", "w") as fh:
    json.dump({"family": fam, "seed": seed, "rows": rows}, fh, indent=1)
