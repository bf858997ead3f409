"""Diagnosis (development catheter 105, session 13, the lead): the circle residual in the
controller's own spin against the same compensation in ``eval spin``'s spin.

The console's "Dense + hysteresis" calibration runs as a controller task (simulated time, 25
Hz), with the circle residual tried (``TRIED_RESIDUAL`` set for this run only) or not; then
the installed compensation spins twice: in the controller (the bench's ``_spin_rms``: the
true tip's RMS distance from where the spin started) and, from a copy of it, through the
eval's protocol (a fresh rig, ``knob_map_commands``; absolute error and the same
stillness measure). Development seed only::

    python docs/figures/diagnose_residual_controller.py
"""

import copy
import math
import sys

import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[2]))
from benchmarks import bench_controller_spins as B

import icenav.calibration.transmission as T
from icenav.apps.wiring import make_sim_controller
from icenav.control.controller import ControllerConfig
from icenav.control.state import Mode
from icenav.eval import spin as S
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import spin_trajectory


def run(residual: bool):
    T.TRIED_RESIDUAL = residual
    t = [0.0]
    cfg = ControllerConfig(spin_feedback=False, rate_hz=25.0)
    session = make_sim_controller(seed=105, imaging=False, config=cfg, clock=lambda: t[0])
    ctrl, plant = session.controller, session.plant

    def step():
        t[0] += cfg.dt
        return ctrl.step()

    ctrl.start_calibration("dense+hysteresis")
    for _ in range(400000):
        if step().mode is Mode.IDLE:
            break
    for _ in range(3):
        step()
    comp = ctrl.compensation
    form = comp.calibration.fit.model.form
    comp_copy = copy.deepcopy(comp)
    ours = B._spin_rms(ctrl, plant, step)
    session.close()
    # the same compensation through the eval's spin (fresh rig, eval's approach)
    bend = 40
    sp = spin_trajectory([math.radians(bend), 0, 0, 0], 360, include_end=True)
    intended = forward(sp.q_model, check=False)
    rig, tracker = S.make_rig(105, "straight")
    cmd = S.knob_map_commands(comp_copy, S._approach_path(sp.q_model))
    true, em = S.run_spin(rig, tracker, cmd)
    absolute = S._rmse(true, intended)[0]
    tips = true[:, :3, 3]
    still = float(np.sqrt(np.mean(np.sum((tips - tips[0]) ** 2, -1))))
    print(
        f"residual={residual} form={form}: controller spin (stillness) {ours:.2f} mm | "
        f"eval spin absolute {absolute:.2f} mm, stillness {still:.2f} mm",
        flush=True,
    )


if __name__ == "__main__":
    for r in (False, True):
        run(r)
