"""Tests of icenav.calibration.procedure / procedures: one generator per calibration kind."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.calibration.plans import calibrate_five_point, raster_grid
from icenav.calibration.procedure import Procedure, Visit, run_procedure
from icenav.calibration.procedures import CALIBRATION_KINDS, make_procedure
from icenav.errors import ConfigurationError, ShapeError
from icenav.sim import CatheterPlant, EMTracker


def _twin(seed: int = 7) -> tuple[CatheterPlant, EMTracker]:
    plant = CatheterPlant(seed=seed)
    tracker = EMTracker(plant, seed=seed)
    tracker.start()
    return plant, tracker


def test_every_kind_is_a_procedure_starting_and_ending_at_rest() -> None:
    for kind in CALIBRATION_KINDS:
        proc = make_procedure(kind)
        assert isinstance(proc, Procedure)
        assert proc.kind == kind and proc.label
        gen = proc.visits()
        first = next(gen)
        assert isinstance(first, Visit)
    dense = make_procedure("dense")
    visits = list(dense.plan.q_motor)  # type: ignore[union-attr]
    np.testing.assert_array_equal(visits[0], np.zeros(4))
    np.testing.assert_array_equal(visits[-1], np.zeros(4))
    np.testing.assert_allclose(np.array(visits[1:-1]), raster_grid())


def test_the_five_point_search_is_the_same_algorithm_as_the_synchronous_one() -> None:
    plant, tracker = _twin()
    proc = make_procedure("five_point")
    rec = run_procedure(proc, plant.move, lambda n: tracker.measure_tip2base(n))
    out = proc.fit(rec)
    plant2, tracker2 = _twin()
    old = calibrate_five_point(plant2.move, tracker2)
    np.testing.assert_allclose(out.calibration_set.q_motor, old.calibration.q_motor)
    np.testing.assert_array_equal(rec.plan.q_motor[-1], np.zeros(4))
    assert out.quality.n_missing == 0
    # the searched pairs are not the model's targets (the catheter is not the model)
    assert np.max(np.abs(np.degrees(out.calibration_set.q_motor[1:, :2]))) < 90.01
    assert np.any(np.abs(np.degrees(out.calibration_set.q_motor[1:, :2]) % 90) > 1.0)


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
    with pytest.raises(Exception, match="calibration samples were measured"):
        proc.fit(rec2)


def test_bad_input_is_refused() -> None:
    with pytest.raises(ConfigurationError, match="unknown calibration kind 'grid'"):
        make_procedure("grid")
    with pytest.raises(ShapeError, match=r"shape \(4,\)"):
        Visit(np.zeros(3), 1, 0, "x")
    with pytest.raises(ConfigurationError, match=">= 0"):
        Visit(np.zeros(4), -1, 0, "x")
    plant, _ = _twin()
    with pytest.raises(ShapeError, match="finite"):
        run_procedure(make_procedure("dense"), plant.move, lambda n: np.eye(3))
