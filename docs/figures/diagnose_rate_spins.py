"""Where ours' 60-deg position error on `rate-dependent` comes from (session 13, rate12;
docs/results.md "Plant families"). Truth read for the diagnosis only; development seeds only.

For each catheter: ours' (``dense+hysteresis``) calibration recorded once (the recording cache
of ``dev_ours_spins.py``) and fitted at the source tree, then the spin of ``icenav eval spin``
(360 samples, one way; ``--both-ways`` also the other way) through the controller's map, the
plant's state read at every sample. The true position error is split in the base frame into
its **radial** part (along the tip's intended offset from the shaft axis: the bend's size),
its **tangential** part (across it: the bending plane's direction) and its **axial** part; the
plane's direction error (effective knob direction plus the section's roll, against the
intended) into the **roll's** part (the plant's section roll against the map's model of it,
``TendonKnobMap._p3``) and the **knobs'** (the rest: the transmission's and F's); the tendons'
creep (R6 of docs/digital-twin.md) against its steady value ``c_c T`` in the spin and, with
``--calibration-state``, at every reading of the calibration replayed on a fresh plant (by
phase). ``--samples N`` spins in N samples instead of 360 (the pace test: the same turn in
steps 360/N times as large); ``--circle-step DEG`` fits ours on a recording whose knob
circles go in DEG steps (the transmission's data at another pace). The quarter means of the
tangential error show whether it grows with the time since the spin began (a lag that builds
up) or is a level.

    python docs/figures/diagnose_rate_spins.py --cache /tmp/rec --seeds 213,214,218 \
        --both-ways --calibration-state --json docs/figures/families_dev213-218_s13_rate.json
    python docs/figures/diagnose_rate_spins.py --cache /tmp/rec --seeds 213,214,218 \
        --samples 60 --json pace60.json
"""

from __future__ import annotations

import argparse
import json
import math
import pickle
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from dev_ours_spins import recording  # noqa: E402

from icenav.calibration.catheter import catheter_plan, fit_catheter  # noqa: E402
from icenav.calibration.procedure import run_procedure, run_visits  # noqa: E402
from icenav.calibration.procedures import make_procedure, plan_visits  # noqa: E402
from icenav.eval.spin import (  # noqa: E402
    APPROACH_STEPS,
    _approach_path,
    knob_map_commands,
    make_rig,
)
from icenav.geometry.kinematics import DEFAULT_GEOMETRY as G  # noqa: E402
from icenav.geometry.kinematics import forward  # noqa: E402
from icenav.geometry.trajectories import spin_trajectory  # noqa: E402


def _rms(x: Any) -> float:
    return float(np.sqrt(np.mean(np.asarray(x) ** 2)))


def _wrap_deg(a: Any) -> Any:
    return np.degrees((np.asarray(a) + np.pi) % (2 * np.pi) - np.pi)


def spin(cat: Any, family: str, seed: int, bend: int, samples: int, direction: int) -> dict:
    """One spin through ours' map with the plant's state read (see the module's doc)."""
    sp = spin_trajectory(
        [math.radians(bend), 0.0, 0.0, 0.0], samples, include_end=True, direction=direction
    )
    q = sp.q_model
    km = cat.knob_map(np.zeros(4), G)
    model_roll: list[float] = []

    class Recording:  # the map as the controller drives it, noting its model of the roll
        def model_to_motor(self, q_model: Any, *, check: bool = True) -> Any:
            return km.model_to_motor(q_model, check=check)

        def observe(self, q_motor: Any) -> None:
            km.observe(q_motor)
            model_roll.append(km._p3)

    cmd = knob_map_commands(Recording(), _approach_path(q))
    rig, _tracker = make_rig(seed, "straight", family)
    plant = rig.robot.plant
    rig.reset()
    rows: list[dict[str, Any]] = []
    for i, c in enumerate(cmd):
        rig.move(c)
        if i < APPROACH_STEPS:
            continue
        s = plant.state
        rows.append(
            {
                "t": plant.time,
                "eff": s.effective_knobs,
                "roll": s.roll,
                "tip": s.tip2base[:3, 3],
                "creep": list(plant._creep),
                "tension": list(plant._t),
            }
        )
    p = np.array([r["tip"] for r in rows])
    want = forward(q, G, check=False)[:, :3, 3]
    e = p - want
    radial = want[:, :2] / np.linalg.norm(want[:, :2], axis=1)[:, None]
    er = np.sum(e[:, :2] * radial, axis=1)
    et = e[:, 0] * -radial[:, 1] + e[:, 1] * radial[:, 0]
    ez = e[:, 2]
    eff = np.array([r["eff"] for r in rows])
    roll = np.array([r["roll"] for r in rows])
    size = np.hypot(q[:, 0], q[:, 1])
    d_size = np.degrees(np.hypot(eff[:, 0], eff[:, 1]) - size)
    plane = _wrap_deg(
        np.arctan2(eff[:, 1], eff[:, 0]) + roll - q[:, 2] - np.arctan2(q[:, 1], q[:, 0])
    )
    roll_part = np.degrees(roll - np.array(model_roll[APPROACH_STEPS:]))
    creep = np.array([r["creep"] for r in rows])
    steady = plant.dynamics.creep_compliance_mm_per_n * np.array([r["tension"] for r in rows])
    n4 = len(et) // 4
    return {
        "family": family,
        "seed": seed,
        "bend_deg": bend,
        "samples": samples,
        "direction": direction,
        "duration_s": float(rows[-1]["t"] - rows[0]["t"]),
        "true_mm": _rms(np.linalg.norm(e, axis=1)),
        "radial_rms_mm": _rms(er),
        "radial_mean_mm": float(er.mean()),
        "tangential_rms_mm": _rms(et),
        "tangential_mean_mm": float(et.mean()),
        "tangential_quarter_means_mm": [float(et[k * n4 : (k + 1) * n4].mean()) for k in range(4)],
        "axial_rms_mm": _rms(ez),
        "axial_mean_mm": float(ez.mean()),
        "bend_size_rms_deg": _rms(d_size),
        "bend_size_mean_deg": float(d_size.mean()),
        "plane_rms_deg": _rms(plane),
        "plane_mean_deg": float(plane.mean()),
        "plane_roll_part_mean_deg": float(roll_part.mean()),
        "plane_roll_part_rms_deg": _rms(roll_part),
        "plane_knob_part_mean_deg": float((plane - roll_part).mean()),
        "plane_knob_part_rms_deg": _rms(plane - roll_part),
        "creep_fraction_of_steady": float(creep.sum() / steady.sum()),
        "creep_max_mm": float(creep.max()),
    }


