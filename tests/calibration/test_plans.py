"""Tests of icenav.calibration.plans: motion plans, their recordings through the runner, and
the calibration sets made from them (against a small synthetic catheter and tracker)."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from icenav.calibration.plans import MotionPlan, calibration_set_from, raster_grid
from icenav.calibration.procedure import Visit, run_procedure, run_visits
from icenav.calibration.procedures import make_procedure, plan_visits
from icenav.compensation.elasticity import ElasticityMap
from icenav.errors import ConfigurationError, InvalidValueError, TrackerError
from tests.support.calibration import SyntheticCatheter, Tracker, distortion

DEG = math.pi / 180


def test_raster_is_the_papers_grid_in_serpentine_order() -> None:
    q = raster_grid()
    assert q.shape == (361, 4)
    got = {(round(a), round(b)) for a, b in np.degrees(q[:, :2])}
    assert got == {(a, b) for a in range(-90, 91, 10) for b in range(-90, 91, 10)}
    steps = np.abs(np.diff(q[:, :2], axis=0))
    assert np.all(np.max(steps, axis=1) <= 10 * DEG + 1e-12)  # neighbours only
    assert np.all(q[:, 2:] == 0.0)
    with pytest.raises(ConfigurationError, match="multiple of step"):
        raster_grid(7 * DEG)


def test_dense_calibration_builds_a_map_that_compensates() -> None:
    cath = SyntheticCatheter()
    proc = make_procedure("dense")
    seen: list[int] = []
    rec = run_procedure(proc, cath.move, Tracker(cath), progress=lambda i, v: seen.append(i))
    out = proc.fit(rec)
    assert out.calibration_set.n_samples == 361 and out.quality.n_missing == 0
    assert seen == list(range(1, 364))  # rest, 361 raster states, rest
    # exact data: no smoothing needed (the default smoothing is for a noisy tracker)
    fmap = ElasticityMap.build(out.calibration_set, smoothing=0.0)
    rng = np.random.default_rng(0)
    k = rng.uniform(-60, 60, (300, 2)) * DEG
    a, b = fmap.model_to_motor_knobs(k[:, 0], k[:, 1])
    err = np.abs(distortion(np.stack([a, b], -1)) - k)
    assert np.max(err) < 0.1 * DEG
    assert np.max(np.abs(distortion(k) - k)) > 5 * DEG  # without the map


def test_missing_samples_are_retried_then_skipped(caplog: pytest.LogCaptureFixture) -> None:
    cath = SyntheticCatheter()
    # sample 0: one miss then valid (retried); sample 2: four misses (skipped, retries=3)
    tracker = Tracker(cath, misses={1, 4, 5, 6, 7})
    q = np.zeros((5, 4))
    q[:, 0] = np.linspace(0, 0.8, 5)
    plan = MotionPlan.make(q, "points", n_average=1, retries=3)
    rec = run_visits(plan_visits(plan), cath.move, tracker)
    with caplog.at_level(logging.WARNING, logger="icenav.calibration.plans"):
        run = calibration_set_from(rec)
    assert run.calibration.n_samples == 4
    assert len(run.skipped) == 1
    assert np.allclose(run.skipped[0].q_motor, q[2])
    assert "skipped" in caplog.text
    never = Tracker(cath, misses=set(range(1, 1000)))
    with pytest.raises(TrackerError, match="only 0 of 5"):
        calibration_set_from(run_visits(plan_visits(plan), cath.move, never))


def test_a_plan_visits_its_states_and_reads_where_it_says() -> None:
    cath = SyntheticCatheter()
    tracker = Tracker(cath)
    a = MotionPlan.make(raster_grid(45 * DEG), "raster", n_average=2)
    b = MotionPlan.make(np.zeros((2, 4)), "rest", n_average=0, retries=0)
    plan = MotionPlan.concat([a, b])
    assert plan.n == 27 and plan.segments == ((0, 25, "raster"), (25, 27, "rest"))
    assert plan.phase_at(26) == "rest" and plan.segment("raster") == slice(0, 25)
    reports: list[Visit] = []
    rec = run_visits(plan_visits(plan), cath.move, tracker, progress=lambda i, v: reports.append(v))
    assert cath.moves == 27 and len(reports) == 27 and tracker.calls == 25
    assert reports[-1].phase == "rest" and reports[0].n_average == 2
    assert rec.measured.tolist() == [True] * 25 + [False] * 2
    q, poses = rec.part("raster")
    np.testing.assert_array_equal(q, raster_grid(45 * DEG))
    with pytest.raises(InvalidValueError, match="no segment 'sweep'"):
        rec.part("sweep")
    for bad, match in (
        (dict(n_average=np.array([1, -1])), "n_average must be 2 integers >= 0"),
        (dict(retries=np.array([0.5, 1.0])), "retries must be 2 integers"),
        (dict(segments=((0, 1, "a"),)), "cover 1 of 2"),
        (dict(segments=((1, 2, "a"),)), "consecutive"),
    ):
        kwargs = dict(
            q_motor=np.zeros((2, 4)),
            n_average=np.array([1, 1]),
            retries=np.array([0, 0]),
            segments=((0, 2, "a"),),
        )
        kwargs.update(bad)
        with pytest.raises(ConfigurationError, match=match):
            MotionPlan(**kwargs)  # type: ignore[arg-type]
