"""Go-to-view paths: the force check of a return, Eqs. (F1, F4) of icenav.recovery.force."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.control.tasks import Done, Failed, PathTask, Running
from icenav.devices.sim_robot import SimulatedRobot
from icenav.errors import InvalidValueError
from icenav.recovery.force import ForceMap
from icenav.recovery.roadmap import Roadmap
from icenav.sim.beat_imager import SimClock
from icenav.sim.conditions import build_twin
from icenav.sim.disturbed import TwinForceSensor

V_MAX = np.array([0.5, 0.5, 0.5, 5.0])


class _Sensor:
    def __init__(self, values: list[float | None]) -> None:
        self.values = values

    def contact_force_n(self) -> float | None:
        return self.values.pop(0) if len(self.values) > 1 else self.values[0]


def _run(task: PathTask, n: int = 10_000) -> tuple[object, int]:
    status: object = None
    for k in range(n):
        status = task.step(np.zeros(4), 0.01)
        if not isinstance(status, Running):
            return status, k
    return status, n


def test_a_path_stops_when_the_force_exceeds_the_trace_plus_the_margin() -> None:
    path = np.zeros((3, 4))
    path[:, 3] = [0.0, 1.0, 2.0]
    ok = PathTask(path, V_MAX, force_sensor=_Sensor([0.1]), force_profile=np.full(3, 0.05),
                  force_margin_n=0.06, force_margin_fraction=0.0)  # fmt: skip
    assert isinstance(_run(ok)[0], Done)
    over = PathTask(path, V_MAX, force_sensor=_Sensor([0.1] * 20 + [0.2]),
                    force_profile=np.full(3, 0.05), force_margin_n=0.04,
                    force_margin_fraction=0.4, force_hold_s=0.0)  # fmt: skip
    status, k = _run(over)
    assert isinstance(status, Failed) and k == 20
    held = PathTask(path, V_MAX, force_sensor=_Sensor([0.1] * 20 + [0.2]),
                    force_profile=np.full(3, 0.05), force_margin_n=0.04,
                    force_margin_fraction=0.4, force_hold_s=0.25)  # fmt: skip
    status_held, k_held = _run(held)  # Eq. (F4): above the limit for 0.25 s, then stops
    assert isinstance(status_held, Failed) and k_held == 20 + 25
    assert "for 0.25 s" in status_held.reason
    spike = PathTask(path, V_MAX, force_sensor=_Sensor([0.1] * 20 + [0.2] * 24 + [0.1]),
                     force_profile=np.full(3, 0.05), force_margin_n=0.04,
                     force_margin_fraction=0.4, force_hold_s=0.25)  # fmt: skip
    assert isinstance(_run(spike)[0], Done)  # above the limit 0.23 s: a slip, not a shift
    assert "0.20 N" in status.reason and "0.05 N" in status.reason and "margin" in status.reason
    assert over.failure == status.reason
    assert isinstance(over.step(np.zeros(4), 0.01), Failed)  # stays stopped: the robot holds
    blind = PathTask(path, V_MAX, force_sensor=_Sensor([None]), force_profile=np.zeros(3))
    assert isinstance(_run(blind)[0], Done)  # no reading: no check
    with pytest.raises(InvalidValueError):
        PathTask(path, V_MAX, force_profile=np.zeros(2))


def test_a_return_into_a_shifted_patient_stops_and_says_so() -> None:
    """The operator drives to a view and back (forces recorded per vertex); the patient
    then moves 20 mm on the table; the return replays the recorded states, meets more force
    than the trace did, and stops with the reason. Without the shift it arrives."""
    outcomes = []
    for shift in (False, True):
        clock = SimClock()
        twin = build_twin("phantom", 100, 0, clock.now)
        robot = SimulatedRobot(twin.plant, clock=clock.now)
        robot.enable()
        sensor = TwinForceSensor(twin.plant)
        roadmap, forces = Roadmap(epsilon=1.0), ForceMap()
        q_view = np.asarray(twin.views["mitral_valve"])
        out_and_back = np.concatenate(
            [np.linspace(np.zeros(4), q_view, 120), np.linspace(q_view, np.zeros(4), 120)]
        )
        for q in out_and_back:  # the operator's trace
            robot.command_position(q)
            roadmap.add(q)
            forces.record(roadmap.current_vertex, sensor.contact_force_n())
            clock.advance(0.02)
        if shift:
            twin.shift_patient([0.0, 20.0, 0.0])
        path = roadmap.plan(np.zeros(4), q_view)
        profile = forces.profile(roadmap, path)
        assert profile is not None
        task = PathTask(path, V_MAX, force_sensor=sensor, force_profile=profile)
        status: object = None
        for _ in range(20_000):
            status = task.step(np.asarray(robot.read_state().q), 0.02)
            if not isinstance(status, Running):
                break
            robot.command_position(status.q)
            clock.advance(0.02)
        held = np.asarray(robot.read_state().q).copy()
        outcomes.append((status, task.path_index, len(path), held))
    (arrived, _, _, q_end), (stopped, index, n, q_held) = outcomes
    assert isinstance(arrived, Done)
    np.testing.assert_allclose(q_end, q_view, atol=1e-9)
    assert isinstance(stopped, Failed), stopped
    assert "contact force" in stopped.reason and "patient" in stopped.reason
    assert index < n - 1 and not np.allclose(q_held, q_view)  # held on the way


def test_where_the_operator_had_the_tip_its_force_there_is_the_reference() -> None:
    """Eq. (F2): the motor state's recorded force is low (another lost motion), but the
    tracked tip is where the operator pushed 1.0 N: no stop; away from there it stops."""
    from icenav.recovery.force import TipForceMap

    path = np.zeros((3, 4))
    path[:, 3] = [0.0, 1.0, 2.0]
    tips = TipForceMap(radius_mm=2.0)
    at = np.eye(4)
    at[:3, 3] = [5.0, 0.0, 40.0]
    tips.record(at, 1.0)
    for tip_x, stops in ((5.5, False), (9.0, True)):
        pose = at.copy()
        pose[0, 3] = tip_x
        task = PathTask(path, V_MAX, force_sensor=_Sensor([1.5]), force_profile=np.full(3, 0.2),
                        force_margin_n=0.1, force_margin_fraction=0.5, tip_forces=tips,
                        tip_pose=lambda pose=pose: pose)  # fmt: skip
        status, _ = _run(task)
        assert isinstance(status, Failed) is stops, status
        if stops:
            assert "0.20 N" in status.reason  # the motor state's, the tip's not near


def test_the_return_holds_at_its_start_until_the_tip_index_is_built() -> None:
    """The index of the operator's tip readings is built off the loop: the path holds at
    its first state until the future is done, then checks against it."""
    from concurrent.futures import Future

    from icenav.recovery.force import TipForceMap

    path = np.zeros((3, 4))
    path[:, 3] = [0.0, 1.0, 2.0]
    tips = TipForceMap(radius_mm=2.0)
    at = np.eye(4)
    tips.record(at, 1.0)
    index: Future[object] = Future()
    task = PathTask(path, V_MAX, force_sensor=_Sensor([1.5]), force_profile=np.full(3, 0.2),
                    force_margin_n=0.1, force_margin_fraction=0.5, tip_index=index,
                    tip_pose=lambda: at)  # fmt: skip
    for _ in range(5):
        status = task.step(np.zeros(4), 0.01)
        assert isinstance(status, Running) and np.array_equal(status.q, path[0])
    assert task.progress == 0.0
    index.set_result(tips.index())
    assert isinstance(_run(task)[0], Done)  # 1.5 N <= 1.0 + 0.1 + 50 %: the tip's reference


def test_a_return_does_not_start_when_the_tip_moved_with_the_motors_still() -> None:
    """Eq. (F5) on the twin: the operator drives to a view and stops; the patient moves
    10 mm on the table and the vessel and walls carry the catheter: the tracked tip is no
    longer where the operator left it, and the return does not start. Without the shift it
    starts (and arrives)."""
    for shift in (False, True):
        clock = SimClock()
        twin = build_twin("phantom", 100, 0, clock.now)
        robot = SimulatedRobot(twin.plant, clock=clock.now)
        robot.enable()
        roadmap = Roadmap(epsilon=1.0)
        q_view = np.asarray(twin.views["mitral_valve"])
        for q in np.linspace(np.zeros(4), q_view, 120):  # the operator's trace
            robot.command_position(q)
            roadmap.add(q)
            clock.advance(0.02)
        rest = twin.tracker.measure_tip2base(1)[:3, 3]
        if shift:
            twin.shift_patient([-10.0, 0.0, 0.0])
        clock.advance(1.0)
        path = roadmap.plan(q_view, np.zeros(4))
        tracker = twin.tracker
        task = PathTask(path, V_MAX, rest_tip=rest, drift_limit_mm=5.0,
                        tip_pose=lambda tracker=tracker: tracker.measure_tip2base(1))  # fmt: skip
        status = task.step(np.asarray(robot.read_state().q), 0.02)
        if shift:
            assert isinstance(status, Failed) and "as it started" in status.reason, status
            assert "mm with the motors still" in status.reason and task.progress == 0.0
        else:
            assert isinstance(status, Running), status


def test_the_return_holds_at_its_start_while_it_checks_the_tip_drift() -> None:
    """Eq. (F5) is checked before the path moves: it holds at its first state for
    DRIFT_WINDOW_S (a tracker sample may be a frame old), then goes on."""
    from icenav.recovery.drift import DRIFT_WINDOW_S

    path = np.zeros((3, 4))
    path[:, 3] = [0.0, 1.0, 2.0]
    at = np.eye(4)
    at[:3, 3] = [1.0, 0.0, 40.0]
    task = PathTask(path, V_MAX, rest_tip=np.array([0.0, 0.0, 40.0]), drift_limit_mm=5.0,
                    tip_pose=lambda: at)  # fmt: skip
    held = 0
    while isinstance(status := task.step(np.zeros(4), 0.01), Running) and task.progress == 0:
        assert np.array_equal(status.q, path[0])
        held += 1
    n = round(DRIFT_WINDOW_S / 0.01)
    assert n <= held <= n + 1  # 0.1 s of 0.01 s cycles (one more when the sum rounds below)
    assert isinstance(_run(task)[0], Done)


def test_a_refused_start_tells_how_much_the_tip_strays_at_rest_and_matches_phases() -> None:
    """Eq. (F5) through the task's signals and clock: a tip swinging 4 mm with the beat is
    compared at its phase (no refusal at a like phase); moved 8 mm it is refused, and the
    reason says how far the tip strays at rest, so the operator can weigh it."""
    from icenav.recovery.drift import RestReference

    NOW = 5.75  # noqa: N806 - the opposite phase to the stop: 8 mm from it when nobody moved

    def at(t: float, shift: float = 0.0) -> np.ndarray:
        pose = np.eye(4)
        pose[:3, 3] = [shift + 4.0 * np.sin(2 * np.pi * t), 0.0, 40.0]
        return pose

    for shift in (0.0, 8.0):
        rest = RestReference(0.25, at(0.25), None, None, 0.25)
        for t in np.arange(0.27, 3.0, 0.02):
            rest.add(float(t), at(float(t)), None, float(t % 1.0))
        assert rest.drift(at(NOW)) > 5.0  # the instantaneous form would refuse
        path = np.zeros((2, 4))
        path[1, 3] = 1.0
        task = PathTask(path, V_MAX, rest_tip=rest, drift_limit_mm=5.0,
                        tip_pose=lambda s=shift: at(NOW, s), signals=lambda t: (None, t % 1.0),
                        clock=lambda: NOW)  # fmt: skip
        status = task.step(np.zeros(4), 0.01)
        if shift:
            assert isinstance(status, Failed) and "strayed up to" in status.reason, status
        else:
            assert isinstance(status, Running), getattr(status, "reason", status)


class _ConstantForce:
    def contact_force_n(self) -> float:
        return 0.2


def test_goto_view_task_is_the_products_check_with_the_controllers_settings() -> None:
    """One definition of the checked "go to view" task (controller and evaluations): the
    margins, hold and drift limit are the config's; without a channel or a recorded trace
    the path is not checked."""
    from dataclasses import replace

    from icenav.control.config import ControllerConfig
    from icenav.control.tasks import goto_view_task
    from icenav.recovery.force import ForceRecord

    roadmap = Roadmap(epsilon=1.0)
    path = np.array([[0.0, 0.0, 0.0, 0.0], [0.01, 0.0, 0.0, 1.0]])
    for q in path:
        roadmap.add(q)
    forces = ForceRecord()
    cfg = replace(ControllerConfig(), force_margin_n=0.3, force_margin_fraction=0.2,
                  force_hold_s=0.25, force_drift_mm=4.0)  # fmt: skip
    unchecked = goto_view_task(path, cfg, label="go", force_sensor=_ConstantForce(),
                               forces=forces, roadmap=roadmap, tip_pose=None)  # fmt: skip
    assert unchecked.force_sensor is None and unchecked.force_path is None  # no trace yet
    tip = np.eye(4)
    forces.record(roadmap.current_vertex, 0.2, tip)
    forces.note_motion(tip, operator=True)
    task = goto_view_task(path, cfg, label="go", force_sensor=_ConstantForce(), forces=forces,
                          roadmap=roadmap, tip_pose=lambda: tip)  # fmt: skip
    assert task.force_sensor is not None and task.force_path is not None
    assert (task.force_margin_n, task.force_margin_fraction) == (0.3, 0.2)
    assert (task.force_hold_s, task.drift_limit_mm) == (0.25, 4.0)
    assert task.tip_forces is forces.tips and task.rest_tip is not None
    none = goto_view_task(path, cfg, label="go", force_sensor=None, forces=forces,
                          roadmap=roadmap, tip_pose=None)  # fmt: skip
    assert none.force_sensor is None and none.rest_tip is None
    # no force channel but a tracker: the tip-drift check (Eq. F5) alone
    drift_only = goto_view_task(path, cfg, label="go", force_sensor=None, forces=forces,
                                roadmap=roadmap, tip_pose=lambda: tip)  # fmt: skip
    assert drift_only.force_sensor is None and drift_only.force_path is None
    assert drift_only.rest_tip is not None and drift_only.drift_limit_mm == 4.0


def test_where_the_check_cannot_tell_the_return_asks_and_a_second_press_runs_it() -> None:
    """Eqs. (F5, F6): a still tip that wanders as far as a shift would move it is 8 mm from
    its reference: the first press holds with a question (no refusal), a second press
    within CONFIRM_S runs the return under the force check alone, a later one asks again;
    a fresh reference (the operator drove) asks anew."""
    from icenav.recovery.drift import CONFIRM_S, REST_WINDOW_S, RestReference

    rng = np.random.default_rng(3)
    rest = RestReference(0.0, [0.0, 0.0, 40.0], None, None, 0.0)
    p = np.array([0.0, 0.0, 40.0])
    for t in np.arange(0.02, REST_WINDOW_S, 0.02):
        p = p + rng.normal(0.0, 0.6, 3)
        rest.add(float(t), p, None, float(t % 1.0))
    tip = np.eye(4)
    tip[:3, 3] = [8.0, 0.0, 40.0]
    path = np.zeros((2, 4))
    path[1, 3] = 1.0
    now = [20.0]

    def press(reference: RestReference) -> PathTask:
        return PathTask(path, V_MAX, rest_tip=reference, drift_limit_mm=5.0, tip_pose=lambda: tip,
                        signals=lambda t: (None, t % 1.0), clock=lambda: now[0])  # fmt: skip

    first = press(rest)
    status = first.step(np.zeros(4), 0.01)
    assert isinstance(status, Failed) and "cannot tell here" in status.reason, status
    assert "press again within 30 s" in status.reason and first.progress == 0.0
    now[0] += CONFIRM_S - 1.0
    second = press(rest)
    assert isinstance(_run(second)[0], Done) and second.drift_unchecked
    now[0] += 2.0  # more than CONFIRM_S after the question: asked again
    third = press(rest)
    assert isinstance(third.step(np.zeros(4), 0.01), Failed) and not third.drift_unchecked
    moved = RestReference(now[0], rest.tip, None, None, 0.0)  # the operator drove: a new one
    for t in np.arange(0.02, REST_WINDOW_S, 0.02):
        moved.add(now[0] + float(t), rest.tip + rng.normal(0.0, 4.0, 3), None, float(t % 1.0))
    now[0] += REST_WINDOW_S + 1.0
    status = press(moved).step(np.zeros(4), 0.01)
    assert isinstance(status, Failed) and "cannot tell here" in status.reason
