"""Make the play priors of the plant families (docs/calibration.md section 7, "A prior for
the short calibration"): for each family, the full calibration's roll sweeps
(:func:`icenav.calibration.hysteresis.hysteresis_plan` with joints (2,), the plan and fit
:func:`icenav.calibration.catheter.catheter_plan` uses) on development catheters 215-217 of
that family, from rest in the straight vessel, and (P0) over their plays
(:func:`icenav.calibration.play_prior.make_play_prior`). Each family stands for one product
line; the files are what a lab would make once from a few catheters of a line::

    python docs/figures/make_play_priors.py [SEEDS]    # default 215-217

writes ``src/icenav/eval/data/play_prior_<family>.json`` (``eval spin``'s condition
``short+rings+prior`` reads them). Development catheters only (210-229); 215-217 are used
for nothing else.
"""

from __future__ import annotations

import sys
from pathlib import Path

from icenav.calibration.hysteresis import fit_hysteresis, hysteresis_plan
from icenav.calibration.play_prior import make_play_prior, save_play_prior
from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.eval import spin as S
from icenav.sim.families import FAMILIES

first, _, last = (sys.argv[1] if len(sys.argv) > 1 else "215-217").partition("-")
seeds = list(range(int(first), int(last or first) + 1))
if not all(210 <= s <= 229 for s in seeds):
    raise SystemExit("development catheters only (210-229)")
out_dir = Path(__file__).resolve().parents[2] / "src" / "icenav" / "eval" / "data"
hplan = hysteresis_plan(joints=(2,))
for family in FAMILIES:
    comps = []
    for seed in seeds:
        rig, tracker = S.make_rig(seed, "straight", family)
        rig.reset()
        rec = run_visits(plan_visits(hplan.plan), rig.move, tracker)
        comps.append(fit_hysteresis(hplan, rec).compensator)
    prior = make_play_prior(comps, family, [f"{family} {s}" for s in seeds])
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
        + f"; spread {prior.spread[0]:.2f} / {prior.spread[1]:.2f} -> {path.name}",
        flush=True,
    )
