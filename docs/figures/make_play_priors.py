"""Make the play priors of the plant families (docs/calibration.md section 7, "A prior for
the short calibration"): for each family, the full calibration's roll sweeps
(:func:`icenav.calibration.hysteresis.hysteresis_plan` with joints (2,), the plan and fit
:func:`icenav.calibration.catheter.catheter_plan` uses) on development catheters 215-217 of
that family, from rest in the straight vessel, and (P0) over their plays
(:func:`icenav.calibration.play_prior.make_play_prior`); then the full calibration's plan
(:func:`icenav.calibration.catheter.catheter_plan`) on the same catheters, from rest, and
(M0) over their dense rasters' tip interpolants, each with its tracker's bias and its
section's axial excess removed as :func:`icenav.calibration.catheter.fit_catheter` does
(:func:`icenav.calibration.map_prior.make_map_prior`, stored as the prior's ``map``). Each
family stands for one product line; the files are what a lab would make once from a few
catheters of a line::

    python docs/figures/make_play_priors.py [SEEDS [FAMILIES]]    # default 215-217, all

writes ``src/icenav/eval/data/play_prior_<family>.json`` (``eval spin``'s condition
``short+rings+prior`` reads them). Development catheters only (210-229); 215-217 are used
for nothing else.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from icenav.calibration.catheter import CatheterCalibration
from icenav.calibration.hysteresis import fit_hysteresis, hysteresis_plan
from icenav.calibration.map_prior import make_map_prior
from icenav.calibration.play_prior import make_play_prior, save_play_prior
from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.short import short_ring_plan
from icenav.eval import spin as S
from icenav.geometry.kinematics import forward
from icenav.sim.families import FAMILIES

first, _, last = (sys.argv[1] if len(sys.argv) > 1 else "215-217").partition("-")
seeds = list(range(int(first), int(last or first) + 1))
if not all(210 <= s <= 229 for s in seeds):
    raise SystemExit("development catheters only (210-229)")
out_dir = Path(__file__).resolve().parents[2] / "src" / "icenav" / "eval" / "data"
hplan = hysteresis_plan(joints=(2,))


def model_drive(full: CatheterCalibration, path: Any) -> Any:
    """The full calibration's model of catheter ``full`` driven along the motor knob path
    (n, 2) (rad) from rest: the tips (n, 3) (mm, knob frame, the section's model length)
    of the model states its per-tendon transmission and F_eff predict."""
    km = full.knob_map()
    tips = []
    for a, b in np.asarray(path, dtype=np.float64):
        q = np.array([a, b, 0.0, 0.0])
        km.observe(q)
        m = km.motor_to_model(q, check=False)
        m[3] = 0.0
        p = forward(m, check=False)[:3, 3]
        c, s = math.cos(m[2]), math.sin(m[2])
        tips.append([c * p[0] + s * p[1], -s * p[0] + c * p[1], p[2]])
    return np.array(tips)


families = sys.argv[2].split(",") if len(sys.argv) > 2 else list(FAMILIES)
for family in families:
    comps, tips = [], []
    for seed in seeds:
        rig, tracker = S.make_rig(seed, "straight", family)
        rig.reset()
        rec = run_visits(plan_visits(hplan.plan), rig.move, tracker)
        comps.append(fit_hysteresis(hplan, rec).compensator)
        full = S.run_calibration("dense+hysteresis", rig, tracker).details
        tips.append(functools.partial(model_drive, full))
    names = [f"{family} {s}" for s in seeds]
    prior = make_play_prior(comps, family, names)
    rings = short_ring_plan().rings  # the short calibration's ring stops, in order
    prior = dataclasses.replace(prior, map=make_map_prior(tips, family, names, rings))
    path = out_dir / f"play_prior_{family}.json"
    save_play_prior(prior, path)
    ap = prior.roll[0]
    print(
        f"{family}: roll AP shape at 25 / 50 / 75 / 100 deg "
        + " / ".join(f"{ap[int(b / 5) - 1]:.2f}" for b in (25, 50, 75, 100))
        + ", at 75 deg by direction "
        + " / ".join(f"{row[14]:.2f}" for row in prior.roll)
        + "; twist by direction "
        + " / ".join(f"{row[14]:.2f}" for row in prior.twist)
        + f"; spread {prior.spread[0]:.2f} / {prior.spread[1]:.2f}"
        + f"; map spread {prior.map.spread_mm:.2f} mm -> {path.name}",
        flush=True,
    )
