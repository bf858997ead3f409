"""Ours (``dense+hysteresis``) on development catheters of the plant families: the console's
calibration recorded once per catheter, fitted by :func:`icenav.calibration.catheter.fit_catheter`
of the source tree, and the spins of ``icenav eval spin`` (20 / 40 / 60 deg, 360 samples, the
controller's map; one fresh rig per spin, the tracker's noise sequence the same at every
commit). Session 10's before / after of the tension's form (docs/results.md):

    python docs/figures/dev_ours_spins.py --json before.json default:213 ...   # at b4a65da
    python docs/figures/dev_ours_spins.py --json after.json default:213 ...    # after

Session 11's after (the band's extensions; before = session 10's frozen records):

    python docs/figures/dev_ours_spins.py --cache /tmp/rec \
        --before docs/figures/families_dev213-218_s10_smoothing.json \
        --json docs/figures/families_dev213-218_s11_after.json default:213 ...

``--cache DIR`` keeps each catheter's recording (deterministic: the same at every commit) so
a second run fits and spins without recording again; ``--before FILE`` (records of the same
catheters) keeps their spins where the fitted model is the same (a deterministic repeat).

Each record: the transmission fit's residual (deg), its form and held-out scores, the fit's
wall time and per bend (EM mm, EM deg, true mm, true deg). Development seeds only. (The
session-10 records were written by this loop before it kept the held-out scores.)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pickle
import time
from typing import Any

import numpy as np

from icenav.calibration.catheter import fit_catheter
from icenav.calibration.procedure import run_procedure
from icenav.calibration.procedures import make_procedure
from icenav.eval.spin import _approach_path, _rmse, knob_map_commands, make_rig, run_spin
from icenav.geometry.kinematics import DEFAULT_GEOMETRY as G
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import spin_trajectory

NEUTRAL = ", extension='none', bend_tension=0.0, second_weight=0.0, second_width=1.0"


def one(
    family: str, seed: int, cache: str | None = None, before: dict[str, Any] | None = None
) -> dict[str, Any]:
    proc = make_procedure("dense+hysteresis")
    path = None if cache is None else os.path.join(cache, f"{family}_{seed}.pkl")
    if path is not None and os.path.exists(path):
        with open(path, "rb") as f:
            rec = pickle.load(f)  # noqa: S301 (our own cache of a deterministic recording)
    else:
        rig, tracker = make_rig(seed, "straight", family)
        rig.reset()
        rec = run_procedure(proc, rig.move, tracker)
        if path is not None:
            with open(path, "wb") as f:
                pickle.dump(rec, f)
    t = time.time()
    cat = fit_catheter(proc.catheter_plan, rec, geometry=G)
    fit = cat.transmission.fit
    out: dict[str, Any] = {
        "fit_rms_deg": math.degrees(fit.rms),
        "fit_s": time.time() - t,
        "model": str(fit.model),
        "held_out_deg": {k: math.degrees(v) for k, v in getattr(fit, "held_out_rms", ())},
        "spins": {},
    }
    # records written before the model's extensions have no extension fields in its repr
    plain = str(fit.model).replace(NEUTRAL, "") if fit.model.extension == "none" else None
    if before is not None and before.get("model") in (out["model"], plain):
        # the same model as the record before: the spins are deterministic, so they are its
        out["spins"] = before["spins"]
        out["spins_from_before"] = True
        return out
    for bend in (20, 40, 60):
        sp = spin_trajectory([math.radians(bend), 0.0, 0.0, 0.0], 360, include_end=True)
        cmd = knob_map_commands(cat.knob_map(np.zeros(4), G), _approach_path(sp.q_model))
        rig, tracker = make_rig(seed, "straight", family)
        true, em = run_spin(rig, tracker, cmd)
        intended = forward(sp.q_model, G, check=False)
        ok = np.all(np.isfinite(em.reshape(len(em), -1)), axis=1)
        out["spins"][str(bend)] = (*_rmse(em[ok], intended[ok]), *_rmse(true, intended))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("catheters", nargs="+", help="family:seed")
    ap.add_argument("--json", required=True)
    ap.add_argument("--cache", help="directory of recordings kept between runs (pickles)")
    ap.add_argument(
        "--before",
        help="records of the same catheters: a catheter whose fitted model is "
        "the same as there keeps their spins (deterministic) instead of spinning again",
    )
    args = ap.parse_args()
    before: dict[str, Any] = {}
    if args.before:
        with open(args.before) as f:
            before = json.load(f)
    res = {}
    for spec in args.catheters:
        family, seed = spec.split(":")
        res[spec] = one(family, int(seed), args.cache, before.get(spec))
        print(spec, res[spec]["fit_rms_deg"], res[spec]["spins"], flush=True)
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
