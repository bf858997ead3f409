"""The product's force check end to end on the twin: the controller records the operator's
contact forces, the session stores them, a restarted session checks its returns against them
(Eqs. F1, F2, F4, F5 of icenav.recovery.force)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from icenav.control.controller import Controller, ControllerConfig
from icenav.control.state import Mode
from icenav.devices.sim_robot import SimulatedRobot
from icenav.persistence.forces import load_forces
from icenav.persistence.recorder import StoreRecorder
from icenav.persistence.store import SessionStore
from icenav.sim.conditions import build_twin
from icenav.sim.disturbed import DisturbedTracker, TwinForceSensor, mean_pose
from tests.support.clock import Clock
from tests.support.twin import WanderingTracker, exact_tracker


def _cycle(ctrl: Controller, clock: Clock) -> None:
    clock.t += ctrl.config.dt
    ctrl.step()


def _jog_to(ctrl: Controller, clock: Clock, target: np.ndarray, seconds: float) -> None:
    """The operator drives the knobs to ``target`` in about ``seconds`` (jogs each cycle)."""
    n = int(round(seconds * ctrl.config.rate_hz))
    for k in range(n):
        q = np.asarray(ctrl.robot.read_state().q, np.float64)
        left = max((n - k) * ctrl.config.dt, ctrl.config.dt)
        ctrl.jog((target - q) / left, "knob")
        _cycle(ctrl, clock)


def _go(ctrl: Controller, clock: Clock, name: str) -> str:
    ctrl.goto_view(name)
    for _ in range(30_000):
        _cycle(ctrl, clock)
        if ctrl.mode is Mode.IDLE and ctrl.task is None and ctrl.cycle > 2:
            break
    return ctrl.snapshot().message


def test_a_restarted_session_keeps_the_forces_and_stops_a_return_into_a_moved_patient(
    tmp_path: Path,
) -> None:
    clock = Clock()
    twin = build_twin("phantom", 100, 0, clock)
    robot = SimulatedRobot(twin.plant, clock=clock)
    sensor = TwinForceSensor(twin.plant)
    path = tmp_path / "forces.icenav"
    store = SessionStore(path, new_session=True, clock=clock)
    tracker = twin.tracker.inner  # the EM tracker (get_frame, registration)
    tracker.start()
    ctrl = Controller(robot, ControllerConfig(), clock=clock, force_sensor=sensor,
                      tracker=tracker)  # fmt: skip
    recorder = StoreRecorder(store, ctrl.roadmap, threaded=True, forces=ctrl.forces)
    ctrl.set_recorder(recorder)
    assert ctrl.snapshot().force_check.startswith("on")
    q_view = np.asarray(twin.views["mitral_valve"], np.float64)
    ctrl.request_mode(Mode.KNOB)
    _jog_to(ctrl, clock, q_view, 2.4)
    ctrl.save_view("mitral")
    _cycle(ctrl, clock)
    _jog_to(ctrl, clock, np.zeros(4), 2.4)
    recorded = ctrl.forces.forces.n_recorded
    assert recorded > 50 and ctrl.forces.tips.n_samples > 20  # with the tracked tip
    assert ctrl.forces.rest_tip is not None  # where the operator left the tip (Eq. F5)
    assert f"{recorded} states" in ctrl.snapshot().force_check
    assert "done" in _go(ctrl, clock, "mitral")  # the patient where it was: it arrives
    np.testing.assert_allclose(robot.read_state().q, ctrl.views.get("mitral").q, atol=1e-9)
    assert ctrl.forces.forces.n_recorded == recorded  # a return is not the operator's trace
    assert ctrl.forces.rest_tip is None  # the return moved the motors: no rest pose
    recorder.flush()  # committed; then the process dies: the connection drops mid-batch
    ids = np.arange(ctrl.roadmap.n_vertices)
    before, tips_before = ctrl.forces.forces.at(ids), ctrl.forces.tips.samples()
    recorder.writer.close()  # type: ignore[union-attr]
    store._db.close()  # noqa: SLF001 - a crash: no flush, no clean close
    store._lock.release()  # type: ignore[union-attr]  # noqa: SLF001 - the OS releases it

    with SessionStore(path, clock=clock) as again:
        roadmap, views, forces = again.load_roadmap(), again.load_views(), load_forces(again)
    np.testing.assert_array_equal(forces.forces.at(ids), before)
    np.testing.assert_array_equal(forces.tips.samples(), tips_before)
    assert forces.rest_tip is None  # the return moved the motors: the stored rest is gone
    robot.command_position(np.zeros(4))
    twin.shift_patient([0.0, 20.0, 0.0])  # the patient moved on the table
    restarted = Controller(robot, ControllerConfig(), roadmap=roadmap, views=views,
                           clock=clock, force_sensor=sensor, forces=forces,
                           tracker=tracker)  # fmt: skip
    message = _go(restarted, clock, "mitral")
    assert "contact force" in message and "patient" in message, message
    assert not np.allclose(robot.read_state().q, views.get("mitral").q)  # held on the way


@pytest.mark.parametrize(
    ("force_channel", "ecg", "dwell_s"),
    [(True, False, 0.2), (False, False, 0.2), (False, True, 3.0)],
)
def test_a_return_does_not_start_after_the_patient_carried_the_tip_away(
    force_channel: bool, ecg: bool, dwell_s: float
) -> None:
    """Eq. (F5) in the controller: the operator drives to a view and half way back with
    the tracker (the twin's disturbed pose) and lets go for ``dwell_s``; the patient moves
    10 mm and carries the catheter; "go to view" stops as it starts and says why. Without
    the shift the return goes on. The check needs the tracker only: a robot without a force
    channel has it too. With the ECG connected, the loop keeps the still tip's readings with
    their cardiac phases (the phase-matched reference)."""
    for shift in (False, True):
        clock = Clock()
        twin = build_twin("phantom", 100, 0, clock)
        robot = SimulatedRobot(twin.plant, clock=clock)
        tracker = DisturbedTracker(exact_tracker(twin.plant.inner, clock), twin.plant)
        tracker.start()
        sensor = TwinForceSensor(twin.plant) if force_channel else None
        phase = twin.rhythm.phase if ecg else None
        ctrl = Controller(robot, ControllerConfig(), clock=clock, force_sensor=sensor,
                          tracker=tracker, cardiac_phase=phase)  # fmt: skip
        if not force_channel:
            assert ctrl.snapshot().force_check.endswith(
                "tip-drift check on (tracker, armed at your next drive: the last motion was "
                "not yours)"
            )
        q_view = np.asarray(twin.views["mitral_valve"], np.float64)
        ctrl.request_mode(Mode.KNOB)
        _jog_to(ctrl, clock, q_view, 1.2)
        ctrl.save_view("mitral")
        _jog_to(ctrl, clock, 0.5 * q_view, 0.6)
        for _ in range(int(dwell_s * ctrl.config.rate_hz)):  # the jog runs out; then still
            _cycle(ctrl, clock)
        rest = ctrl.forces.rest
        assert rest is not None
        if ecg:
            assert rest.n_readings > (dwell_s - 1.5) * ctrl.config.rate_hz
            resp, now_phase = ctrl.signals(ctrl.now())
            assert resp is None and now_phase is not None and 0.0 <= now_phase < 1.0
        q_left = np.asarray(robot.read_state().q).copy()
        if not force_channel:  # where the operator left the tip: the check is armed
            assert ctrl.snapshot().force_check.endswith("tip-drift check on (tracker)")
        if shift:
            twin.shift_patient([-10.0, 0.0, 0.0])
        ctrl.goto_view("mitral")
        for _ in range(50):
            _cycle(ctrl, clock)
        step = np.abs(np.asarray(robot.read_state().q) - q_left)
        message = ctrl.snapshot().message
        if shift:  # stopped in the path's first 0.2 s, still where the operator left it
            assert "as it started" in message and "motors still" in message, message
            assert ctrl.task is None and np.all(step < [0.05, 0.05, 0.05, 0.5])
        else:
            assert step.max() > 0.05 and "as it started" not in message, message


@pytest.mark.parametrize("case", ["still", "patient moved", "motors moved"])
def test_after_a_crash_the_stored_rest_pose_still_stops_a_return_into_a_moved_patient(
    case: str, tmp_path: Path
) -> None:
    """Eq. (F5) across a crash: the session stores where the operator left the tip and the
    motors; the process dies; the restarted controller keeps the rest pose only when the
    robot's motors stand where they were left. Then a patient who moved meanwhile stops the
    return as it starts; without a shift it goes; motors moved meanwhile (homed, driven by
    hand) leave no reference and the return goes unchecked by Eq. (F5)."""
    clock = Clock()
    twin = build_twin("phantom", 100, 0, clock)
    robot = SimulatedRobot(twin.plant, clock=clock)
    tracker = DisturbedTracker(exact_tracker(twin.plant.inner, clock), twin.plant)
    tracker.start()
    path = tmp_path / "rest.icenav"
    store = SessionStore(path, new_session=True, clock=clock)
    ctrl = Controller(robot, ControllerConfig(), clock=clock, tracker=tracker)
    recorder = StoreRecorder(store, ctrl.roadmap, threaded=True, forces=ctrl.forces)
    ctrl.set_recorder(recorder)
    q_view = np.asarray(twin.views["mitral_valve"], np.float64)
    ctrl.request_mode(Mode.KNOB)
    _jog_to(ctrl, clock, q_view, 1.2)
    ctrl.save_view("mitral")
    _jog_to(ctrl, clock, 0.5 * q_view, 0.6)
    for _ in range(60):  # the jog's hold runs out and the motors stop
        _cycle(ctrl, clock)
    rest_tip, q_left = ctrl.forces.rest_tip, np.asarray(robot.read_state().q).copy()
    assert rest_tip is not None
    recorder.flush()  # committed; then the process dies
    recorder.writer.close()  # type: ignore[union-attr]
    store._db.close()  # noqa: SLF001 - a crash: no clean close
    store._lock.release()  # type: ignore[union-attr]  # noqa: SLF001 - the OS releases it

    with SessionStore(path, clock=clock) as again:
        roadmap, views, forces = again.load_roadmap(), again.load_views(), load_forces(again)
    np.testing.assert_array_equal(forces.rest_tip, rest_tip)
    np.testing.assert_array_equal(forces.rest_q, q_left)
    if case == "motors moved":
        robot.command_position(q_left + np.array([0.0, 0.0, 0.1, 0.0]))
    if case != "still":
        twin.shift_patient([-10.0, 0.0, 0.0])
    restarted = Controller(robot, ControllerConfig(), roadmap=roadmap, views=views,
                           clock=clock, forces=forces, tracker=tracker)  # fmt: skip
    assert (restarted.forces.rest_tip is None) == (case == "motors moved")
    q_start = np.asarray(robot.read_state().q).copy()
    restarted.goto_view("mitral")
    for _ in range(50):
        _cycle(restarted, clock)
    step = np.abs(np.asarray(robot.read_state().q) - q_start)
    message = restarted.snapshot().message
    if case == "patient moved":
        assert "as it started" in message and "motors still" in message, message
        assert restarted.task is None and np.all(step < [0.05, 0.05, 0.05, 0.5])
    else:
        assert step.max() > 0.05 and "as it started" not in message, message


def test_without_a_force_channel_there_is_no_check_and_the_operator_is_told() -> None:
    clock = Clock()
    twin = build_twin("phantom", 100, 0, clock)
    robot = SimulatedRobot(twin.plant, clock=clock)
    ctrl = Controller(robot, ControllerConfig(), clock=clock)
    assert ctrl.snapshot().force_check == "off: no force channel"
    ctrl.request_mode(Mode.KNOB)
    _jog_to(ctrl, clock, np.array([0.0, 0.0, 0.0, 5.0]), 0.5)
    assert ctrl.forces.forces.n_recorded == 0


def test_the_loop_buffers_the_tracker_and_the_estimator_cuts_complete_breaths() -> None:
    """The product's EM pose for the refinement: the loop keeps the tracker's samples with
    their times; Eq. (R1) averages the complete breaths of the belt's signal, or the whole
    window without one."""
    clock = Clock()
    twin = build_twin("in-vivo", 100, 0, clock)
    robot = SimulatedRobot(twin.plant, clock=clock)
    exact = exact_tracker(twin.plant.inner, clock)
    tracker = DisturbedTracker(exact, twin.plant)  # frames at the disturbed pose of their time
    tracker.start()
    ctrl = Controller(robot, ControllerConfig(), clock=clock, tracker=tracker,
                      respiration=twin.monitor, cardiac_phase=twin.rhythm.phase)  # fmt: skip
    for _ in range(1000):  # 10 s held still
        _cycle(ctrl, clock)
    assert ctrl.pose_buffer is not None and len(ctrl.pose_buffer) >= 400
    _, buffered = ctrl.pose_buffer.sample_window(9.0, 80.0)
    assert np.ptp(buffered[:, :3, 3], axis=0).max() > 0.5  # mm: the breathing is buffered
    gated = ctrl.cycle_pose(window_s=9.0)
    est = gated.measure_tip2base()
    win = gated.last_window
    assert win is not None and win.kind == "breath" and win.cycles >= 1
    # the true poses over the complete breaths it cut (the tracker is exact)
    truth = mean_pose(
        np.stack([twin.plant.pose_at(t) for t in np.arange(win.start_s, win.end_s, 0.0125)])
    )
    np.testing.assert_allclose(est[:3, 3], truth[:3, 3], atol=0.1)
    plain = Controller(robot, ControllerConfig(), clock=clock, tracker=tracker)
    for _ in range(300):
        _cycle(plain, clock)
    blind = plain.cycle_pose(window_s=2.0)
    assert blind.measure_tip2base() is not None and blind.last_window.kind == "none"


def test_refine_view_runs_the_pose_stage_on_the_breath_averaged_pose() -> None:
    """Saved after the catheter was held still for the window, a view keeps its
    breath-averaged EM pose; "refine view" after a return servoes towards it on the same
    estimator and ends with a verdict. A view saved while moving cannot be refined."""
    from icenav.control.commands import Outcome

    clock = Clock()
    twin = build_twin("in-vivo", 100, 0, clock)
    robot = SimulatedRobot(twin.plant, clock=clock)
    tracker = twin.tracker.inner
    tracker.start()
    ctrl = Controller(robot, ControllerConfig(refine_window_s=4.0), clock=clock,
                      tracker=tracker, respiration=twin.monitor,
                      cardiac_phase=twin.rhythm.phase)  # fmt: skip
    ctrl.request_mode(Mode.KNOB)
    q_view = np.asarray(twin.views["mitral_valve"], np.float64)
    _jog_to(ctrl, clock, q_view, 2.0)
    ctrl.save_view("moving")  # not held still: no EM pose
    for _ in range(450):  # held still for the window
        _cycle(ctrl, clock)
    ctrl.save_view("still")
    _cycle(ctrl, clock)
    assert ctrl.views.get("moving").em_tip2base is None
    assert ctrl.views.get("still").em_tip2base is not None
    _jog_to(ctrl, clock, q_view + np.array([0.05, -0.05, 0.1, -3.0]), 1.0)
    assert "done" in _go(ctrl, clock, "still")
    saved = ctrl.views.get("still").em_tip2base

    def em_error_mm() -> float:
        for _ in range(450):  # held still for the window
            _cycle(ctrl, clock)
        now = ctrl.still_em_pose()
        assert now is not None
        return float(np.linalg.norm(now[:3, 3] - saved[:3, 3]))

    before = em_error_mm()
    refused = ctrl.refine_view("moving")
    _cycle(ctrl, clock)
    assert refused.final(0).outcome is Outcome.REFUSED
    assert "no EM pose was saved" in refused.final(0).reason
    ticket = ctrl.refine_view("still")
    for _ in range(20_000):
        _cycle(ctrl, clock)
        if ticket.finished:
            break
    final = ticket.final(0)
    assert final.outcome in (Outcome.DONE, Outcome.FAILED), final
    assert ctrl.mode is Mode.IDLE
    box = np.radians([5.0, 5.0, 30.0, 0.0]) + [0.0, 0.0, 0.0, 3.0]  # the stage's radius
    q_saved = ctrl.views.get("still").q
    assert np.all(np.abs(robot.read_state().q - q_saved) <= box + 1e-9)
    assert em_error_mm() <= before + 0.3  # never farther than it started (the scatter)


@pytest.mark.parametrize("between", ["nothing", "the operator drives"])
def test_where_the_drift_check_cannot_tell_a_return_asks_and_the_second_press_runs_it(
    between: str,
) -> None:
    """Eq. (F6) in the controller: the still tip wanders 4 mm about (no phase explains it)
    and is then carried 8 mm: the console says the check cannot tell here, the first press
    holds with a question, and a second press runs the return (the robot moves). When the
    operator drives between the presses, the new rest asks again."""
    clock = Clock()
    twin = build_twin("phantom", 100, 0, clock)
    robot = SimulatedRobot(twin.plant, clock=clock)
    tracker = WanderingTracker(DisturbedTracker(exact_tracker(twin.plant.inner, clock), twin.plant))
    tracker.start()
    ctrl = Controller(robot, ControllerConfig(), clock=clock, tracker=tracker,
                      cardiac_phase=twin.rhythm.phase)  # fmt: skip
    q_view = np.asarray(twin.views["mitral_valve"], np.float64)
    ctrl.request_mode(Mode.KNOB)
    _jog_to(ctrl, clock, q_view, 1.2)
    ctrl.save_view("mitral")
    _jog_to(ctrl, clock, 0.5 * q_view, 0.6)
    for _ in range(int(7.0 * ctrl.config.rate_hz)):  # the jog runs out; the operator looks
        _cycle(ctrl, clock)
    assert "cannot tell here" in ctrl.snapshot().force_check, ctrl.snapshot().force_check
    tracker.t_jump = clock.t
    q_left = np.asarray(robot.read_state().q).copy()
    message = _go(ctrl, clock, "mitral")
    assert "cannot tell here" in message and "press again" in message, message
    assert np.all(np.abs(np.asarray(robot.read_state().q) - q_left) < [0.05, 0.05, 0.05, 0.5])
    assert "s left)" in ctrl.snapshot().question  # the console keeps it in front
    if between == "the operator drives":
        ctrl.request_mode(Mode.KNOB)
        _jog_to(ctrl, clock, 0.45 * q_view, 0.3)
        for _ in range(int(7.0 * ctrl.config.rate_hz)):
            _cycle(ctrl, clock)
        q_left = np.asarray(robot.read_state().q).copy()
        message = _go(ctrl, clock, "mitral")
        assert "cannot tell here" in message, message
    else:
        _go(ctrl, clock, "mitral")
        assert np.abs(np.asarray(robot.read_state().q) - q_left).max() > 0.05
        assert ctrl.snapshot().question == ""  # answered


def test_the_rest_after_the_operators_stop_arms_the_tip_drift_check() -> None:
    """The operator jogs and presses Stop: the robot settles in IDLE; that settling is still
    the operator's drive, so the rest reference is kept (the check is armed). A return's own
    motion, ended in IDLE, is not."""
    clock = Clock()
    twin = build_twin("phantom", 100, 0, clock)
    robot = SimulatedRobot(twin.plant, clock=clock)
    tracker = DisturbedTracker(exact_tracker(twin.plant.inner, clock), twin.plant)
    tracker.start()
    ctrl = Controller(robot, ControllerConfig(), clock=clock, tracker=tracker,
                      cardiac_phase=twin.rhythm.phase)  # fmt: skip
    q_view = np.asarray(twin.views["mitral_valve"], np.float64)
    ctrl.request_mode(Mode.KNOB)
    _jog_to(ctrl, clock, q_view, 1.0)
    ctrl.save_view("mitral")
    for _ in range(20):  # driving on, then Stop while the knobs still move
        ctrl.jog(np.array([-0.4, 0.3, 0.0, 0.0]), "knob")
        _cycle(ctrl, clock)
    q_stop = ctrl.snapshot().q_motor  # the loop has not read the last jog's move yet
    ctrl.stop()
    for _ in range(int(2.0 * ctrl.config.rate_hz)):
        _cycle(ctrl, clock)
    assert ctrl.mode is Mode.IDLE
    assert not np.array_equal(ctrl.snapshot().q_motor, q_stop)  # it settled in IDLE
    assert ctrl.forces.rest is not None
    assert "armed at your next drive" not in ctrl.snapshot().force_check
    _go(ctrl, clock, "mitral")  # a return moves the robot: not the operator's
    assert ctrl.forces.rest is None
    assert "armed at your next drive" in ctrl.snapshot().force_check
