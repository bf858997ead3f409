"""Tests of icenav.refinement.pose_stage: the EM pose stage of the view refinement."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray

from icenav.devices.sim_robot import SimulatedRobot
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import forward
from icenav.refinement.image_search import NeighbourhoodError
from icenav.refinement.pose_stage import (
    PoseStageConfig,
    PoseStageStatus,
    PoseStageTask,
    pose_error,
    pose_stage,
)
from icenav.sim.anatomy import EXAMPLE_VIEWS
from icenav.sim.tracker import rotvec_to_matrix
from tests.support.refinement import em_bench, true_error

Array = NDArray[np.float64]
DEG = math.pi / 180


def test_pose_error_recovers_a_known_body_twist() -> None:
    """Round trip: target = measured @ exp(twist) gives back the twist (rotation vector)."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        m = forward(rng.uniform([-0.5, -0.5, -3, -20], [0.5, 0.5, 3, 20]))
        w = rng.normal(size=3) * 0.02
        v = rng.normal(size=3) * 0.5
        step = np.eye(4)
        step[:3, :3] = rotvec_to_matrix(w)
        step[:3, 3] = v
        err = pose_error(m @ step, m)
        np.testing.assert_allclose(err[:3], v, atol=1e-9)
        np.testing.assert_allclose(err[3:], w, atol=1e-9)
    np.testing.assert_allclose(pose_error(np.eye(4), np.eye(4)), np.zeros(6), atol=0)
    with pytest.raises(ShapeError, match="shape"):
        pose_error(np.eye(3), np.eye(4))


@pytest.mark.parametrize("seed", [110, 111, 112, 113])
def test_pose_stage_reduces_a_known_play_error_on_the_hysteretic_twin(seed: int) -> None:
    """A view saved after approaching every joint from below, far enough to take up every
    play. The catheter comes back to the same motor state with the knobs again from below
    (as the roadmap's recorded approach does) but the roll and the translation from above,
    so their plays (roll, distal twist, translation) sit on the other side, and with the
    knobs a little short of the view: the tip is off by up to millimetres and up to 20 deg.
    The pose stage (EM tracker, averaged samples) brings the true error down to about the
    tracker's averaged noise."""
    clock, plant, robot, tracker = em_bench(seed, ("moderate", "steep")[seed % 2])
    rng = np.random.default_rng(seed)
    name = ("aortic_valve", "mitral_valve", "tricuspid_valve")[seed % 3]
    q_view = np.array(EXAMPLE_VIEWS[name]) + rng.uniform(-1, 1, 4) * [2 * DEG, 2 * DEG, 5 * DEG, 1]
    below = np.array([16 * DEG, 16 * DEG, 30 * DEG, 3.0])
    plant.move(q_view - below)
    robot.command_position(q_view)  # every joint arrives from below
    saved_true = plant.state.tip2base.copy()
    saved_em = tracker.measure_tip2base(n_average=64)
    assert saved_em is not None
    short = rng.uniform(0.3, 1.0, 2) * DEG
    plant.move(q_view + [-below[0], -below[1], below[2], below[3]])
    robot.command_position(q_view - [short[0], short[1], 0.0, 0.0])
    d0, a0 = true_error(plant, saved_true)
    assert d0 > 0.3 or a0 > 0.5  # the play really is on the other side
    sent: list[Array] = []
    res = pose_stage(robot, q_view, saved_em, tracker, arrival_direction=(1, 1, 1, 1),
                     start_direction=(1, 1, -1, -1), sleep=clock.advance,
                     on_command=sent.append)  # fmt: skip
    d1, a1 = true_error(plant, saved_true)
    assert res.status in (PoseStageStatus.CONVERGED, PoseStageStatus.STALLED)
    assert d1 < 0.3 and a1 < 0.3, (d0, a0, d1, a1, res.status)
    assert d1 < d0 and a1 < a0
    # the result's measurements are the EM's view of the same thing
    assert res.final is not None and res.final.position_mm < 0.4
    radius = np.array(PoseStageConfig().radius)
    assert all(np.all(np.abs(q - q_view) <= radius + 1e-12) for q in sent)
    assert np.all(res.max_offset <= radius + 1e-12)
    np.testing.assert_allclose(res.q_final, robot.read_state().q)
    # the knobs were never moved against their arrival direction (no tendon play crossed)
    knobs = np.array([q[:2] for q in [q_view - [short[0], short[1], 0, 0], *sent]])
    assert np.all(np.diff(knobs, axis=0) >= -1e-12)


