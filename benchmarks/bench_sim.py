"""Speed of the digital twin: plant step, 360-sample spin, 19 x 19 calibration raster.

Baseline, measured in the same run: the plain constant-curvature ``kinematics.forward`` call
(what a twin that is "the model plus noise" would cost).
"""

from __future__ import annotations

import math
import time

import numpy as np

from benchmarks.common import Result, time_per_call
from icenav.geometry.kinematics import forward
from icenav.sim import CatheterPlant, EMTracker
from icenav.sim.tuning import spin_trajectory


def _raster() -> np.ndarray:
    """The paper's 19 x 19 grid over +-90 deg, serpentine order (as a robot would drive it)."""
    ang = np.radians(np.arange(-90, 91, 10))
    rows = []
    for i, a in enumerate(ang):
        for b in ang if i % 2 == 0 else ang[::-1]:
            rows.append([a, b, 0.0, 0.0])
    return np.array(rows)


def main() -> list[Result]:
    plant = CatheterPlant(seed=0)
    rng = np.random.default_rng(0)
    # a 100 Hz console step: small knob motion from the current state
    qs = np.cumsum(rng.normal(scale=[0.01, 0.01, 0.02, 0.1], size=(4096, 4)), axis=0)
    qs[:, :2] = np.clip(qs[:, :2], -1.5, 1.5)
    i = [0]

    def step() -> None:
        plant.move(qs[i[0] & 4095])
        i[0] += 1

    t_step = time_per_call(step)
    q1 = qs[0]
    t_fk = time_per_call(lambda: forward(q1))

    spin = spin_trajectory(math.radians(60.0))

    def run_spin() -> None:
        plant.reset()
        plant.move_along(spin)

    t_spin = time_per_call(run_spin, min_time=0.5, repeat=3)
    t_spin_fk = time_per_call(lambda: [forward(q) for q in spin], min_time=0.5, repeat=3)

    raster = _raster()
    tracker = EMTracker(plant, seed=0)

    def run_raster() -> None:
        plant.reset()
        for q in raster:
            plant.move(q)
            tracker.measure_tip2base(n_average=4)

    t0 = time.perf_counter()
    run_raster()
    t_raster = time.perf_counter() - t0
    t_raster_fk = time_per_call(lambda: [forward(q) for q in raster], min_time=0.3, repeat=3)

    return [
        Result(
            "plant step (move, small knob motion)",
            t_step * 1e6,
            "us/call",
            baseline=t_fk * 1e6,
            baseline_name="kinematics.forward, one q",
            target="< 200 us",
            met=t_step < 200e-6,
        ),
        Result(
            "360-sample spin at 60 deg (move_along)",
            t_spin * 1e3,
            "ms",
            baseline=t_spin_fk * 1e3,
            baseline_name="360 x kinematics.forward",
            target="well under 1 s",
            met=t_spin < 0.25,
        ),
        Result(
            "19 x 19 raster, move + tracked tip (4 samples averaged)",
            t_raster * 1e3,
            "ms",
            baseline=t_raster_fk * 1e3,
            baseline_name="361 x kinematics.forward",
            target="",
        ),
    ]


if __name__ == "__main__":
    from benchmarks.common import print_results

    print_results(main())
