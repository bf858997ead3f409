"""Tests of icenav.calibration.plans against a small synthetic catheter and tracker."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from numpy.typing import ArrayLike

from icenav.calibration.plans import (
    Progress,
    as_mover,
    calibrate_dense,
    calibrate_five_point,
    calibrate_points,
    five_point_targets,
    identify_hysteresis,
    raster_grid,
)
from icenav.compensation.elasticity import ElasticityMap
from icenav.devices.robot import JointState, RobotStatus
from icenav.errors import ConfigurationError, InvalidValueError, JointLimitError, TrackerError
from icenav.geometry.kinematics import forward

DEG = math.pi / 180


def distortion(k: np.ndarray) -> np.ndarray:
    c, s = math.cos(6 * DEG), math.sin(6 * DEG)
    r2 = np.sum(k * k, axis=-1, keepdims=True) / (math.pi / 2) ** 2
    return (k @ np.array([[c, -s], [s, c]]).T) * (1.1 - 0.1 * r2)


class SyntheticCatheter:
    """Motor knobs -> per-joint backlash (half-width r) + dead-zone d -> distortion -> FK."""

    def __init__(
        self, r: tuple[float, float, float] = (0, 0, 0), d: float = 0.0, roll_per_bend: float = 0.0
    ) -> None:
        self.r = r
        self.d = d
        self.roll_per_bend = roll_per_bend
        self.p = [0.0, 0.0, 0.0]
        self.moves = 0

    def move(self, q: ArrayLike) -> None:
        q = np.asarray(q, dtype=np.float64)
        for j in range(3):
            w = self.r[j] + (self.roll_per_bend * math.hypot(self.p[0], self.p[1]) if j == 2 else 0)
            self.p[j] = min(max(self.p[j], q[j] - w), q[j] + w)
        self.q = q
        self.moves += 1

    def pose(self) -> np.ndarray:
        eff = np.array(
            [np.sign(v) * max(abs(v) - self.d, 0.0) for v in self.p[:2]], dtype=np.float64
        )
        k = distortion(eff[None, :])[0]
        return forward(np.array([k[0], k[1], self.p[2], 0.0]), check=False)


class Tracker:
    """Reads the synthetic catheter; returns None for the attempts listed in ``misses``."""

    def __init__(self, cath: SyntheticCatheter, misses: set[int] | None = None) -> None:
        self.cath = cath
        self.misses = misses or set()
        self.calls = 0

    def measure_tip2base(self) -> np.ndarray | None:
        self.calls += 1
        if self.calls in self.misses:
            return None
        return self.cath.pose()


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
    seen: list[Progress] = []
    run = calibrate_dense(cath.move, Tracker(cath), progress=seen.append, catheter_id="syn-1")
    assert run.calibration.n_samples == 361 and not run.skipped
    assert run.calibration.method == "dense-raster"
    assert [p.done for p in seen] == list(range(1, 362)) and seen[-1].total == 361
    # exact data: no smoothing needed (the default smoothing is for a noisy tracker)
    fmap = ElasticityMap.build(run.calibration, smoothing=0.0)
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
    with caplog.at_level(logging.WARNING, logger="icenav.calibration.plans"):
        run = calibrate_points(cath.move, tracker, q, retries=3)
    assert run.calibration.n_samples == 4
    assert len(run.skipped) == 1
    assert np.allclose(run.skipped[0].q_motor, q[2])
    assert run.skipped[0].attempts == 4
    assert "skipped" in caplog.text
    never = Tracker(cath, misses=set(range(1, 1000)))
    with pytest.raises(TrackerError, match="only 0 of 5"):
        calibrate_points(cath.move, never, q)


def test_five_point_calibration_finds_the_motor_knobs() -> None:
    cath = SyntheticCatheter()
    run = calibrate_five_point(cath.move, Tracker(cath), tol_mm=0.5)
    assert run.calibration.n_samples == 5
    _, xy = five_point_targets()
    reached = run.calibration.tip2base[:, :2, 3]
    assert np.max(np.linalg.norm(reached - xy, axis=-1)) < 0.5
    # the distortion turns the bend by 6 deg: the motor knobs are not the model's
    k = run.calibration.q_motor[1, :2]
    assert abs(k[1]) > 2 * DEG
    # and a map from the five points reduces the error
    fmap = ElasticityMap.build(run.calibration)
    rng = np.random.default_rng(1)
    m = rng.uniform(-50, 50, (300, 2)) * DEG
    a, b = fmap.model_to_motor_knobs(m[:, 0], m[:, 1])
    with_map = np.abs(distortion(np.stack([a, b], -1)) - m)
    without = np.abs(distortion(m) - m)
    assert np.sqrt(np.mean(with_map**2)) < 0.7 * np.sqrt(np.mean(without**2))


def test_hysteresis_identification_on_the_synthetic_catheter() -> None:
    cath = SyntheticCatheter(r=(3 * DEG, 2 * DEG, 1.5 * DEG), d=2 * DEG, roll_per_bend=0.06)
    ident = identify_hysteresis(cath.move, Tracker(cath))
    # the roll's play grows with the bend (per rad of the tracked bend), the knobs' does not
    assert ident.compensator.roll_play_per_bend == pytest.approx(0.06, abs=0.015)
    assert ident.compensator.knob_play_per_bend < 0.01
    assert ident.compensator.twist_play_per_bend < 0.015  # no distal twist here
    m1, m2, m3, m4 = ident.compensator.joints
    assert m1 is not None and m2 is not None and m3 is not None and m4 is None
    assert m1.backlash == pytest.approx(3 * DEG, abs=0.3 * DEG)
    assert m2.backlash == pytest.approx(2 * DEG, abs=0.3 * DEG)
    assert m1.dead_zone == pytest.approx(2 * DEG, abs=0.3 * DEG)
    assert m3.backlash == pytest.approx(1.5 * DEG, abs=0.3 * DEG)
    assert m3.dead_zone == 0.0


class FakeBackend:
    """A RobotBackend that records commands and moves the synthetic catheter."""

    def __init__(self, cath: SyntheticCatheter) -> None:
        self.cath = cath
        self.commands: list[np.ndarray] = []

    @property
    def status(self) -> RobotStatus:
        return RobotStatus.ENABLED

    def enable(self) -> None: ...
    def disable(self) -> None: ...
    def home(self) -> None: ...

    def read_state(self) -> JointState:
        return JointState(q=self.commands[-1], timestamp=0.0, status=RobotStatus.ENABLED)

    def command_position(self, q_motor: ArrayLike) -> None:
        self.commands.append(np.asarray(q_motor, dtype=np.float64))

    def stop(self) -> None: ...
    def estop(self) -> None: ...
    def reset_fault(self) -> None: ...
    def close(self) -> None: ...


def test_procedures_drive_a_robot_backend() -> None:
    cath = SyntheticCatheter()
    backend = FakeBackend(cath)
    with pytest.raises(ConfigurationError, match="settle"):
        as_mover(backend)
    settled: list[int] = []

    def settle() -> None:
        cath.move(backend.commands[-1])
        settled.append(1)

    q = raster_grid(45 * DEG)
    run = calibrate_points(backend, Tracker(cath), q, settle=settle)
    assert len(backend.commands) == len(settled) == q.shape[0] == run.calibration.n_samples
    with pytest.raises(ConfigurationError, match="RobotBackend or a callable"):
        as_mover(42)  # type: ignore[arg-type]


def test_a_plan_visits_its_states_and_reads_where_it_says() -> None:
    from icenav.calibration.plans import MotionPlan, execute_plan

    cath = SyntheticCatheter()
    tracker = Tracker(cath)
    a = MotionPlan.make(raster_grid(45 * DEG), "raster", n_average=2)
    b = MotionPlan.make(np.zeros((2, 4)), "rest", n_average=0, retries=0)
    plan = MotionPlan.concat([a, b])
    assert plan.n == 27 and plan.segments == ((0, 25, "raster"), (25, 27, "rest"))
    assert plan.phase_at(26) == "rest" and plan.segment("raster") == slice(0, 25)
    reports: list[Progress] = []
    rec = execute_plan(cath.move, tracker, plan, progress=reports.append)
    assert cath.moves == 27 and [r.done for r in reports] == list(range(1, 28))
    assert reports[-1].phase == "rest"
    assert rec.measured.tolist() == [True] * 25 + [False] * 2
    assert rec.attempts.tolist() == [2] * 25 + [0, 0]
    q, poses = rec.part("raster")
    fresh = SyntheticCatheter()  # the same as the raster procedure reads it
    run = calibrate_points(fresh.move, Tracker(fresh), q, n_average=2)
    np.testing.assert_array_equal(run.calibration.tip2base, poses)
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
    with pytest.raises(JointLimitError, match="phi1 = 3 rad .* is outside"):
        execute_plan(cath.move, tracker, MotionPlan.make([[3.0, 0, 0, 0]], "far"))


def test_hysteresis_plan_fitted_equals_the_procedure() -> None:
    """identify_hysteresis is its plan executed and fitted: the same moves, the same fit."""
    from icenav.calibration.plans import execute_plan, fit_hysteresis, hysteresis_plan

    a = SyntheticCatheter(r=(3 * DEG, 2 * DEG, 1.5 * DEG), d=2 * DEG, roll_per_bend=0.06)
    b = SyntheticCatheter(r=(3 * DEG, 2 * DEG, 1.5 * DEG), d=2 * DEG, roll_per_bend=0.06)
    direct = identify_hysteresis(a.move, Tracker(a))
    hplan = hysteresis_plan()
    planned = fit_hysteresis(hplan, execute_plan(b.move, Tracker(b), hplan.plan))
    assert a.moves == b.moves == hplan.plan.n == direct.n_moves
    for ma, mb in zip(direct.compensator.joints, planned.compensator.joints, strict=True):
        assert ma == mb
    assert direct.compensator.roll_play_per_bend == planned.compensator.roll_play_per_bend
