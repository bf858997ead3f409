"""Tests of icenav.control.spin: the spin as a controller task, open loop and on the tracker."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.control.servo import PoseServoConfig, TipPoseServo
from icenav.control.spin import SpinTask, tracked_tip2base
from icenav.control.state import Mode
from icenav.errors import InvalidValueError
from icenav.eval.metrics import rotation_angle
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, forward
from icenav.geometry.trajectories import spin_trajectory
from icenav.sim.beat_imager import SimClock
from icenav.sim.plant import CatheterPlant
from icenav.sim.tracker import EMTracker

V_MAX = np.array([1.0, 1.0, 1.0, 10.0])
DT = 0.01


def _run(task: SpinTask, plant: CatheterPlant, clock: SimClock) -> tuple[np.ndarray, int]:
    """Step the task to the end on the plant; true tip errors (mm) and cycles."""
    q = plant.state.q_motor.copy()
    errs = []
    n = 0
    while (cmd := task.next_command(q, DT)) is not None:
        plant.move(cmd)
        q = cmd
        clock.advance(DT)
        n += 1
        errs.append(np.linalg.norm(plant.state.tip2base[:3, 3] - task.intended[0, :3, 3]))
        assert np.all(cmd >= DEFAULT_GEOMETRY.joint_limits[:, 0] - 1e-12)
        assert np.all(cmd <= DEFAULT_GEOMETRY.joint_limits[:, 1] + 1e-12)
    return np.array(errs), n


@pytest.mark.parametrize("seed", [53, 54])
def test_closed_loop_holds_the_tip_better_than_open_loop(seed: int) -> None:
    """On the hysteretic twin, without F: the uncompensated spin drifts by millimetres; the
    EM closed loop removes most of it (its floor is the tracker's distortion)."""
    sp = spin_trajectory([math.radians(25.0), 0.0, 0.0, 0.0], 120, include_end=True)
    results = []
    for closed in (False, True):
        clock = SimClock()
        plant = CatheterPlant(seed=seed, vessel="moderate")
        plant.reset(sp.q_model[0])
        tracker = EMTracker(plant, seed=seed, clock=clock.now)
        tracker.start()
        source = (lambda t=tracker: tracked_tip2base(t)) if closed else None
        task = SpinTask(sp.q_model, None, V_MAX, DEFAULT_GEOMETRY.joint_limits, pose_source=source)
        assert task.mode is Mode.SPINNING
        errs, n = _run(task, plant, clock)
        assert task.progress == 1.0 and n > len(sp.q_model)
        results.append((float(np.sqrt(np.mean(errs[n // 4 :] ** 2))), task))
    (open_rms, _), (closed_rms, closed_task) = results
    assert closed_task.n_pose_updates > 50
    assert open_rms > 2.0
    assert closed_rms < 0.5 * open_rms


def test_one_servo_update_per_tracker_sample_and_missing_holds() -> None:
    sp = spin_trajectory([math.radians(30.0), 0.0, 0.0, 0.0], 40, include_end=True)
    frames = iter([(0.0, None), (0.0, None), (1.0, forward(sp.q_model[0]))] + [(1.0, None)] * 10**4)
    servo = TipPoseServo(PoseServoConfig())
    task = SpinTask(
        sp.q_model,
        None,
        V_MAX,
        DEFAULT_GEOMETRY.joint_limits,
        pose_source=lambda: next(frames),
        servo=servo,
    )
    q = sp.q_model[0]
    for _ in range(5):
        q = task.next_command(q, DT)
    # stamps 0.0, 0.0, 1.0, 1.0, 1.0: two distinct samples -> two servo updates, one MISSING
    assert servo.n_updates == 1 and servo.n_missing == 1 and task.n_pose_updates == 1


def test_open_loop_task_follows_the_feed_forward_path() -> None:
    sp = spin_trajectory([math.radians(40.0), 0.0, 0.0, 0.0], 60, include_end=True)
    task = SpinTask(sp.q_model, None, V_MAX, DEFAULT_GEOMETRY.joint_limits)
    q = sp.q_model[0]
    out = []
    while (cmd := task.next_command(q, DT)) is not None:
        out.append(cmd)
        q = cmd
    out_a = np.array(out)
    assert np.allclose(out_a[-1], sp.q_model[-1])
    # every command lies on the model path's polyline: its model tip stays put
    tips = forward(out_a)[:, :3, 3]
    assert np.max(np.linalg.norm(tips - forward(sp.q_model[0])[:3, 3], axis=1)) < 0.5
    ang = rotation_angle(forward(out_a[-1])[:3, :3], forward(sp.q_model[0])[:3, :3])
    assert float(ang) < 1e-6  # a full turn ends where it started


def test_bad_inputs_are_refused() -> None:
    lim = DEFAULT_GEOMETRY.joint_limits
    with pytest.raises(InvalidValueError, match="q_model_path"):
        SpinTask(np.zeros((1, 4)), None, V_MAX, lim)
    with pytest.raises(InvalidValueError, match="max_velocity"):
        SpinTask(np.zeros((3, 4)), None, [1.0, 0.0, 1.0, 1.0], lim)
    with pytest.raises(InvalidValueError, match="speed_scale"):
        SpinTask(np.zeros((3, 4)), None, V_MAX, lim, speed_scale=2.0)
