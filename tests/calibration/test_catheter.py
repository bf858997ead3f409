"""Tests of icenav.calibration.catheter: the combined plan and its fit's guards (the whole
procedure on the twin, in the controller's loop, is tests/test_controller.py's
test_dense_hysteresis_calibration_in_the_loop_installs_the_tendon_map)."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.calibration.catheter import (
    DENSE_RASTER,
    KNOB_CIRCLE_STEP,
    catheter_plan,
    fit_catheter,
)
from icenav.calibration.hysteresis import hysteresis_plan
from icenav.calibration.plans import Recording
from icenav.calibration.tracker_bias import ROLL_CIRCLES, roll_circle_plan
from icenav.calibration.transmission import KNOB_CIRCLES, circle_plan
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY


def test_the_plan_strings_the_procedures_together_from_rest_to_rest() -> None:
    cp = catheter_plan()
    plan = cp.plan
    names = [name for _, _, name in plan.segments]
    assert names[0] == DENSE_RASTER and ROLL_CIRCLES in names and KNOB_CIRCLES in names
    raster = plan.segment(DENSE_RASTER)
    assert raster.stop - raster.start == 361 and np.all(plan.n_average[raster] == 4)
    np.testing.assert_array_equal(plan.q_motor[raster], cp.raster)
    # the sweeps' own plan sits whole inside, right after the raster
    h = cp.hysteresis.plan
    sl = slice(cp.hysteresis_start, cp.hysteresis_start + h.n)
    np.testing.assert_array_equal(plan.q_motor[sl], h.q_motor)
    np.testing.assert_array_equal(plan.n_average[sl], h.n_average)
    assert plan.n == 361 + h.n + roll_circle_plan().n + circle_plan(step=KNOB_CIRCLE_STEP).n
    # only the roll is swept: the knobs' plays are the per-tendon model's (raster, circles)
    assert cp.hysteresis.joints == (2,)
    assert all("phi1" not in name.split(",")[0] for name in names if name.startswith("sweep"))
    np.testing.assert_array_equal(plan.q_motor[-1], np.zeros(4))  # ends at rest
    lim = DEFAULT_GEOMETRY.joint_limits
    assert np.all(plan.q_motor >= lim[:, 0]) and np.all(plan.q_motor <= lim[:, 1])
    # knob circles: one sample, no retry (a gap is a gap); the raster retries MISSING
    circles = plan.segment(KNOB_CIRCLES)
    assert np.all(plan.retries[circles] == 0) and np.all(plan.retries[raster] == 10)


def test_fit_refuses_a_recording_of_another_plan() -> None:
    cp = catheter_plan()
    other = hysteresis_plan().plan
    rec = Recording(
        plan=other, tip2base=np.full((other.n, 4, 4), np.nan), attempts=np.zeros(other.n)
    )
    with pytest.raises(ConfigurationError, match="not of this catheter plan"):
        fit_catheter(cp, rec)