def calibration_state(family: str, seed: int) -> dict[str, Any]:
    """The tendons' creep against its steady value at the calibration's readings, by phase
    (the calibration replayed on a fresh plant)."""
    rig, tracker = make_rig(seed, "straight", family)
    plant = rig.robot.plant
    rig.reset()
    cc = plant.dynamics.creep_compliance_mm_per_n
    phases: dict[str, list[float]] = {}

    def progress(_i: int, visit: Any) -> None:
        if visit.n_average > 0:
            acc = phases.setdefault(visit.phase, [0.0, 0.0, 0.0])
            acc[0] += 1
            acc[1] += float(np.sum(plant._creep))
            acc[2] += float(cc * np.sum(plant._t))

    run_procedure(make_procedure("dense+hysteresis"), rig.move, tracker, progress=progress)
    return {
        k: {"n": int(v[0]), "creep_fraction": v[1] / max(v[2], 1e-12)} for k, v in phases.items()
    }


def fitted(family: str, seed: int, cache: str | None, circle_step: float | None) -> Any:
    """Ours' calibration of the catheter; with ``circle_step`` (deg) the plan's knob circles
    in that step instead (the pace test of the transmission's data: not a plan of the
    product, its robot time is over the budget), recorded and cached under its own name."""
    proc = make_procedure("dense+hysteresis")
    if circle_step is None:
        return fit_catheter(proc.catheter_plan, recording(family, seed, cache), geometry=G)
    cplan = catheter_plan(circle_step=math.radians(circle_step))
    path = None if cache is None else Path(cache) / f"{family}_{seed}_circles{circle_step:g}.pkl"
    if path is not None and path.exists():
        with open(path, "rb") as f:
            rec = pickle.load(f)  # noqa: S301 (our own cache of a deterministic recording)
    else:
        rig, tracker = make_rig(seed, "straight", family)
        rig.reset()
        rec = run_visits(plan_visits(cplan.plan), rig.move, tracker)
        if path is not None:
            with open(path, "wb") as f:
                pickle.dump(rec, f)
    return fit_catheter(cplan, rec, geometry=G)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--family", default="rate-dependent")
    ap.add_argument("--seeds", required=True, help="comma-separated development seeds")
    ap.add_argument("--bend", type=int, default=60)
    ap.add_argument("--samples", type=int, default=360)
    ap.add_argument("--both-ways", action="store_true")
    ap.add_argument("--calibration-state", action="store_true")
    ap.add_argument("--circle-step", type=float, help="knob circles' step (deg; see fitted)")
    ap.add_argument("--cache", help="recording cache of dev_ours_spins.py")
    ap.add_argument("--json", required=True)
    a = ap.parse_args()
    out = []
    for seed in (int(s) for s in a.seeds.split(",")):
        cat = fitted(a.family, seed, a.cache, a.circle_step)
        for direction in (-1, 1) if a.both_ways else (-1,):
            r = spin(cat, a.family, seed, a.bend, a.samples, direction)
            r["circle_step_deg"] = a.circle_step
            out.append(r)
            print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in r.items()}))
            sys.stdout.flush()
        if a.calibration_state:
            out.append({"seed": seed, "calibration": calibration_state(a.family, seed)})
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
