"""Shared helpers of the calibration-file tests: a reduced ``dense+hysteresis`` fit on the
twin (every part of :class:`icenav.calibration.catheter.CatheterCalibration` identified from
the twin's tracked poses, on a coarse raster and coarse sweeps so that it takes seconds, not
the full procedure's minutes)."""

from __future__ import annotations

import math

import numpy as np

from icenav.calibration.catheter import CatheterCalibration
from icenav.calibration.hysteresis import fit_hysteresis, hysteresis_plan
from icenav.calibration.plans import MotionPlan, calibration_set_from, raster_grid
from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.tracker_bias import fit_tracker_bias_from, roll_circle_plan
from icenav.calibration.transmission import build_transmission
from icenav.compensation.elasticity import ElasticityMap
from icenav.sim import CatheterPlant, EMTracker


def small_catheter_calibration(seed: int = 52) -> CatheterCalibration:
    """A CatheterCalibration of twin catheter ``seed`` (a development seed) from an 8 x 8 (+-70 deg)
    raster, 10-degree sweeps and the roll circles; the per-tendon identification limited to
    a few evaluations (the file keeps whatever was identified)."""
    plant = CatheterPlant(seed=seed, vessel="straight")
    t = [0.0]
    tracker = EMTracker(plant, seed=seed, clock=lambda: t[0])
    tracker.start()

    def move(q: np.ndarray) -> None:
        plant.move(q)
        t[0] += 0.5

    def record(plan: MotionPlan):  # type: ignore[no-untyped-def]
        plant.move(np.zeros(4))
        return run_visits(plan_visits(plan), move, tracker)

    raster = raster_grid(math.radians(20.0), math.radians(70.0))
    dense_rec = record(MotionPlan.make(raster, "dense raster", n_average=2, retries=10))
    dense = calibration_set_from(dense_rec, "dense raster").calibration
    hplan = hysteresis_plan(step=math.radians(10.0))
    hyst = fit_hysteresis(hplan, record(hplan.plan))
    bias = fit_tracker_bias_from(record(roll_circle_plan()))
    transmission = build_transmission(
        bias.correct_calibration(dense), raster, None, hyst.compensator, max_nfev=8
    )
    return CatheterCalibration(
        dense=dense,
        elasticity_map=ElasticityMap.build(dense),
        hysteresis=hyst,
        tracker_bias=bias,
        transmission=transmission,
    )
