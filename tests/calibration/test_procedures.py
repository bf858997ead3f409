"""Tests of icenav.calibration.procedure / procedures: one generator per calibration kind, the
runner, the fits and their quality, on the twin and on a synthetic catheter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.calibration.plans import five_point_targets, raster_grid
from icenav.calibration.procedure import FitQuality, Procedure, Visit, run_procedure
from icenav.calibration.procedures import CALIBRATION_KINDS, make_procedure
from icenav.compensation.elasticity import ElasticityMap
from icenav.devices.registration import Registration
from icenav.errors import ConfigurationError, ShapeError, TrackerError
from icenav.geometry.se3 import rigid_inverse, rotation_angle, rotvec_to_matrix
from icenav.sim import CatheterPlant, EMTracker, TrackerConfig
from icenav.sim.tracker import DEFAULT_SENSOR2TIP
from tests.support.calibration import SyntheticCatheter, Tracker, distortion

DEG = math.pi / 180


def _twin(seed: int = 7, config: TrackerConfig | None = None) -> tuple[CatheterPlant, EMTracker]:
    plant = CatheterPlant(seed=seed)
    tracker = EMTracker(plant, seed=seed, config=config)
    tracker.start()
    return plant, tracker


def test_every_kind_is_a_procedure_starting_and_ending_at_rest() -> None:
    for kind in CALIBRATION_KINDS:
        proc = make_procedure(kind, sensor2tip=DEFAULT_SENSOR2TIP)
        assert isinstance(proc, Procedure)
        assert proc.kind == kind and proc.label
        first = next(proc.visits())
        assert isinstance(first, Visit)
    dense = make_procedure("dense")
    visits = list(dense.plan.q_motor)  # type: ignore[union-attr]
    np.testing.assert_array_equal(visits[0], np.zeros(4))
    np.testing.assert_array_equal(visits[-1], np.zeros(4))
    np.testing.assert_allclose(np.array(visits[1:-1]), raster_grid())


def test_the_five_point_search_finds_the_motor_knobs_of_a_synthetic_catheter() -> None:
    cath = SyntheticCatheter()
    proc = make_procedure("five_point")
    rec = run_procedure(proc, cath.move, Tracker(cath))
    out = proc.fit(rec)
    cal = out.calibration_set
    assert cal.n_samples == 5 and out.quality.n_missing == 0
    np.testing.assert_array_equal(rec.plan.q_motor[-1], np.zeros(4))  # back at rest
    _, xy = five_point_targets()
    assert np.max(np.linalg.norm(cal.tip2base[:, :2, 3] - xy, axis=-1)) < 1.0  # tol_mm
    # the distortion turns the bend by 6 deg: the motor knobs are not the model's
    assert abs(cal.q_motor[1, 1]) > 2 * DEG
    # and a map from the five points reduces the error
    fmap = ElasticityMap.build(cal)
    m = np.random.default_rng(1).uniform(-50, 50, (300, 2)) * DEG
    a, b = fmap.model_to_motor_knobs(m[:, 0], m[:, 1])
    with_map = np.abs(distortion(np.stack([a, b], -1)) - m)
    without = np.abs(distortion(m) - m)
    assert np.sqrt(np.mean(with_map**2)) < 0.7 * np.sqrt(np.mean(without**2))


def test_the_five_point_search_on_the_twin() -> None:
    plant, tracker = _twin()
    proc = make_procedure("five_point")
    out = proc.fit(run_procedure(proc, plant.move, tracker))
    q = np.degrees(out.calibration_set.q_motor[1:, :2])
    # the searched pairs are within the limits and not the model's targets
    assert np.max(np.abs(q)) < 90.01
    assert np.any(np.abs(q % 90) > 1.0)
    text = out.quality.describe()
    assert "samples used" in text and " mm RMS" in text and " deg RMS" in text


def test_missing_readings_are_retried_then_recorded_as_not_measured() -> None:
    plant, tracker = _twin()
    proc = make_procedure("dense")
    calls = {"n": 0}

    def flaky(n: int) -> np.ndarray | None:
        calls["n"] += 1
        if calls["n"] % 3 == 0:
            return None  # a dropout: retried
        return tracker.measure_tip2base(n)

    rec = run_procedure(proc, plant.move, flaky)
    assert rec.measured.sum() == 361
    rec2 = run_procedure(proc, plant.move, lambda n: None)
    assert rec2.measured.sum() == 0
    with pytest.raises(TrackerError, match="calibration samples were measured"):
        proc.fit(rec2)


def test_the_registration_procedure_recovers_the_trackers_pose_on_the_twin() -> None:
    """Run as a lab would: the tracker's registration unknown (None), the procedure reads the
    sensor in the tracker frame, its fit is set on the tracker, and the tip poses it then
    reports agree with the plant's true tip within the tracker's accuracy."""
    truth = np.eye(4)
    truth[:3, :3] = rotvec_to_matrix(np.array([1.2, -0.4, 0.3]))
    truth[:3, 3] = -truth[:3, :3] @ np.array([10.0, -20.0, 300.0]) + [0.0, 0.0, 60.0]
    plant, tracker = _twin(11, TrackerConfig(tracker2base=truth))
    tracker.registration = None
    assert tracker.measure_tip2base() is None  # unregistered: no tip2base
    proc = make_procedure("registration", sensor2tip=DEFAULT_SENSOR2TIP)
    out = proc.fit(run_procedure(proc, plant.move, tracker))
    reg = out.details
    assert isinstance(reg, Registration) and out.kind == "registration"
    assert out.knob_map is None and out.calibration_set is None
    err = rigid_inverse(truth) @ reg.tracker2base
    assert np.linalg.norm(err[:3, 3]) < 3.0  # mm (the field bias shifts all points alike)
    assert math.degrees(float(rotation_angle(err[:3, :3], np.eye(3)))) < 1.0
    assert out.quality.rms_mm < 1.5 and math.isnan(out.quality.rms_deg)
    assert "residual" in out.quality.describe()
    tracker.registration = reg
    plant.move(np.array([0.6, -0.3, 0.4, 5.0]))
    tip = tracker.measure_tip2base(8)
    assert tip is not None
    assert np.linalg.norm(tip[:3, 3] - plant.state.tip2base[:3, 3]) < 4.0
    # the registration's visits read the tracker frame: a plain measure callable cannot
    with pytest.raises(ConfigurationError, match="measure_sensor2tracker"):
        run_procedure(proc, plant.move, lambda n: np.eye(4))


def test_fit_quality_says_what_was_left_out_and_why() -> None:
    q = FitQuality(n_used=10, n_missing=2, rms_mm=1.234, max_mm=2.5, rms_deg=0.5,
                   n_left_out=3, left_out="at the knob limit", max_deg=1.0)  # fmt: skip
    text = q.describe()
    assert "10 samples used" in text and "2 not tracked" in text
    assert "3 left out (at the knob limit)" in text
    assert "1.23 mm RMS (max 2.50 mm)" in text and "0.50 deg RMS (max 1.00 deg)" in text


def test_bad_input_is_refused() -> None:
    with pytest.raises(ConfigurationError, match="unknown calibration kind 'grid'"):
        make_procedure("grid")
    with pytest.raises(ConfigurationError, match="needs sensor2tip"):
        make_procedure("registration")
    with pytest.raises(ShapeError, match=r"shape \(4,\)"):
        Visit(np.zeros(3), 1, 0, "x")
    with pytest.raises(ConfigurationError, match=">= 0"):
        Visit(np.zeros(4), -1, 0, "x")
    with pytest.raises(ConfigurationError, match="frame must be one of"):
        Visit(np.zeros(4), 1, 0, "x", "world")
    plant, _ = _twin()
    with pytest.raises(ShapeError, match="finite"):
        run_procedure(make_procedure("dense"), plant.move, lambda n: np.eye(3))
