"""A development diagnosis, not the method (docs/results.md, session 9, "`out-of-tolerance` at
60 deg"): ours' (``dense+hysteresis``) spin error on one catheter, from the twin's *true*
pose, decomposed in the base frame into the axial (along the shaft), radial (away from the
axis) and tangential parts of the tip's error and the bend's error, overall and by quarter
of the knob circle the spin's knobs pass through. Development catheters only (210-214)::

    python docs/figures/diagnose_spin_error.py out-of-tolerance 211 [20,60]
"""

from __future__ import annotations

import math
import sys

import numpy as np

from icenav.eval import spin as S
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import spin_trajectory

fam, seed = sys.argv[1], int(sys.argv[2])
bends = [int(b) for b in (sys.argv[3] if len(sys.argv) > 3 else "60").split(",")]
if not 210 <= seed <= 214:
    raise SystemExit("development catheters 210-214 only")
rig, tracker = S.make_rig(seed, "straight", fam)
ours = S.run_calibration("dense+hysteresis", rig, tracker).details
print(f"{fam} {seed}: section length scale {ours.transmission.section.scale:.4f}", flush=True)


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


for bend in bends:
    sp = spin_trajectory([math.radians(bend), 0.0, 0.0, 0.0], 360, include_end=True)
    intended = forward(sp.q_model, check=False)
    cmd = S.knob_map_commands(ours.knob_map(), S._approach_path(sp.q_model))
    true, _ = S.run_spin(rig, tracker, cmd)
    p_i, d = intended[:, :3, 3], true[:, :3, 3] - intended[:, :3, 3]
    out = p_i[:, :2] / np.linalg.norm(p_i[:, :2], axis=1, keepdims=True)
    radial = np.sum(d[:, :2] * out, axis=1)
    tangential = d[:, 1] * out[:, 0] - d[:, 0] * out[:, 1]
    axial = d[:, 2]
    bend_err = np.degrees(np.arccos(np.clip(true[:, 2, 2], -1, 1)))
    bend_err -= np.degrees(np.arccos(np.clip(intended[:, 2, 2], -1, 1)))
    print(
        f"  {bend} deg: |d| rms {rms(np.linalg.norm(d, axis=1)):.2f} mm; axial mean "
        f"{axial.mean():+.2f} rms {rms(axial):.2f}; radial mean {radial.mean():+.2f} rms "
        f"{rms(radial):.2f}; tangential mean {tangential.mean():+.2f} rms {rms(tangential):.2f}; "
        f"bend error mean {bend_err.mean():+.2f} rms {rms(bend_err):.2f} deg",
        flush=True,
    )
    knob_dir = np.degrees(np.arctan2(sp.q_model[:, 1], sp.q_model[:, 0])) % 360.0
    for q0 in range(0, 360, 90):
        m = (knob_dir >= q0) & (knob_dir < q0 + 90)
        print(
            f"    knobs {q0:3d}-{q0 + 90} deg: |d| {rms(np.linalg.norm(d[m], axis=1)):.2f} mm, "
            f"axial {axial[m].mean():+.2f} radial {radial[m].mean():+.2f} tangential "
            f"{tangential[m].mean():+.2f} mm, bend error {bend_err[m].mean():+.2f} deg",
            flush=True,
        )
