"""Scripted operator traces, and view recovery end to end on SimulatedRobot(IdealPlant)."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.control.controller import ControllerConfig, PathTask
from icenav.devices.sim_robot import IdealPlant, SimulatedRobot
from icenav.errors import ConfigurationError
from icenav.recovery.roadmap import Roadmap, direction_tracker
from icenav.sim.operator import OperatorConfig, ScriptedOperator, drive, minimum_jerk


def test_minimum_jerk_profile() -> None:
    q0, q1 = np.zeros(4), np.array([0.5, -0.2, 0.1, 10.0])
    tr = minimum_jerk(q0, q1, 2.0, 100.0)
    assert tr.shape == (200, 4)
    np.testing.assert_array_equal(tr[-1], q1)
    v = np.diff(np.vstack([q0, tr]), axis=0) * 100.0
    np.testing.assert_allclose(v.max(axis=0)[[0, 3]], 1.875 * q1[[0, 3]] / 2.0, rtol=1e-3)
    assert np.all(np.abs(v[[0, -1]]) < 1e-3 * np.abs(q1).max())  # starts and ends at rest
    assert np.all(np.diff(tr[:, 3]) > 0)  # monotone


def test_operator_respects_speed_box_and_seed() -> None:
    cfg = OperatorConfig()
    a = ScriptedOperator(config=cfg, seed=4)
    trace = np.vstack([a.explore(30), a.dwell(1.0, tremor=1e-4), a.move_to([3, 3, 9, 99])])
    v = np.abs(np.diff(trace[:-100], axis=0)) * cfg.rate_hz
    assert np.all(v <= np.array(cfg.max_velocity) * (1 + 1e-9))
    assert np.all(trace >= np.array(cfg.box_low) - 1e-3)
    assert np.all(trace <= np.array(cfg.box_high) + 1e-3)
    np.testing.assert_array_equal(trace[-1], cfg.box_high)
    c = ScriptedOperator(config=cfg, seed=4)
    np.testing.assert_array_equal(c.explore(30), ScriptedOperator(config=cfg, seed=4).explore(30))
    with pytest.raises(ConfigurationError, match="exceed max_velocity"):
        a.move_to([0, 0, 0, 0], duration_s=0.01)
    with pytest.raises(ConfigurationError, match="box_low"):
        OperatorConfig(box_low=(1, 1, 1, 1), box_high=(0, 0, 0, 0))


def follow(robot: SimulatedRobot, path: np.ndarray, dt: float = 0.01) -> None:
    """Follow a roadmap path as the controller does (its PathTask) until it ends."""
    task = PathTask(path, np.asarray(ControllerConfig().max_velocity))
    for _ in range(1_000_000):
        q = task.next_command(robot.read_state().q, dt)
        if q is None:
            return
        robot.command_position(q)
    raise AssertionError("the path task did not end")


def test_record_save_wander_return_end_to_end() -> None:
    robot = SimulatedRobot(IdealPlant())
    robot.enable()
    rm = Roadmap(1.0)
    op = ScriptedOperator(seed=11)
    t = 0.0
    n_recorded = 0
    views = []
    for name in ("tricuspid", "aortic", "mitral"):
        trace = np.vstack([op.explore(6), op.dwell(2.0, tremor=2e-5)])
        drive(trace, robot, rm)
        n_recorded += len(trace)
        t += len(trace) / 100
        views.append(rm.make_view(name, created_s=t, tip2base=robot.tip2base.copy()))
    wander = op.explore(10)
    drive(wander, robot, rm)
    n_recorded += len(wander)
    n_states = 0
    for view in reversed(views):
        path = rm.plan(robot.read_state().q, view, approach=True)
        follow(robot, path)
        np.testing.assert_array_equal(robot.read_state().q, view.q)
        np.testing.assert_allclose(robot.tip2base, view.tip2base, atol=1e-9)
        assert direction_tracker(path, rm.direction_threshold_motor) == view.arrival_direction
        n_states += len(path)
    # 100 Hz states are mostly tiny steps and dwelling: far fewer vertices than states
    assert rm.n_vertices < n_recorded / 3
    assert n_states > 3


def test_same_direction_approach_takes_up_backlash_on_the_physics_plant() -> None:
    """On the twin's catheter (slack, friction, backlash), returning with the recorded
    approach lands the tip nearer the saved pose than the plain shortest path."""
    from icenav.sim import CatheterPlant

    errors: dict[bool, list[float]] = {True: [], False: []}
    for seed in (1, 2):
        for approach in (True, False):
            robot = SimulatedRobot(CatheterPlant(seed=seed, vessel="moderate"))
            robot.enable()
            rm = Roadmap(1.0)
            op = ScriptedOperator(seed=seed)
            drive(op.explore(4), robot, rm)
            view = rm.make_view("v", created_s=0.0, tip2base=robot.tip2base.copy())
            drive(op.explore(6), robot, rm)
            path = rm.plan(robot.read_state().q, view, approach=approach)
            follow(robot, path)
            np.testing.assert_array_equal(robot.read_state().q, view.q)  # same motor state
            assert view.tip2base is not None
            errors[approach].append(
                float(np.linalg.norm(robot.tip2base[:3, 3] - view.tip2base[:3, 3]))
            )
    assert np.mean(errors[True]) < 0.6 * np.mean(errors[False])