def test_pose_stage_does_nothing_at_the_view() -> None:
    clock, plant, robot, tracker = em_bench(120)
    q_view = np.array(EXAMPLE_VIEWS["mitral_valve"])
    robot.command_position(q_view)
    saved = tracker.measure_tip2base(n_average=64)
    assert saved is not None
    sent: list[Array] = []
    res = pose_stage(robot, q_view, saved, tracker, sleep=clock.advance, on_command=sent.append)
    assert res.status == PoseStageStatus.AT_VIEW
    assert res.n_commands == 0 and len(res.measurements) == 1
    assert all(np.array_equal(q, q_view) for q in sent)  # it only held still to measure


class _NoisyPose:
    """A pose sensor that reports a fixed wrong pose plus large noise (a tracker in a
    disturbed field): the servo must still stay in its box and within its budgets."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def measure_tip2base(self, n_average: int = 1) -> Array | None:
        if self.rng.random() < 0.05:
            return None
        t = np.eye(4)
        t[:3, :3] = rotvec_to_matrix(self.rng.normal(size=3) * 0.1)
        t[:3, 3] = self.rng.normal(size=3) * 5.0
        return t


def test_pose_stage_never_leaves_its_neighbourhood_random_cases() -> None:
    """Random views, starts, targets and sensors (true tracker or a wild one): every
    set-point sent stays in the box, within the iteration and time budgets."""
    for seed in range(12):
        rng = np.random.default_rng(seed)
        clock, plant, robot, tracker = em_bench(
            130 + seed, ("straight", "moderate", "steep")[seed % 3]
        )
        q_view = np.array([*rng.uniform(-0.4, 0.4, 2), rng.uniform(-2, 2), rng.uniform(-20, 20)])
        cfg = PoseStageConfig(
            radius=(3 * DEG, 3 * DEG, 20 * DEG, 2.0),
            max_step=(*(rng.uniform(0.2, 1.0) * np.array([2 * DEG, 2 * DEG, 4 * DEG, 1.0])),),
            backoff=(2 * DEG, 2 * DEG, 25 * DEG, 1.5),
            max_iterations=int(rng.integers(1, 8)),
            reapproach_first=bool(seed % 2),
        )
        radius = np.array(cfg.radius)
        start = q_view + rng.uniform(-1, 1, 4) * radius
        robot.command_position(start)
        target = tracker.measure_tip2base(16)
        assert target is not None
        offset = np.eye(4)
        offset[:3, :3] = rotvec_to_matrix(rng.normal(size=3) * 0.03)
        offset[:3, 3] = rng.normal(size=3)
        target = target @ offset
        sensor = tracker if seed % 3 else _NoisyPose(seed)
        sent: list[Array] = []
        arrival = tuple(int(d) for d in rng.integers(-1, 2, 4))
        res = pose_stage(robot, q_view, target, sensor, arrival_direction=arrival, config=cfg,
                         sleep=clock.advance, on_command=sent.append)  # fmt: skip
        assert sent, seed
        assert all(np.all(np.abs(q - q_view) <= radius * (1 + 1e-9) + 1e-12) for q in sent)
        assert len(res.measurements) <= cfg.max_iterations + 3
        assert res.duration_s <= cfg.max_duration_s + 10.0
        assert res.status != PoseStageStatus.RUNNING


def test_pose_stage_stops_on_abort() -> None:
    clock, plant, robot, tracker = em_bench(140)
    q_view = np.array(EXAMPLE_VIEWS["aortic_valve"])
    robot.command_position(q_view)
    saved = tracker.measure_tip2base(n_average=32)
    assert saved is not None
    polls: list[int] = []

    def abort() -> bool:
        polls.append(1)
        return len(polls) > 150

    shifted = saved.copy()
    shifted[:3, 3] += [0.0, 0.0, 1.0]  # a 1 mm target: the stage must move
    sent: list[Array] = []
    res = pose_stage(robot, q_view, shifted, tracker, abort=abort, sleep=clock.advance,
                     on_command=sent.append)  # fmt: skip
    assert res.status == PoseStageStatus.ABORTED
    assert len(sent) == 150  # not one set-point after the abort
    assert res.n_commands > 0  # it was moving when stopped
    np.testing.assert_allclose(res.q_final, robot.read_state().q)
    task = PoseStageTask(q_view, shifted, tracker, abort=lambda: True)
    assert task.next_command(q_view, 0.01) is None and task.status == PoseStageStatus.ABORTED


def test_pose_stage_timeout_and_bad_inputs() -> None:
    clock, plant, robot, tracker = em_bench(141)
    q_view = np.array(EXAMPLE_VIEWS["aortic_valve"])
    robot.command_position(q_view)
    far = np.eye(4)
    far[:3, 3] = 1000.0  # unreachable: runs until its time budget
    cfg = PoseStageConfig(max_duration_s=2.0, max_iterations=50, min_gain=0.01)
    res = pose_stage(robot, q_view, far, tracker, config=cfg, sleep=clock.advance)
    assert res.status in (PoseStageStatus.TIMEOUT, PoseStageStatus.STALLED)
    assert res.duration_s <= 2.0 + 10.0
    with pytest.raises(NeighbourhoodError, match="outside the pose stage radius"):
        PoseStageTask(q_view, far, tracker, q_start=q_view + [0.0, 0.0, 0.0, 5.0])
    with pytest.raises(ShapeError, match="saved_tip2base"):
        PoseStageTask(q_view, np.eye(3), tracker)
    with pytest.raises(ConfigurationError, match="arrival_direction"):
        PoseStageTask(q_view, far, tracker, arrival_direction=(2, 0, 0, 0))
    with pytest.raises(ConfigurationError, match="start_direction"):
        PoseStageTask(q_view, far, tracker, start_direction=(0, 0, 0))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_average": 0}, "n_average"),
        ({"max_step": (1.0, 0.01, 0.01, 0.1)}, "max_step"),
        ({"tolerance_mm": -1.0}, "tolerance_mm"),
        ({"min_gain": 0.0}, "min_gain"),
        ({"damping": math.nan}, "damping"),
        ({"backoff": (0.1, 0.1, 0.1)}, "backoff"),
        ({"undo_margin_mm": -0.1}, "undo_margin_mm"),
    ],
)
def test_bad_pose_stage_config_is_rejected(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        PoseStageConfig(**kwargs)  # type: ignore[arg-type]


# --- respiratory gating ----------------------------------------------------------------------


class _WorseWithEveryMove:
    """A pose sensor that reads the saved pose offset by 1 mm, plus 20 mm per radian (or
    mm) the commanded state moved from where the stage started: every step looks worse."""

    def __init__(self, robot: SimulatedRobot, q0: Array) -> None:
        self.robot, self.q0 = robot, q0.copy()

    def measure_tip2base(self, n_average: int = 1) -> Array:
        moved = float(np.abs(np.asarray(self.robot.read_state().q) - self.q0).sum())
        out = np.eye(4)
        out[0, 3] = 1.0 + 20.0 * moved
        return out


def test_a_stage_that_made_it_worse_goes_back_to_where_it_started() -> None:
    """The stage never ends farther from the saved pose than it started, as its own
    estimator tells: worse after its steps, it re-approaches the start state."""
    clock, plant, robot, _ = em_bench(110)
    q0 = np.array([0.05, -0.05, 0.3, 2.0])
    robot.command_position(q0)
    clock.advance(0.5)
    sensor = _WorseWithEveryMove(robot, q0)
    cfg = PoseStageConfig(max_iterations=2, reapproach_first=False, hold_s=0.1)
    res = pose_stage(robot, q0, np.eye(4), sensor, config=cfg, sleep=clock.advance,
                     arrival_direction=(1, 1, 1, 1))  # fmt: skip
    assert res.undone
    # roll and translation are re-approached exactly; the knobs are never reversed (their
    # tendon play), so they stay where the one-sided steps left them
    np.testing.assert_allclose(res.q_final[2:], q0[2:], atol=1e-12)
    np.testing.assert_allclose(res.q_final[:2], q0[:2], atol=1e-3)
    assert res.final is not None and res.final.position_mm == pytest.approx(1.0, abs=0.05)
    assert res.final.position_mm < max(m.position_mm for m in res.measurements)
    assert len(res.measurements) >= 3  # the start, the steps, and after going back
    off = PoseStageConfig(max_iterations=2, reapproach_first=False, hold_s=0.1,
                          undo_if_worse=False)  # fmt: skip
    robot.command_position(q0)
    res2 = pose_stage(robot, q0, np.eye(4), sensor, config=off, sleep=clock.advance,
                      arrival_direction=(1, 1, 1, 1))  # fmt: skip
    assert not res2.undone


class _Scripted:
    """EM 'tracker' whose measured position error follows a script, one value per
    measurement (mm along the base x axis); records the commanded state of each."""

    def __init__(self, robot: SimulatedRobot, errors_mm: list[float]) -> None:
        self.robot, self.errors = robot, list(errors_mm)
        self.q: list[Array] = []

    def measure_tip2base(self, n_average: int = 1) -> Array:
        self.q.append(np.asarray(self.robot.read_state().q, np.float64).copy())
        out = np.eye(4)
        out[0, 3] = self.errors.pop(0) if self.errors else 5.0
        return out


def test_a_correction_that_landed_worse_goes_back_to_the_best_measured_state() -> None:
    """With ``revisit_best`` the stage ends at the best *measured* command (re-approached,
    measured again), not at the worse last one and not at the start: start 2.0 mm, first
    correction 0.8 mm, second 3.0 mm (a bad draw) -> back to the first correction's state."""
    clock, plant, robot, _ = em_bench(110)
    q0 = np.array([0.05, -0.05, 0.3, 2.0])
    robot.command_position(q0)
    clock.advance(0.5)
    sensor = _Scripted(robot, [2.0, 0.8, 3.0, 0.9])
    cfg = PoseStageConfig(max_iterations=2, reapproach_first=False, hold_s=0.1,
                          step_from_last=True, revisit_best=True, tolerance_mm=0.5,
                          min_decrease_mm=0.3)  # fmt: skip
    res = pose_stage(robot, q0, np.eye(4), sensor, config=cfg, sleep=clock.advance,
                     arrival_direction=(1, 1, 1, 1))  # fmt: skip
    assert res.revisits == 1 and not res.undone
    assert [round(m.position_mm, 3) for m in res.measurements] == [2.0, 0.8, 3.0, 0.9]
    # the end state is the first correction's command, roll and translation re-approached
    np.testing.assert_allclose(res.q_final[2:], sensor.q[1][2:], atol=1e-12)
    assert not np.allclose(sensor.q[1], q0) and not np.allclose(sensor.q[1], sensor.q[2])
    # without it, the stage stays at its worse last state (and would undo to the start)
    robot.command_position(q0)
    plain = replace(cfg, revisit_best=False, undo_if_worse=False)
    res2 = pose_stage(robot, q0, np.eye(4), _Scripted(robot, [2.0, 0.8, 3.0]), config=plain,
                      sleep=clock.advance, arrival_direction=(1, 1, 1, 1))  # fmt: skip
    assert res2.revisits == 0 and res2.final is not None and res2.final.position_mm == 3.0


