"""Path execution: limits, staying near the path, exact arrival, pause / abort / stop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.devices.sim_robot import IdealPlant, SimulatedRobot
from icenav.errors import ConfigurationError, DriveFaultError, MotionAborted, PlanningError
from icenav.recovery.motion import ExecutionStatus, MotionLimits, PathExecutor, execute_path
from icenav.recovery.roadmap import Roadmap, RoadmapMetric

DEG = math.pi / 180
DT = 0.01


def planned_path(seed: int) -> tuple[np.ndarray, Roadmap]:
    """A return path planned on a roadmap built from a random smooth trace."""
    rng = np.random.default_rng(seed)
    rm = Roadmap(1.0)
    q = np.array([0.0, 0.0, 0.0, 0.0])
    vel = np.zeros(4)
    for _ in range(1500):
        vel = 0.9 * vel + 0.1 * rng.normal(0, 1, 4) * np.array([0.6 * DEG] * 3 + [0.6])
        q = np.clip(q + vel, [-1.5, -1.5, -6, -50], [1.5, 1.5, 6, 50])
        rm.add(q)
    target = int(rng.integers(0, rm.n_vertices // 3))
    return rm.plan(rm.current_state, target), rm


def robot_at(q: np.ndarray) -> SimulatedRobot:
    robot = SimulatedRobot(IdealPlant())
    robot.enable()
    robot.command_position(q)
    robot.commands.clear()
    return robot


def distance_to_polyline(x: np.ndarray, poly: np.ndarray) -> np.ndarray:
    a, b = poly[:-1], poly[1:]
    ab = b - a
    den = np.maximum((ab * ab).sum(1), 1e-300)
    out = np.empty(len(x))
    for i, p in enumerate(x):
        t = np.clip(((p - a) * ab).sum(1) / den, 0, 1)
        out[i] = np.linalg.norm(a + t[:, None] * ab - p, axis=1).min()
    return out


def check_limits(cmds: np.ndarray, limits: MotionLimits) -> None:
    v = np.diff(cmds, axis=0) / DT
    a = np.diff(v, axis=0) / DT
    assert np.all(np.abs(v) <= np.array(limits.max_velocity) * (1 + 1e-6))
    assert np.all(np.abs(a) <= np.array(limits.max_acceleration) * (1 + 1e-6))


@pytest.mark.parametrize("seed", range(4))
def test_follows_path_within_limits_and_lands_exactly(seed: int) -> None:
    path, rm = planned_path(seed)
    robot = robot_at(path[0])
    limits = MotionLimits()
    fractions: list[float] = []
    ex = PathExecutor(robot, path, limits=limits, dt=DT, progress=fractions.append)
    assert ex.run() is ExecutionStatus.DONE
    cmds = np.vstack([path[:1], np.array(robot.commands)])
    np.testing.assert_array_equal(cmds[-1], path[-1])  # exactly the goal state
    check_limits(cmds, limits)
    scale = RoadmapMetric().scale
    steps = np.linalg.norm(np.diff(cmds * scale, axis=0), axis=1)
    assert steps.max() <= rm.epsilon  # densified: no step beyond epsilon
    dist = distance_to_polyline(cmds * scale, path * scale)
    assert dist.max() <= rm.epsilon / 2  # stays in the tube around the planned path
    assert np.all(np.diff(fractions) >= 0) and fractions[-1] == 1.0
    assert fractions[len(fractions) // 2] < 1.0


def test_abort_by_operator_input_stops_smoothly() -> None:
    path, _ = planned_path(11)
    robot = robot_at(path[0])
    cycles = {"n": 0}

    def operator_touched() -> bool:
        cycles["n"] += 1
        return cycles["n"] > 150

    ex = PathExecutor(robot, path, dt=DT, abort=operator_touched)
    assert ex.run() is ExecutionStatus.ABORTED
    n_cmds = len(robot.commands)
    assert ex.step() is ExecutionStatus.ABORTED and len(robot.commands) == n_cmds
    cmds = np.vstack([path[:1], np.array(robot.commands)])
    check_limits(cmds, ex.limits)
    assert np.abs(cmds[-1] - cmds[-2]).max() / DT < 1e-4  # came to rest
    assert not np.allclose(cmds[-1], path[-1])
    assert 0.0 < ex.fraction_done < 1.0
    robot2 = robot_at(path[0])
    with pytest.raises(MotionAborted, match="aborted at"):
        execute_path(robot2, path, dt=DT, abort=lambda: True)


def test_stop_at_once_and_pause_resume() -> None:
    path, _ = planned_path(12)
    robot = robot_at(path[0])
    ex = PathExecutor(robot, path, dt=DT)
    for _ in range(100):
        ex.step()
    ex.stop()
    n = len(robot.commands)
    assert ex.run() is ExecutionStatus.STOPPED and len(robot.commands) == n

    robot = robot_at(path[0])
    ex = PathExecutor(robot, path, dt=DT)
    for _ in range(100):
        ex.step()
    ex.pause()
    for _ in range(300):
        ex.step()
    assert ex.status is ExecutionStatus.PAUSED
    held = len(robot.commands)
    for _ in range(50):
        assert ex.step() is ExecutionStatus.PAUSED
    assert len(robot.commands) == held  # nothing commanded while paused
    ex.resume()
    assert ex.run() is ExecutionStatus.DONE
    cmds = np.vstack([path[:1], np.array(robot.commands)])
    check_limits(cmds, ex.limits)
    np.testing.assert_array_equal(cmds[-1], path[-1])
    # operator input while paused aborts too
    robot = robot_at(path[0])
    touched = {"now": False}
    ex = PathExecutor(robot, path, dt=DT, abort=lambda: touched["now"])
    for _ in range(50):
        ex.step()
    ex.pause()
    for _ in range(300):
        ex.step()
    assert ex.status is ExecutionStatus.PAUSED
    touched["now"] = True
    assert ex.run() is ExecutionStatus.ABORTED


def test_fault_during_motion_is_raised() -> None:
    path, _ = planned_path(13)
    robot = robot_at(path[0])
    ex = PathExecutor(robot, path, dt=DT)
    for _ in range(20):
        ex.step()
    robot.inject_fault("phi1 drive overcurrent")
    with pytest.raises(DriveFaultError, match="overcurrent"):
        ex.step()
    assert ex.status is ExecutionStatus.FAULTED


def test_bad_setup_is_refused() -> None:
    path, _ = planned_path(14)
    with pytest.raises(PlanningError, match="from the start of the path"):
        PathExecutor(robot_at(path[0] + np.array([0, 0, 0, 5.0])), path)
    with pytest.raises(ConfigurationError, match="more than epsilon"):
        PathExecutor(robot_at(path[0]), path, dt=1.0)
    with pytest.raises(ConfigurationError, match="max_velocity"):
        MotionLimits(max_velocity=(1.0, 1.0, 1.0, -1.0))
    with pytest.raises(ConfigurationError, match="lookahead"):
        PathExecutor(robot_at(path[0]), path, lookahead=0.9)
