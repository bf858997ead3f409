"""The disturbed plant: a plant of the plug-in protocol around any plant, identical to it
with nothing switched on, time-dependent with the heart, measured over the tracker's window;
and the conditions that build it."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from icenav.devices.sim_robot import SimulatedRobot
from icenav.errors import ConfigurationError
from icenav.sim.beat_imager import SimClock
from icenav.sim.conditions import CONDITIONS, DISTURBANCES, build_twin, condition
from icenav.sim.disturbed import DisturbedPlant, DisturbedTracker, TwinForceSensor, mean_pose
from icenav.sim.plant import CatheterPlant
from tests.support.twin import exact_tracker

Q_VIEW = np.array([-0.17453292519943295, 0.3490658503988659, 0.7853981633974483, 0.0])


def test_with_nothing_on_it_is_the_plant() -> None:
    clock = SimClock()
    plain = CatheterPlant(seed=101, vessel="moderate")
    wrapped = DisturbedPlant(CatheterPlant(seed=101, vessel="moderate"), clock.now)
    path = np.linspace(np.zeros(4), Q_VIEW, 50)
    np.testing.assert_array_equal(wrapped.move_along(path), plain.move_along(path))
    np.testing.assert_array_equal(wrapped.state.tip2base, plain.state.tip2base)
    wrapped.reset(Q_VIEW)
    plain.reset(Q_VIEW)
    np.testing.assert_array_equal(wrapped.state.tip2base, plain.state.tip2base)


def test_the_robot_drives_a_twin_and_the_catheter_moves_with_the_heart() -> None:
    """In vivo the pose changes with time at a fixed motor state (beat, breathing, the
    shaft), the plant's own pose does not; past times since the last move are answered
    consistently; the contact force is reported per state."""
    clock = SimClock()
    twin = build_twin("in-vivo", 100, 0, clock.now)
    robot = SimulatedRobot(twin.plant, clock=clock.now)
    robot.enable()
    for q in np.linspace(np.zeros(4), np.asarray(twin.views["aortic_valve"]), 300):
        robot.command_position(q)
        clock.advance(0.01)
    t0 = clock.now()
    clock.advance(8.0)
    poses = np.stack([twin.plant.pose_at(t) for t in np.linspace(t0, t0 + 8.0, 81)])
    spread = np.ptp(poses[:, :3, 3], axis=0)
    assert 0.2 < np.linalg.norm(spread) < 15.0
    st = twin.plant.state_at(t0 + 3.0)
    np.testing.assert_array_equal(st.plant_tip2base, twin.plant.state.plant_tip2base)
    np.testing.assert_array_equal(twin.plant.pose_at(t0 + 3.0), st.tip2base)
    assert st.contact_force_n >= 0.0 and st.t == t0 + 3.0


class _Resolving:
    """An inner plant whose reported tip moves along x by ``offset(calls)`` mm: float
    round-off of a re-solve (alternating 1e-13 mm) or a plant that still creeps."""

    def __init__(self, plant: CatheterPlant, offset: Any) -> None:
        self._plant = plant
        self._offset = offset
        self.calls = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self._plant, name)

    def move(self, q: np.ndarray) -> np.ndarray:
        self.calls += 1
        self._plant.move(q)
        return np.asarray(self.state.tip2base)

    @property
    def state(self) -> Any:
        st = self._plant.state
        pose = np.array(st.tip2base)
        pose[0, 3] += self._offset(self.calls)
        return SimpleNamespace(tip2base=pose, inner=st)


def test_a_held_set_point_is_no_new_move_but_a_settling_plant_is() -> None:
    """The robot re-sends its set-point every cycle: a hold keeps the time of the last move
    (the shaft settles, the contact history goes on) although the inner plant re-solves to a
    pose that differs in the last bits; an inner plant that still moves by more than the
    tolerance starts a new motor state."""
    clock = SimClock()
    twin = build_twin("in-vivo", 100, 0, clock.now)
    plant = twin.plant
    robot = SimulatedRobot(plant, clock=clock.now)
    robot.enable()
    view = np.asarray(twin.views["aortic_valve"])
    for q in np.linspace(np.zeros(4), view, 100):
        robot.command_position(q)
        clock.advance(0.01)
    arrived = plant.last_move_s
    inner = plant.inner
    plant.inner = _Resolving(inner, lambda k: 1e-13 * (k % 2))
    for _ in range(50):
        robot.command_position(view)
        clock.advance(0.01)
    assert plant.last_move_s == arrived
    plant.inner = _Resolving(inner, lambda k: 1e-4 * k)
    robot.command_position(view)
    assert plant.last_move_s == clock.now() > arrived


def test_the_tracker_averages_over_its_window() -> None:
    """A jitter-free tracker of a disturbed plant returns the mean of the true poses over
    the last n / rate seconds."""
    clock = SimClock()
    twin = build_twin("phantom", 100, 1, clock.now)
    exact = exact_tracker(twin.plant.inner, clock.now)
    tracker = DisturbedTracker(exact, twin.plant)
    twin.plant.move(np.asarray(twin.views["mitral_valve"]))
    clock.advance(2.0)
    now = clock.now()
    measured = tracker.measure_tip2base(n_average=16)
    assert measured is not None
    times = now - np.arange(16)[::-1] / 80.0
    keys = np.round(times * 40.0) / 40.0
    expected = mean_pose(np.stack([twin.plant.pose_at(t) for t in keys]))
    np.testing.assert_allclose(measured, expected, atol=1e-9)


def test_the_tracker_keeps_its_samples_with_their_times() -> None:
    """sample_window: one sample per 1 / rate up to now, each the true pose at its time (a
    jitter-free tracker); the force channel reads the last solved contact force."""
    clock = SimClock()
    twin = build_twin("in-vivo", 100, 1, clock.now)
    exact = exact_tracker(twin.plant.inner, clock.now)
    tracker = DisturbedTracker(exact, twin.plant)
    twin.plant.move(np.asarray(twin.views["aortic_valve"]))
    clock.advance(3.0)
    times, poses = tracker.sample_window(2.0, 10.0)
    np.testing.assert_allclose(times, clock.now() - np.arange(20)[::-1] / 10.0)
    for t, p in zip(times[::5], poses[::5], strict=True):
        np.testing.assert_allclose(p, twin.plant.pose_at(float(t)), atol=1e-9)
    assert np.ptp(poses[:, :3, 3], axis=0).max() > 0.1  # the tip moves with breathing
    sensor = TwinForceSensor(twin.plant)
    now = twin.plant.state.contact_force_n  # solves the state now
    assert sensor.contact_force_n() == pytest.approx(now)
    with pytest.raises(ConfigurationError):
        tracker.sample_window(0.0, 10.0)


def test_the_frames_the_control_loop_reads_move_with_the_heart_and_breathing() -> None:
    """get_frame (what the product's loop buffers) reports each frame at the disturbed pose
    of its acquisition time, as measure_tip2base does; it returned the undisturbed pose."""
    clock = SimClock()
    twin = build_twin("in-vivo", 100, 1, clock.now)
    exact = exact_tracker(twin.plant.inner, clock.now, latency_s=0.0)
    tracker = DisturbedTracker(exact, twin.plant)
    tracker.start()
    twin.plant.move(np.asarray(twin.views["aortic_valve"]))
    tips = []
    for _ in range(80):  # 8 s: two breaths or more
        clock.advance(0.1)
        frame = tracker.get_frame()
        assert frame.sensor2tracker is not None
        assert tracker.get_frame() is frame  # the same sample until the next is due
        tip = tracker.registration.tip2base(frame.sensor2tracker)
        np.testing.assert_allclose(tip, twin.plant.pose_at(frame.timestamp), atol=1e-9)
        tips.append(tip[:3, 3])
    assert np.ptp(np.array(tips), axis=0).max() > 0.5  # mm: the breathing is in the frames


def test_a_patient_shift_moves_the_walls_not_the_motors() -> None:
    """The anatomy moves by the shift in the base frame: a catheter held near a wall meets
    it (more contact force), and the shift back restores the state."""
    clock = SimClock()
    twin = build_twin("phantom", 100, 0, clock.now)
    q = np.asarray(twin.views["mitral_valve"])
    twin.plant.move(q)
    clock.advance(0.5)
    before = twin.plant.state.contact_force_n
    b2a = twin.base2anatomy.copy()
    twin.shift_patient([0.0, 15.0, 0.0])
    np.testing.assert_allclose(
        np.linalg.inv(twin.base2anatomy) @ b2a @ np.array([0, 0, 0, 1.0]),
        [0, 15.0, 0, 1],
        atol=1e-9,
    )  # an anatomy point now sits 15 mm further along base y
    shifted = twin.plant.state.contact_force_n
    assert shifted > before + 0.02
    twin.shift_patient([0.0, -15.0, 0.0])
    assert twin.plant.state.contact_force_n == pytest.approx(before, abs=1e-9)
    np.testing.assert_allclose(twin.plant.state.q_motor, q)


def test_conditions_switch_disturbances_off() -> None:
    c = condition("in-vivo")
    assert set(c.active) == set(DISTURBANCES)
    assert condition("phantom").breathing is None
    off = c.without("breathing", "shaft")
    assert "breathing" not in off.active and "shaft" not in off.active and off.contact
    assert condition("none").active == ()
    assert set(CONDITIONS) == {"none", "phantom", "in-vivo"}
    with pytest.raises(ConfigurationError, match="unknown disturbance"):
        c.without("gravity")
    with pytest.raises(ConfigurationError, match="condition must be one of"):
        condition("mars")


def test_seeds_per_catheter_and_per_patient() -> None:
    """The patient seed sets the heart and the views; the catheter seed the plant; the
    shaft draws depend on both."""
    a = build_twin("in-vivo", 100, 0, SimClock().now)
    b = build_twin("in-vivo", 101, 0, SimClock().now)
    c = build_twin("in-vivo", 100, 1, SimClock().now)
    assert a.patient == b.patient != c.patient
    assert a.views == b.views != c.views
    assert a.plant.inner.params != b.plant.inner.params
    assert a.plant.shaft is not None and b.plant.shaft is not None and c.plant.shaft is not None
    draws = [t.plant.shaft._xi for t in (a, b, c)]  # first stick's static friction factor
    assert len(set(draws)) == 3


def test_bad_wrapping_is_refused() -> None:
    with pytest.raises(ConfigurationError, match="callable move"):
        DisturbedPlant(object(), SimClock().now)
    with pytest.raises(ConfigurationError, match="measure_tip2base"):
        DisturbedTracker(object(), DisturbedPlant(CatheterPlant(), SimClock().now))