def test_a_difference_within_the_undo_margin_is_not_undone() -> None:
    """``undo_margin_mm``: last 2.2 mm against a first 2.0 mm is within a 0.3 mm margin (the
    estimator's scatter), so the stage stays; 2.4 mm is beyond it and goes back."""
    clock, plant, robot, _ = em_bench(110)
    q0 = np.array([0.05, -0.05, 0.3, 2.0])
    cfg = PoseStageConfig(max_iterations=1, reapproach_first=False, hold_s=0.1,
                          step_from_last=True, undo_margin_mm=0.3)  # fmt: skip
    for last, undone in ((2.2, False), (2.4, True)):
        robot.command_position(q0)
        clock.advance(0.5)
        res = pose_stage(robot, q0, np.eye(4), _Scripted(robot, [2.0, last, 2.0]), config=cfg,
                         sleep=clock.advance, arrival_direction=(1, 1, 1, 1))  # fmt: skip
        assert res.undone is undone
        assert len(res.measurements) == (3 if undone else 2)


def test_the_stage_makes_no_move_it_cannot_measure_within_its_time() -> None:
    """With ``step_from_last`` a correction starts only when it and a measurement after it
    (and, with ``undo_if_worse``, a way back to the start) fit in ``max_duration_s``: the
    stage ends at its last *measured* state (status BUDGET), never with a blind move."""
    clock, plant, robot, _ = em_bench(110)
    q0 = np.array([0.05, -0.05, 0.3, 2.0])
    for undo, n_meas in ((False, 2), (True, 1)):
        robot.command_position(q0)
        clock.advance(0.5)
        sensor = _Scripted(robot, [2.0] * 10)
        cfg = PoseStageConfig(max_iterations=10, reapproach_first=False, hold_s=10.0,
                              max_duration_s=25.0, step_from_last=True, undo_if_worse=undo,
                              tolerance_mm=0.1)  # fmt: skip
        res = pose_stage(robot, q0, np.eye(4), sensor, config=cfg, sleep=clock.advance,
                         arrival_direction=(1, 1, 1, 1))  # fmt: skip
        assert res.status is PoseStageStatus.BUDGET
        assert len(res.measurements) == n_meas
        np.testing.assert_allclose(res.q_final, sensor.q[-1], atol=1e-12)
        assert res.duration_s <= 25.0


