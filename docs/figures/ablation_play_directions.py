"""A development ablation of session 7 (docs/results.md, round 3), kept to reproduce it: the
method now does this itself (``KnobPlanePlay``, docs/calibration.md section 4); here the
plan's own further directions are switched off (``play_directions=()``) so that "ours" is
the AP-only method the ablation compared against. The roll's and the
twist's plays measured with the section bent in four directions of the knob plane (the AP
knob, the diagonal, the RL knob, the anti-diagonal: the same roll sweeps at three bends
each) and used by the direction of the intended bend, against ours (the AP knob only).

Ours' controller map (``TendonKnobMap``) is subclassed here to look the plays up by the
bend's direction (a periodic interpolation over 0 / 45 / 90 / 135 deg); nothing else
changes. It reports the true pose's RMS errors of the paper's spin at 20 / 40 / 60 deg.
Development catheters only (210-229):

    python docs/figures/ablation_play_directions.py nonlinear-play 210 [one-bend]

With ``one-bend`` each extra direction is swept at one bend only (the AP knob's 50 deg,
turned to that direction: 87 moves a direction) and its law is the AP law scaled by the
ratio of that sweep's play per rad of bend to the AP one's (``*_per_bend``).
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from typing import Any

import numpy as np

import icenav.calibration.catheter as C
from icenav.calibration.hysteresis import fit_hysteresis, hysteresis_plan
from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.compensation.tendon_map import TendonKnobMap
from icenav.eval import spin as S
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import spin_trajectory

fam, seed = sys.argv[1], int(sys.argv[2])
one_bend = len(sys.argv) > 3 and sys.argv[3] == "one-bend"
if not 210 <= seed <= 229:
    raise SystemExit("development catheters only (210-229)")
_plan = C.hysteresis_plan
C.hysteresis_plan = lambda **kw: _plan(play_directions=(), **kw)  # ours as in session 7
cal = S.calibrate(seed, fam)
base = cal.catheter.hysteresis.compensator
laws: dict[float, tuple[Any, Any]] = {0.0: (base.roll_play, base.twist_play)}
for psi_deg in (45.0, 90.0, 135.0):
    psi = math.radians(psi_deg)
    hp = (
        hysteresis_plan(joints=(2,), more_roll_bends=())
        if one_bend
        else hysteresis_plan(joints=(2,), play_directions=())
    )
    q = hp.plan.q_motor.copy()
    k = q[:, 0].copy()
    q[:, 0], q[:, 1] = k * math.cos(psi), k * math.sin(psi)
    hp2 = replace(hp, plan=replace(hp.plan, q_motor=q))
    rig, tr = S.make_rig(seed, "straight", fam)
    rig.reset()
    comp = fit_hysteresis(hp2, run_visits(plan_visits(hp2.plan), rig.move, tr)).compensator
    if one_bend:
        kr = comp.roll_play_per_bend / max(base.roll_play_per_bend, 1e-9)
        kt = comp.twist_play_per_bend / max(base.twist_play_per_bend, 1e-9)
        ap_roll, ap_twist = base.roll_play, base.twist_play

        def scaled(law: Any, k: float) -> Any:
            return lambda b, law=law, k=k: k * law(b)

        laws[psi_deg] = (scaled(ap_roll, kr), scaled(ap_twist, kt))
        print(psi_deg, f"roll x{kr:.2f}, twist x{kt:.2f} of the AP laws", flush=True)
        continue
    laws[psi_deg] = (comp.roll_play, comp.twist_play)
    print(
        psi_deg,
        "roll",
        comp.roll_play.describe(),
        "| twist",
        comp.twist_play.describe(),
        flush=True,
    )
print(0, "roll", base.roll_play.describe(), "| twist", base.twist_play.describe())
dirs = np.array(sorted(laws))


def blend(which: int, b: float, theta: float) -> float:
    t = math.degrees(theta) % 180.0
    xs = np.append(dirs, 180.0)
    vals = [float(laws[d][which](b)) for d in dirs]
    vals.append(vals[0])
    return float(np.interp(t, xs, vals))


class DirMap(TendonKnobMap):
    _theta = 0.0

    def _advance(self, q: Any) -> None:
        z1, z2 = self._knobs.effective_knobs
        kk = self._f.motor_to_model(np.array([z1, z2, 0.0, 0.0]), check=False)
        self._theta = math.atan2(float(kk[1]), float(kk[0]))
        return super()._advance(q)

    def _command(self, q: Any) -> Any:
        saved = self._theta
        self._theta = math.atan2(float(q[1]), float(q[0]))
        try:
            return super()._command(q)
        finally:
            self._theta = saved

    def _roll_extra(self, bend: float, direction: float = 0.0) -> float:
        return blend(0, bend, self._theta)

    def _twist_extra(self, bend: float, direction: float = 0.0) -> float:
        return blend(1, bend, self._theta)


for bend in (20, 40, 60):
    qm = spin_trajectory([math.radians(bend), 0, 0, 0], 360, include_end=True).q_model
    path = S._approach_path(qm)
    res = []
    for name in ("ours", "ours+directions"):
        m = cal.catheter.knob_map()
        if name != "ours":
            m.__class__ = DirMap
        cmd = S.knob_map_commands(m, path)
        rig, tr = S.make_rig(seed, "straight", fam)
        true, em = S.run_spin(rig, tr, cmd)
        mm, deg = S._rmse(true, forward(qm, check=False))
        res.append(f"{name} {mm:.2f} mm {deg:.2f} deg")
    print(fam, seed, bend, " | ".join(res), flush=True)
