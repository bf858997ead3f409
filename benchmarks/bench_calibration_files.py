"""Calibration files of version 3: a full ``dense+hysteresis`` fit saved and loaded.

Fits the console's ``dense+hysteresis`` procedure on twin catheter 52 (a development seed;
the whole plan, about 2,300 states), writes its calibration file and loads it. Measured: the
time to load the file and get the controller's compensation, against the baseline of the
design it replaces -- rebuilding F on the effective knobs from the samples the file keeps
(``ElasticityMap.build``, what a loader without the stored tables would run), in the same run;
and the largest difference between the loaded knob map's commands and the fitted one's over
200 random model states driven in sequence (rad, mm). The file's size is reported.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import Result
from icenav.calibration.files import CalibrationFile
from icenav.compensation.elasticity import ElasticityMap
from icenav.eval.spin import make_rig, run_calibration
from icenav.geometry.kinematics import DEFAULT_GEOMETRY

SEED = 52
N_STATES = 200


def _largest_difference(fitted: Any, loaded: Any) -> float:
    rng = np.random.default_rng(0)
    lim = 0.95 * DEFAULT_GEOMETRY.knob_limit
    worst = 0.0
    for _ in range(N_STATES):
        q = np.array([*rng.uniform(-lim, lim, 2), rng.uniform(-3, 3), rng.uniform(-30, 30)])
        a = fitted.model_to_motor(q)
        b = loaded.model_to_motor(q)
        worst = max(worst, float(np.max(np.abs(a - b))))
        fitted.observe(a)
        loaded.observe(a)
        c = fitted.motor_to_model(a)
        d = loaded.motor_to_model(a)
        worst = max(worst, float(np.nanmax(np.abs(c - d))))
    return worst


def main() -> list[Result]:
    rig, tracker = make_rig(SEED, "straight")
    outcome = run_calibration("dense+hysteresis", rig, tracker)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "cal.json"
        t0 = time.perf_counter()
        CalibrationFile.from_outcome(outcome).save(path)
        save_s = time.perf_counter() - t0
        size_mb = path.stat().st_size / 1e6
        t0 = time.perf_counter()
        loaded = CalibrationFile.load(path).compensation()
        load_s = time.perf_counter() - t0
    effective = outcome.details.transmission.effective_map
    t0 = time.perf_counter()
    ElasticityMap.build(
        effective.calibration,
        interpolant=effective.report.interpolant,
        smoothing=effective.report.smoothing,
    )
    rebuild_s = time.perf_counter() - t0
    worst = _largest_difference(outcome.details.knob_map(), loaded)
    return [
        Result(
            "load a dense+hysteresis calibration file and its knob map",
            load_s,
            "s",
            baseline=rebuild_s,
            baseline_name="rebuilding F on the effective knobs from the file's samples",
        ),
        Result("write the file", save_s, "s"),
        Result("the file's size", size_mb, "MB"),
        Result(
            f"largest command difference, loaded vs fitted map ({N_STATES} states in sequence)",
            worst,
            "rad or mm",
            target="<= 1e-12 (rounding)",
            met=worst <= 1e-12,
        ),
    ]


if __name__ == "__main__":
    from benchmarks.common import print_results

    print_results(main())