def test_the_stage_ends_at_its_best_measured_state_the_start_included() -> None:
    """``end_at_best``: when the last measurement is worse than the best by more than the
    scatter, the best command is re-approached and measured again; when no correction did
    better than the start, that is the start (the stage undoes itself)."""
    clock, plant, robot, _ = em_bench(110)
    q0 = np.array([0.05, -0.05, 0.3, 2.0])
    cfg = PoseStageConfig(max_iterations=2, reapproach_first=False, hold_s=0.1,
                          step_from_last=True, end_at_best=True, tolerance_mm=0.5,
                          min_decrease_mm=0.3)  # fmt: skip
    for script, best, undone in (([2.0, 3.0, 2.9, 2.1], 0, True),
                                 ([2.0, 0.8, 3.0, 0.9], 1, False)):  # fmt: skip
        robot.command_position(q0)
        clock.advance(0.5)
        sensor = _Scripted(robot, script)
        res = pose_stage(robot, q0, np.eye(4), sensor, config=cfg, sleep=clock.advance,
                         arrival_direction=(1, 1, 1, 1))  # fmt: skip
        assert [round(m.position_mm, 3) for m in res.measurements] == script
        assert res.revisits == 1 and res.undone is undone
        np.testing.assert_allclose(res.q_final[2:], sensor.q[best][2:], atol=1e-12)
        assert res.final is not None and res.final.position_mm == script[-1]


