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

Session 11, third round (plants9): ``--wrap-profile 0,0.15,0.3,0.45,0.6,0.8,1`` writes no
spins but, per catheter and tension form, the held-out circle's residual with the capstan
exponent ``wrap`` held at each value and the rest refitted (the training fit of
:func:`~icenav.calibration.transmission.identify_transmission_form`, from the free fit with
the band's width kept at 45 deg); ``--wraps 0.3,0.6`` lets the form's choice try those held
wraps (not adopted: docs/results.md):

    python docs/figures/dev_ours_spins.py --cache /tmp/rec --wrap-profile 0,0.15,0.3,0.6,1 \
        --json docs/figures/families_dev210-214_s11_wrap_profile.json out-of-tolerance:210 ...

Session 12 (plants11): the spin circle changes the plan, so every catheter is recorded
anew (its own cache); the before is session 11's frozen records (the methods identical since):

    python docs/figures/dev_ours_spins.py --cache /tmp/rec12 \
        --json docs/figures/families_dev213-218_s12_circle.json default:213 ...

Session 13 (choice12): the form is chosen on the knob circle *and* the spin circle (the
product's ``fit_catheter``); ``--knob-circle-only`` reproduces the rule before (main 5d33249),
so both are measured on the same recordings:

    python docs/figures/dev_ours_spins.py --cache /tmp/rec13 --knob-circle-only \
        --json before.json default:213 ...
    python docs/figures/dev_ours_spins.py --cache /tmp/rec13 --before before.json \
        --json after.json default:213 ...

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

from icenav.calibration import transmission as tr
from icenav.calibration.catheter import DENSE_RASTER, fit_catheter
from icenav.calibration.plans import calibration_set_from
from icenav.calibration.procedure import run_procedure
from icenav.calibration.procedures import make_procedure
from icenav.calibration.tracker_bias import fit_tracker_bias_from
from icenav.compensation.section_length import fit_section_length
from icenav.eval.spin import _approach_path, _rmse, knob_map_commands, make_rig, run_spin
from icenav.geometry.kinematics import DEFAULT_GEOMETRY as G
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import spin_trajectory

NEUTRAL = ", extension='none', bend_tension=0.0, second_weight=0.0, second_width=1.0"


def recording(family: str, seed: int, cache: str | None) -> Any:
    """The catheter's calibration recording (from ``cache`` if kept there)."""
    proc = make_procedure("dense+hysteresis")
    path = None if cache is None else os.path.join(cache, f"{family}_{seed}.pkl")
    if path is not None and os.path.exists(path):
        with open(path, "rb") as f:
            return pickle.load(f)  # noqa: S301 (our own cache of a deterministic recording)
    rig, tracker = make_rig(seed, "straight", family)
    rig.reset()
    rec = run_procedure(proc, rig.move, tracker)
    if path is not None:
        with open(path, "wb") as f:
            pickle.dump(rec, f)
    return rec


def wrap_profile(family: str, seed: int, wraps: list[float], cache: str | None) -> dict[str, Any]:
    """Per tension form: the free training fit and the fits with ``wrap`` held at each of
    ``wraps`` (wrap, mu, kappa AP / RL, training and held-out residual in deg), the data
    and held-out middle circle as :func:`~icenav.calibration.transmission.build_transmission`
    builds them."""
    proc = make_procedure("dense+hysteresis")
    rec = recording(family, seed, cache)
    raster = np.asarray(proc.catheter_plan.raster)
    bias = fit_tracker_bias_from(rec)
    unbiased = bias.correct_calibration(calibration_set_from(rec, DENSE_RASTER).calibration)
    section = fit_section_length(unbiased, G)
    circles = tr.motion_from(rec, tr.KNOB_CIRCLES, tracker_bias=bias, geometry=G, section=section)
    dense = section.correct(unbiased)
    gap = np.max(np.abs(raster[None, :, :3] - dense.q_motor[:, None, :3]), axis=-1)
    obs = np.full((raster.shape[0], 2), np.nan)
    obs[np.argmin(gap, axis=1)] = tr.observed_knobs(dense.tip2base, G)
    motions = [tr.CalibrationMotion(q_motor=raster, observed=obs), circles]
    blocks = tr.circle_blocks(circles.q_motor)
    test = [np.zeros(raster.shape[0], dtype=bool), blocks == (int(blocks.max()) + 1) // 2]
    train = [~t for t in test]

    def row(fit: Any) -> list[float]:
        m = fit.model
        held = tr._held_out_rms(fit, motions, test, tr.FIT_LIMIT)
        return [m.wrap, m.friction, m.ap.tension_play, m.rl.tension_play] + [
            math.degrees(fit.rms),
            math.degrees(held),
        ]

    out: dict[str, Any] = {}
    for form in ("added", "stretch"):
        free = tr.identify_transmission(
            motions, coupling_form=form, extension="none", masks=train, max_nfev=20
        )
        out[form] = {"free": row(free)}
        for w in wraps:
            fit = tr.identify_transmission(
                motions,
                initial=tr._with_wrap(free.model, w),
                masks=train,
                max_nfev=20,
                wrap_range=(w, w),
            )
            out[form][f"{w:g}"] = row(fit)
    return out


def one(
    family: str, seed: int, cache: str | None = None, before: dict[str, Any] | None = None
) -> dict[str, Any]:
    proc = make_procedure("dense+hysteresis")
    rec = recording(family, seed, cache)
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
    # and records written before the circle residual have no residual field
    out["model"] = out["model"].replace(", residual=None", "")
    plain = out["model"].replace(NEUTRAL, "") if fit.model.extension == "none" else None
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
    ap.add_argument("--wrap-profile", help="comma-separated wraps: profile the fit, no spins")
    ap.add_argument("--wraps", help="comma-separated wraps the form's choice tries (default none)")
    ap.add_argument(
        "--no-residual", action="store_true", help="do not try the circle residual (the default)"
    )
    ap.add_argument(
        "--residual", action="store_true", help="try the circle residual (plants10's records)"
    )
    ap.add_argument("--max-gain", type=float, help="the bound of kappa and gamma (default 1)")
    ap.add_argument(
        "--knob-circle-only",
        action="store_true",
        help="choose the form on the held-out knob circle alone (the rule before session 13)",
    )
    args = ap.parse_args()
    if args.knob_circle_only:
        plain_form = tr.identify_transmission_form

        def knob_circle_only(*a: Any, **k: Any) -> Any:
            k.pop("spin", None)
            return plain_form(*a, **k)

        tr.identify_transmission_form = knob_circle_only
    tr.TRIED_RESIDUAL = bool(args.residual) and not args.no_residual
    if args.max_gain is not None:
        plain_identify, gain = tr.identify_transmission, args.max_gain

        def identify(*a: Any, **k: Any) -> Any:
            k.setdefault("max_gain", gain)
            return plain_identify(*a, **k)

        tr.identify_transmission = identify
    if args.wraps:
        tr.TRIED_WRAPS = tuple(float(w) for w in args.wraps.split(","))
    before: dict[str, Any] = {}
    if args.before:
        with open(args.before) as f:
            before = json.load(f)
    res = {}
    for spec in args.catheters:
        family, seed = spec.split(":")
        if args.wrap_profile:
            ws = [float(w) for w in args.wrap_profile.split(",")]
            res[spec] = wrap_profile(family, int(seed), ws, args.cache)
            print(spec, res[spec], flush=True)
            with open(args.json, "w") as f:
                json.dump(res, f, indent=1)
            continue
        res[spec] = one(family, int(seed), args.cache, before.get(spec))
        print(spec, res[spec]["fit_rms_deg"], res[spec]["spins"], flush=True)
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
