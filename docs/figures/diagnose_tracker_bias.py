"""Is ours' estimate of the tracker's field bias right? (session 13, field12; development
catheters only; the tracker's truth is read for the diagnosis only, never by a method).

Per catheter (the console's ``dense+hysteresis`` recording, kept in ``--cache``), ours is
fitted (``--variants``) with the tracker-bias estimate of the source tree (``ours``:
``fit_catheter``, the field chosen between the affine and the quadratic form by held-out
roll circles), with the affine field forced (``affine``: the method before session 13) and,
for the diagnosis, with an *oracle* correction of the calibration's tracked tips
(``oracle``: the tracker's own noise-free error at each recorded pose, truth).
Each is spun from 20 / 40 / 60 deg (360 samples, the controller's map, a fresh rig per
spin). At every spin sample the tracker's error is split (base frame, tip position, mm):

    e_i = m_i - p_i = j_i + d_i,     d_i = the tracker's noise-free error at the true pose
    d_i = dbar + (d_i - dbar),       dbar = mean_i d_i (the best base-frame field at the
                                      spin point: the tip barely moves during a spin)

``jitter`` = RMS |j_i|, ``turning`` = RMS |d_i - dbar| (orientation-dependent, the metal that
turns with the roll: no base-frame field can describe it), ``mean`` = |dbar|, ``fit`` =
|dbar - bhat(p)| (ours' affine estimate at the spin point against the best field there;
only its xy part turns with the roll), and the true / EM RMSE of each variant.

    python docs/figures/diagnose_tracker_bias.py --cache /tmp/field12/rec \\
        --json docs/figures/families_dev213-218_s13_bias.json default:213 ...
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import sys
import time
from typing import Any

import numpy as np

from icenav.calibration.catheter import DENSE_RASTER, fit_catheter
from icenav.calibration.plans import calibration_set_from
from icenav.calibration.procedures import make_procedure
from icenav.calibration.tracker_bias import fit_tracker_bias_from
from icenav.compensation.elasticity import CalibrationSet
from icenav.eval.spin import _approach_path, _rmse, knob_map_commands, make_rig
from icenav.geometry.kinematics import DEFAULT_GEOMETRY as G
from icenav.geometry.kinematics import forward
from icenav.geometry.se3 import rotvec_to_matrix
from icenav.geometry.trajectories import spin_trajectory

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from dev_ours_spins import recording  # noqa: E402  (the same cache of recordings)

BENDS = (20, 40, 60)


def noise_free_tip(tracker: Any, tip2base: np.ndarray, roll: float = 0.0, d4: float = 0.0) -> Any:
    """The tip pose (4, 4) the tracker reads without jitter for a true tip pose (truth)."""
    inner = getattr(tracker, "_inner", tracker)
    cfg = inner.config
    sensor = np.linalg.inv(cfg.tracker2base) @ tip2base @ cfg.sensor2tip
    if hasattr(tracker, "_inner"):  # the field-distortion family's tracker
        bp, br = tracker.distortion_at(sensor[:3, 3], sensor[:3, :3], roll, d4)
    else:
        bp, br = tracker.distortion_at(sensor[:3, 3])
    meas = np.eye(4)
    meas[:3, :3] = rotvec_to_matrix(br) @ sensor[:3, :3]
    meas[:3, 3] = sensor[:3, 3] + bp
    return tracker.registration.tip2base(meas)


class OracleBias:
    """Truth, for the diagnosis only: removes the tracker's noise-free error at each tracked
    pose (roll 0, translation 0: the raster's and the knob circles' stops)."""

    def __init__(self, tracker: Any) -> None:
        self.tracker = tracker

    def correct_poses(self, tip2base: Any) -> Any:
        t = np.array(tip2base, dtype=np.float64, copy=True)
        flat = t.reshape(-1, 4, 4)
        for k, m in enumerate(flat):
            if not np.all(np.isfinite(m)):
                continue
            x = m.copy()
            for _ in range(4):  # solve x + d(x) = m
                x[:3, 3] = m[:3, 3] - (noise_free_tip(self.tracker, x)[:3, 3] - x[:3, 3])
            flat[k, :3, 3] = x[:3, 3]
        return flat.reshape(t.shape)

    def correct_calibration(self, c: CalibrationSet) -> CalibrationSet:
        return CalibrationSet(
            q_motor=c.q_motor,
            tip2base=self.correct_poses(c.tip2base),
            catheter_id=c.catheter_id,
            vessel=c.vessel,
            created=c.created,
            method=f"{c.method}+oracle",
            notes=c.notes,
        )


def _constant(value: Any, *_: Any, **__: Any) -> Any:
    return value


def spins(cat: Any, family: str, seed: int, bhat: Any) -> dict[str, Any]:
    """Ours' spins of ``cat``; per bend the RMSEs and the tracker's error split."""
    out: dict[str, Any] = {}
    for bend in BENDS:
        sp = spin_trajectory([math.radians(bend), 0.0, 0.0, 0.0], 360, include_end=True)
        cmd = knob_map_commands(cat.knob_map(np.zeros(4), G), _approach_path(sp.q_model))
        rig, tracker = make_rig(seed, "straight", family)
        rig.reset()
        n_skip = cmd.shape[0] - sp.q_model.shape[0]
        true, em, clean = [], [], []
        for i, q in enumerate(cmd):
            pose = rig.move(q)
            if i < n_skip:
                continue
            true.append(pose)
            clean.append(noise_free_tip(tracker, pose, float(q[2]), float(q[3])))
            m = tracker.measure_tip2base()
            em.append(np.full((4, 4), np.nan) if m is None else m)
        t, e, c = np.array(true), np.array(em), np.array(clean)
        intended = forward(sp.q_model, G, check=False)
        ok = np.all(np.isfinite(e.reshape(len(e), -1)), axis=1)
        p = t[:, :3, 3]
        d = c[:, :3, 3] - p
        j = e[ok, :3, 3] - c[ok, :3, 3]
        dbar = d.mean(axis=0)
        b = np.asarray(bhat.at(p.mean(axis=0))) if bhat is not None else np.zeros(3)
        out[str(bend)] = {
            "em": _rmse(e[ok], intended[ok]),
            "true": _rmse(t, intended),
            "noise_free": _rmse(c, intended),
            "jitter_mm": float(np.sqrt(np.mean(np.sum(j**2, axis=1)))),
            "turning_mm": float(np.sqrt(np.mean(np.sum((d - dbar) ** 2, axis=1)))),
            "mean_mm": [float(v) for v in dbar],
            "bhat_mm": [float(v) for v in b],
            "fit_xy_mm": float(np.hypot(*(dbar - b)[:2])),
            "fit_z_mm": float(abs((dbar - b)[2])),
            "true_xy_radius_mm": float(np.sqrt(np.mean(np.sum((p - p.mean(0))[:, :2] ** 2, 1)))),
        }
    return out


def one(family: str, seed: int, cache: str | None, variants: list[str]) -> dict[str, Any]:
    proc = make_procedure("dense+hysteresis")
    rec = recording(family, seed, cache)
    out: dict[str, Any] = {}
    for v in variants:
        t0 = time.time()
        if v in ("ours", "affine"):
            # ours as the source tree fits it; "affine": its field forced affine (TB1)
            import icenav.calibration.catheter as cc

            plain = cc.fit_tracker_bias_from
            if v == "affine":
                cc.fit_tracker_bias_from = functools.partial(plain, quadratic=False)
            try:
                cat = fit_catheter(proc.catheter_plan, rec, geometry=G)
            finally:
                cc.fit_tracker_bias_from = plain
            bhat = cat.tracker_bias
        else:
            import icenav.calibration.catheter as cc

            _, tracker = make_rig(seed, "straight", family)
            plain = cc.fit_tracker_bias_from
            oracle = OracleBias(tracker)
            cc.fit_tracker_bias_from = functools.partial(_constant, oracle)  # type: ignore
            try:
                cat = fit_catheter(proc.catheter_plan, rec, geometry=G)
            finally:
                cc.fit_tracker_bias_from = plain
            bhat = fit_tracker_bias_from(rec)
        out[v] = {"fit_s": time.time() - t0, "spins": spins(cat, family, seed, bhat)}
        out[v]["quadratic"] = bhat.quadratic is not None
        # the estimate against the truth at the raster's tracked tips
        if v in ("ours", "affine"):
            _, tracker = make_rig(seed, "straight", family)
            dense = calibration_set_from(rec, DENSE_RASTER).calibration
            m = dense.tip2base
            ok = np.all(np.isfinite(m.reshape(len(m), -1)), axis=1)
            truth = m[ok, :3, 3] - OracleBias(tracker).correct_poses(m[ok])[:, :3, 3]
            err = truth - bhat.at(m[ok, :3, 3])
            out[v]["raster_truth_rms_mm"] = float(np.sqrt(np.mean(np.sum(truth**2, 1))))
            out[v]["raster_fit_err_rms_mm"] = float(np.sqrt(np.mean(np.sum(err**2, 1))))
            out[v]["raster_fit_err_xy_rms_mm"] = float(np.sqrt(np.mean(np.sum(err[:, :2] ** 2, 1))))
            out[v]["tb_residual_mm"] = bhat.rms_residual_mm
        print(family, seed, v, json.dumps(out[v]["spins"]), flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("catheters", nargs="+", help="family:seed")
    ap.add_argument("--json", required=True)
    ap.add_argument("--cache")
    ap.add_argument("--variants", default="ours,oracle")
    args = ap.parse_args()
    res: dict[str, Any] = {}
    if os.path.exists(args.json):
        with open(args.json) as f:
            res = json.load(f)
    for c in args.catheters:
        fam, s = c.split(":")
        r = one(fam, int(s), args.cache, args.variants.split(","))
        res.setdefault(c, {}).update(r)
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