def test_a_state_within_the_dead_band_is_accepted_only_when_a_second_window_agrees() -> None:
    """``verify``: a first window within the dead band (0.1 mm) is measured again at the
    same command; the second (0.9 mm: a lucky first estimate, or a slip while held) is not
    accepted and the corrections go on until a measured state is confirmed (0.2, 0.3)."""
    clock, plant, robot, _ = em_bench(110)
    q0 = np.array([0.05, -0.05, 0.3, 2.0])
    cfg = PoseStageConfig(max_iterations=3, reapproach_first=False, hold_s=0.1,
                          step_from_last=True, verify=True, tolerance_mm=0.5)  # fmt: skip
    robot.command_position(q0)
    clock.advance(0.5)
    sensor = _Scripted(robot, [0.1, 0.9, 0.2, 0.3])
    res = pose_stage(robot, q0, np.eye(4), sensor, config=cfg, sleep=clock.advance,
                     arrival_direction=(1, 1, 1, 1))  # fmt: skip
    assert res.status is PoseStageStatus.CONVERGED
    assert [round(m.position_mm, 3) for m in res.measurements] == [0.1, 0.9, 0.2, 0.3]
    np.testing.assert_array_equal(sensor.q[0], sensor.q[1])  # no move between the windows
    np.testing.assert_array_equal(sensor.q[2], sensor.q[3])
    assert not np.array_equal(sensor.q[1], sensor.q[2])
    # without it the first window is taken at its word
    robot.command_position(q0)
    res = pose_stage(robot, q0, np.eye(4), _Scripted(robot, [0.1, 0.9]),
                     config=replace(cfg, verify=False), sleep=clock.advance,
                     arrival_direction=(1, 1, 1, 1))  # fmt: skip
    assert res.status is PoseStageStatus.AT_VIEW and len(res.measurements) == 1


