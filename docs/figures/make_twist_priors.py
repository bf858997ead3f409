"""Add the circle's twist (T0 of :mod:`icenav.calibration.play_prior`, session 13) to the
plant families' priors: for each family, on development catheters 215-217 (the priors' own
seeds, used for nothing else), from rest in the straight vessel, the plays' part of the full
calibration's plan (``catheter_plan().hysteresis``: the roll swept straight, at three bends
and in three further directions, then the spin circle) fitted as the full calibration fits
it, and the short calibration's own plan with its roll circle (``short_ring_plan(
bias_circle=True)``) read as the short calibration reads its twist
(:func:`icenav.calibration.short.short_twist_reading`); (T0) over the three, stored only
when most of the line's full calibrations took the circle's twist (their sweeps' law missed
the circle's readings, TC3 of :mod:`icenav.calibration.twist_circle`; where the sweeps' law
held, (P1)'s twist stays: the table would only change its level by the short reading's
own bias), and not for the lines of :data:`KEEP_P1` (measured worse on their development
catheters). The rest of each file (the plays' shapes, the map prior) is kept as it is::

    python docs/figures/make_twist_priors.py [SEEDS [FAMILIES]]    # default 215-217, all

rewrites ``src/icenav/eval/data/play_prior_<family>.json`` (version 3).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

from icenav.calibration.catheter import catheter_plan
from icenav.calibration.hysteresis import fit_hysteresis
from icenav.calibration.play_prior import load_play_prior, make_twist_circle, save_play_prior
from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.short import short_ring_plan, short_twist_reading
from icenav.compensation.bend_play import KnobPlanePlay
from icenav.eval import spin as S
from icenav.sim.families import FAMILIES

first, _, last = (sys.argv[1] if len(sys.argv) > 1 else "215-217").partition("-")
seeds = list(range(int(first), int(last or first) + 1))
if not all(215 <= s <= 217 for s in seeds):
    raise SystemExit("the priors' catheters only (215-217)")
out_dir = Path(__file__).resolve().parents[2] / "src" / "icenav" / "eval" / "data"
hplan = catheter_plan().hysteresis
splan = short_ring_plan(bias_circle=True)

# the line whose development catheters (210, 211) were spun worse with the table than with
# (P1)'s twist (docs/results.md, session 13: 60 deg 3.9 -> 5.3 and 3.6 -> 4.5 deg EM): its
# file keeps (P1)'s twist, although its full calibrations took the circle's (not diagnosed)
KEEP_P1 = ("distributed-friction",)

families = sys.argv[2].split(",") if len(sys.argv) > 2 else list(FAMILIES)
for family in families:
    comps, readings = [], []
    for seed in seeds:
        rig, tracker = S.make_rig(seed, "straight", family)
        rig.reset()
        rec = run_visits(plan_visits(hplan.plan), rig.move, tracker)
        comps.append(fit_hysteresis(hplan, rec).compensator)
        rig.reset()
        readings.append(
            short_twist_reading(splan, run_visits(plan_visits(splan.plan), rig.move, tracker))
        )
    path = out_dir / f"play_prior_{family}.json"
    prior = load_play_prior(path)
    circled = sum(
        isinstance(c.twist_play, KnobPlanePlay) and c.twist_play.period > math.pi for c in comps
    )
    if 2 * circled <= len(comps) or family in KEEP_P1:
        save_play_prior(dataclasses.replace(prior, twist_circle=None), path)
        print(f"{family}: {circled} of {len(comps)} took the circle's twist: no table", flush=True)
        continue
    try:
        table = make_twist_circle(comps, readings, prior.bends)
    except Exception as exc:  # no reading large enough: the file keeps (P1)'s twist
        print(f"{family}: {exc}", flush=True)
        continue
    save_play_prior(dataclasses.replace(prior, twist_circle=table), path)
    ref = int(round(math.degrees(prior.bends[0]) / 5.0))
    col = 15 - ref  # 75 deg of bend
    print(
        f"{family}: {circled} of {len(comps)} took the circle's twist; short readings "
        + " / ".join(f"{math.degrees(r):.2f}" for r in readings)
        + " deg; T at 75 deg over 0 / 90 / 180 / 270 deg "
        + " / ".join(f"{table[k][col]:.2f}" for k in (0, 3, 6, 9))
        + f" -> {path.name}",
        flush=True,
    )