def test_every_last_leg_starts_at_end_expiration_and_waits_no_longer_than_its_cap() -> None:
    """``arrive_at_expiration``: the last leg of every move (here: the roll coming back from
    its backoff) starts only while the gate is open (open 1 s of every 2); a gate that never
    opens delays each last leg by ``expiration_wait_s`` exactly; without the flag the gate is
    never asked."""
    clock, plant, robot, _ = em_bench(110)
    q0 = np.array([0.05, -0.05, 0.3, 2.0])
    cfg = PoseStageConfig(max_iterations=2, reapproach_first=False, hold_s=0.1,
                          step_from_last=True, approach_always=True, tolerance_mm=0.1,
                          undo_if_worse=False, arrive_at_expiration=True,
                          expiration_wait_s=1.0, max_duration_s=60.0)  # fmt: skip

    def leg_starts(gate: object, config: PoseStageConfig, relative: bool = True) -> list[float]:
        robot.command_position(q0)
        clock.advance(0.5)
        sent: list[tuple[float, float]] = []
        t0 = clock.now() if relative else 0.0
        pose_stage(robot, q0, np.eye(4), _Scripted(robot, [2.0, 1.5, 1.0]), config=config,
                   sleep=clock.advance, arrival_direction=(1, 1, 1, 1),
                   expiration=gate,  # type: ignore[arg-type]
                   on_command=lambda q: sent.append((clock.now(), float(q[2]))))  # fmt: skip
        # the roll's last leg starts where the commanded roll stops falling and rises
        roll = [r for _, r in sent]
        return [sent[i][0] - t0 for i in range(2, len(sent))
                if roll[i] > roll[i - 1] + 1e-12 and roll[i - 1] <= roll[i - 2]]  # fmt: skip

    starts = leg_starts(lambda: clock.now() % 2.0 >= 1.0, cfg, relative=False)
    assert len(starts) == 2  # two corrections, each with a last leg
    assert all(t % 2.0 >= 0.98 for t in starts), starts  # one control cycle after it opened
    never = leg_starts(lambda: False, cfg)
    free = leg_starts(lambda: True, cfg)
    assert len(never) == len(free) == 2
    # the first correction's last leg waits the cap (1 s); the second is shifted by both
    assert never[0] - free[0] == pytest.approx(1.0, abs=0.05)
    assert never[1] - free[1] == pytest.approx(2.0, abs=0.1)
    asked: list[float] = []
    leg_starts(lambda: asked.append(clock.now()) or True, replace(cfg, arrive_at_expiration=False))
    assert asked == []


class _Offset:
    """EM 'tracker' reading the saved pose moved ``mm`` back along its own z axis (the
    bending section's axis: a translation error) at every measurement."""

    def __init__(self, saved: Array, mm: float) -> None:
        self.saved, self.mm = saved, mm

    def measure_tip2base(self, n_average: int = 1) -> Array:
        back = np.eye(4)
        back[2, 3] = -self.mm
        out: Array = self.saved @ back
        return out


def test_a_translation_step_beyond_the_release_threshold_sweeps_the_roll() -> None:
    """``release_translation_mm``: a correction that moves the translation by more than it
    re-approaches the roll through its backoff (the sweep that releases the shaft's axial
    stiction); a translation step below it leaves the roll alone."""
    clock, plant, robot, _ = em_bench(110)
    q0 = np.array([0.05, -0.05, 0.3, 2.0])
    saved = forward(q0)
    cfg = PoseStageConfig(max_iterations=1, reapproach_first=False, hold_s=0.1,
                          step_from_last=True, tolerance_mm=0.1, undo_if_worse=False,
                          release_translation_mm=0.3)  # fmt: skip
    roll: list[float] = []
    for mm, swept in ((1.5, True), (0.15, False)):
        robot.command_position(q0)
        clock.advance(0.5)
        roll.clear()
        res = pose_stage(robot, q0, saved, _Offset(saved, mm), config=cfg, sleep=clock.advance,
                         arrival_direction=(1, 1, -1, 1),
                         on_command=lambda q: roll.append(float(q[2])))  # fmt: skip
        assert abs(res.q_final[3] - q0[3]) > (0.3 if swept else 0.0)
        # (the roll's engaged direction is -1 here and its step does not reverse it)
        sweep = max(abs(r - q0[2]) for r in roll)
        assert bool(sweep > 0.8 * cfg.backoff[2]) is swept, (mm, sweep)
        off = replace(cfg, release_translation_mm=0.0)
        robot.command_position(q0)
        roll.clear()
        pose_stage(
            robot,
            q0,
            saved,
            _Offset(saved, mm),
            config=off,
            sleep=clock.advance,
            arrival_direction=(1, 1, -1, 1),
            on_command=lambda q: roll.append(float(q[2])),
        )
        assert max(abs(r - q0[2]) for r in roll) < 0.5 * cfg.backoff[2]
