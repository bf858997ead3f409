"""Tests of icenav.refinement.image_search: closed-loop, image-based view refinement."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from icenav.devices.sim_robot import IdealPlant, SimulatedRobot
from icenav.errors import ConfigurationError, ShapeError
from icenav.eval.metrics import beat_similarity, rotation_angle
from icenav.geometry.kinematics import forward
from icenav.recovery.beats import BeatClip
from icenav.refinement.image_search import (
    NeighbourhoodError,
    RefinementConfig,
    RefinementStatus,
    RefinementTask,
    refine,
)
from icenav.refinement.similarity import beat_score
from icenav.sim.anatomy import EXAMPLE_VIEWS, default_phantom
from icenav.sim.beat_imager import SimClock, SimulatedBeatImager
from icenav.sim.plant import CatheterPlant
from icenav.sim.ultrasound import ProbeConfig, UltrasoundRenderer
from tests.support.refinement import BlobImager, JitterBlobImager, TrackedPlant, reference

Array = NDArray[np.float64]
DEG = math.pi / 180
SESSION7 = dict(joints=(True, True, True, True), beats=1, significance=0.0, verify_end=False,
                noise_factor=1.5, search=True)  # fmt: skip
"""The session-7 search (every joint, one beat per measurement, no z-test, no verified end)."""


def test_never_leaves_its_neighbourhood_random_cases() -> None:
    """Many seeded random views, starts, settings and noisy landscapes on the hysteretic
    plant: every set-point sent stays in the box, within the evaluation budget."""
    for seed in range(30):
        rng = np.random.default_rng(seed)
        q_view = np.array(
            [
                rng.uniform(-0.6, 0.6),
                rng.uniform(-0.6, 0.6),
                rng.uniform(-2, 2),
                rng.uniform(-20, 20),
            ]
        )
        radius = np.array([*rng.uniform(0.5, 4.0, 3) * DEG, rng.uniform(0.3, 3.0)])
        step = radius * rng.uniform(0.2, 1.0, 4)
        cfg = RefinementConfig(
            radius=tuple(radius),
            initial_step=tuple(step),
            min_step=tuple(step / 16),
            overshoot=tuple(radius * rng.uniform(0.2, 3.0, 4)),
            max_evaluations=int(rng.integers(3, 25)),
            min_improvement=float(rng.uniform(0.0, 0.01)),
            stop_within=0.0,
            confirm=bool(rng.integers(0, 2)),
            joints=tuple(bool(x) for x in rng.permutation([1, *rng.integers(0, 2, 3)])),
            beats=int(rng.integers(1, 3)),
            significance=float(rng.choice([0.0, 2.0])),
            verify_end=bool(rng.integers(0, 2)),
            search=True,
        )
        plant = CatheterPlant(seed=100 + seed, vessel="moderate")
        robot = SimulatedRobot(plant)
        robot.enable()
        q_start = q_view + radius * rng.uniform(-1, 1, 4)
        plant.reset(q_start)
        robot.command_position(q_start)
        # the image optimum may lie outside the box: the search must stop at its wall
        q_best = q_view + radius * rng.uniform(-3, 3, 4)
        imager = BlobImager(robot, q_best, noise=float(rng.uniform(0.0, 0.2)), seed=seed)
        sent: list[Array] = []
        res = refine(
            robot,
            q_view,
            reference(imager),
            imager,
            arrival_direction=tuple(int(x) for x in rng.integers(-1, 2, 4)),
            config=cfg,
            on_command=sent.append,
        )
        assert sent, "the search moved"
        off = np.abs(np.array(sent) - q_view)
        assert np.all(off <= radius * (1 + 1e-9) + 1e-12), f"seed {seed}: left the box"
        assert np.all(res.max_offset <= radius * (1 + 1e-9) + 1e-12)
        assert np.all(np.abs(res.q_final - q_view) <= radius * (1 + 1e-9) + 1e-12)
        assert len(res.trials) <= cfg.max_evaluations
        assert imager.calls == len(res.trials)
        assert res.status in (
            RefinementStatus.CONVERGED,
            RefinementStatus.BUDGET,
            RefinementStatus.UNDONE,
        )
        # a joint not searched ends where it started (it only moves to take up its play)
        fixed = ~np.array(cfg.joints)
        np.testing.assert_allclose(res.q_final[fixed], q_start[fixed], atol=1e-12)
        # the robot ends at the incumbent
        np.testing.assert_allclose(robot.read_state().q, res.q_final)


def test_climbs_a_smooth_landscape_to_its_optimum() -> None:
    """Noise-free blob, ideal plant: the compass search finds the optimum inside the box."""
    robot = SimulatedRobot(IdealPlant())
    robot.enable()
    q_view = np.array([0.2, -0.1, 0.5, 3.0])
    q_best = q_view + np.array([1.5 * DEG, -1.0 * DEG, 0.5 * DEG, -0.75])
    robot.command_position(q_view)
    imager = BlobImager(robot, q_best, noise=0.0, seed=0)
    cfg = RefinementConfig(max_evaluations=200, min_improvement=0.0, stop_within=0.0, **SESSION7)
    res = refine(robot, q_view, reference(imager), imager, config=cfg)
    assert res.status == RefinementStatus.CONVERGED
    assert res.best_score > res.start_score
    err = np.abs(res.q_final - q_best)
    assert np.all(err <= np.array(cfg.min_step) * 2 + 1e-12)


@pytest.fixture(scope="module")
def renderer() -> UltrasoundRenderer:
    cfg = ProbeConfig(image_size=96, n_beams=48, n_samples=128, seed=7)
    return UltrasoundRenderer(default_phantom(), cfg)


def test_improves_similarity_on_a_perturbed_return(renderer: UltrasoundRenderer) -> None:
    """The return lands 2.5 deg off in phi1, phi2 and phi3 (the mitral view): the refinement
    (rendered ICE images, beating heart, respiration) raises the similarity of fresh beats
    to the saved beats and brings the true pose closer to the saved one."""
    clock = SimClock()
    plant = TrackedPlant()
    robot = SimulatedRobot(plant, clock=clock.now)  # type: ignore[arg-type]
    robot.enable()
    imager = SimulatedBeatImager(plant, renderer, clock.now, frames_per_beat=5)
    q_view = np.array(EXAMPLE_VIEWS["mitral_valve"])
    robot.command_position(q_view)
    saved = plant.state.tip2base.copy()
    refs = []
    for _ in range(4):
        clock.advance(imager.beat_duration_s)
        refs.append(imager.acquire_beat())
    judge = RefinementTask(q_view, refs, imager)  # scores fresh beats, never moves

    def fresh_score() -> float:
        values = []
        for _ in range(3):
            clock.advance(imager.beat_duration_s)
            values.append(judge.score(imager.acquire_beat()))
        return float(np.mean(values))

    robot.command_position(q_view + np.array([2.5 * DEG, -2.5 * DEG, 2.5 * DEG, 0.0]))
    start_pose = plant.state.tip2base.copy()
    before = fresh_score()
    cfg = RefinementConfig(max_evaluations=40, search=True)
    res = refine(robot, q_view, refs, imager, config=cfg, sleep=clock.advance)
    assert res.status in (RefinementStatus.CONVERGED, RefinementStatus.BUDGET)
    after = fresh_score()
    assert after > before + 0.01
    assert res.best_score > res.start_score + 0.01
    d0 = np.linalg.norm(start_pose[:3, 3] - saved[:3, 3])
    d1 = np.linalg.norm(plant.state.tip2base[:3, 3] - saved[:3, 3])
    a0 = rotation_angle(start_pose[:3, :3], saved[:3, :3])
    a1 = rotation_angle(plant.state.tip2base[:3, :3], saved[:3, :3])
    assert d1 < d0 and a1 < a0


def test_stays_put_when_already_at_the_view(renderer: UltrasoundRenderer) -> None:
    """A start that scores like consecutive beats of the saved view: no move at all."""
    clock = SimClock()
    plant = TrackedPlant()
    robot = SimulatedRobot(plant, clock=clock.now)  # type: ignore[arg-type]
    robot.enable()
    imager = SimulatedBeatImager(plant, renderer, clock.now, frames_per_beat=5)
    q_view = np.array(EXAMPLE_VIEWS["aortic_valve"])
    robot.command_position(q_view)
    refs = []
    for _ in range(3):
        clock.advance(imager.beat_duration_s)
        refs.append(imager.acquire_beat())
    clock.advance(3.3)
    sent: list[Array] = []
    res = refine(robot, q_view, refs, imager, sleep=clock.advance, on_command=sent.append)
    assert res.status == RefinementStatus.AT_VIEW
    # it only held still while it measured
    assert all(np.array_equal(q, q_view) for q in sent) and res.n_commands == 0
    assert len(res.trials) <= 2


def _blob_setup(seed: int = 0) -> tuple[SimulatedRobot, BlobImager, Array]:
    robot = SimulatedRobot(IdealPlant())
    robot.enable()
    q_view = np.array([0.1, 0.1, 0.0, 0.0])
    robot.command_position(q_view)
    imager = BlobImager(robot, q_view + np.array([2 * DEG, 0, 0, 1.0]), noise=0.0, seed=seed)
    return robot, imager, q_view


def test_abort_stops_at_once() -> None:
    robot, imager, q_view = _blob_setup()
    polls = []

    def abort() -> bool:
        polls.append(1)
        return len(polls) > 120

    sent: list[Array] = []
    cfg = RefinementConfig(stop_within=0.0, max_evaluations=100, search=True)
    res = refine(robot, q_view, reference(imager), imager, config=cfg, abort=abort,
                 on_command=sent.append)  # fmt: skip
    assert res.status == RefinementStatus.ABORTED
    assert len(sent) <= 120
    np.testing.assert_allclose(res.q_final, robot.read_state().q)


def test_timeout_ends_at_the_incumbent_within_the_box() -> None:
    robot, imager, q_view = _blob_setup()
    cfg = RefinementConfig(stop_within=0.0, max_evaluations=100, max_duration_s=3.0, **SESSION7)
    res = refine(robot, q_view, reference(imager), imager, config=cfg)
    assert res.status == RefinementStatus.TIMEOUT
    assert res.duration_s < 3.0 + 2.0  # the final move to the incumbent is short
    np.testing.assert_allclose(robot.read_state().q, res.q_final)
    assert np.all(np.abs(res.q_final - q_view) <= np.array(cfg.radius) + 1e-12)


def test_task_protocol_and_progress() -> None:
    robot, imager, q_view = _blob_setup()
    task = RefinementTask(
        q_view, reference(imager), imager, config=RefinementConfig(max_evaluations=5, **SESSION7)
    )
    assert task.progress == 0.0
    n = 0
    while (q := task.next_command(robot.read_state().q, 0.01)) is not None:
        robot.command_position(q)
        n += 1
        assert 0.0 <= task.progress <= 1.0
    assert n > 0 and task.progress == 1.0
    assert task.next_command(robot.read_state().q, 0.01) is None
    assert task.result().status == RefinementStatus.BUDGET
    assert len(task.result().trials) == 5


def test_start_outside_the_neighbourhood_is_refused() -> None:
    robot, imager, q_view = _blob_setup()
    with pytest.raises(NeighbourhoodError, match="outside the refinement radius"):
        RefinementTask(q_view, reference(imager), imager, q_start=q_view + [0, 0, 0, 5.0])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"initial_step": (0.1, 0.01, 0.01, 0.5)}, "initial_step"),
        ({"max_evaluations": 0}, "max_evaluations"),
        ({"radius": (0.05, 0.05, 0.05, -1.0)}, "radius"),
        ({"max_duration_s": 0.0}, "max_duration_s"),
        ({"min_improvement": -0.1}, "min_improvement"),
        ({"blur_factor": 0}, "blur_factor"),
        ({"beats": 0}, "beats"),
        ({"joints": (False, False, False, False)}, "joints"),
        ({"significance": -1.0}, "significance"),
    ],
)
def test_bad_config_is_rejected(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        RefinementConfig(**kwargs)  # type: ignore[arg-type]


def test_bad_inputs_are_rejected() -> None:
    robot, imager, q_view = _blob_setup()
    with pytest.raises(ConfigurationError, match="arrival_direction"):
        RefinementTask(q_view, reference(imager), imager, arrival_direction=(2, 0, 0, 0))
    with pytest.raises(ShapeError, match="phases"):
        BeatClip(np.zeros((3, 8, 8)), np.zeros(2))
    with pytest.raises(ShapeError, match="mask"):
        BeatClip(np.zeros((3, 8, 8)), np.zeros(3), mask=np.ones((4, 4), bool))
    task = RefinementTask(q_view, reference(imager), imager)
    with pytest.raises(ShapeError, match="differ"):
        task.score(BeatClip(np.zeros((3, 8, 8)), np.zeros(3)))


def test_beat_score_matches_the_metrics_blurred_similarity(renderer: UltrasoundRenderer) -> None:
    """An independent reference: eval.metrics.beat_similarity(blurred=True) uses sigma 4,
    factor 4; beat_score with the same blur gives the same number."""
    pose = forward(np.array(EXAMPLE_VIEWS["mitral_valve"]))
    from icenav.sim.anatomy import BASE2ANATOMY

    imager = SimulatedBeatImager(TrackedPlant(), renderer, lambda: 0.0, frames_per_beat=4)
    a = imager.clip_at(BASE2ANATOMY @ pose, 0.0)
    b = imager.clip_at(BASE2ANATOMY @ pose @ _rot_z(0.05), 2.1)
    ref = beat_similarity(list(b.images), b.phases, list(a.images), a.phases, mask=a.mask,
                          blurred=True)  # fmt: skip
    assert beat_score(b, a, sigma_px=4.0, factor=4) == pytest.approx(ref, abs=1e-9)
    assert beat_score(a, a) == pytest.approx(1.0)


def _rot_z(a: float) -> Array:
    t = np.eye(4)
    t[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return t


def test_ecg_gated_beats_lie_in_the_last_beat_at_exact_phases(
    renderer: UltrasoundRenderer,
) -> None:
    """Retrospective gating: frames at phases k / n, all within [now - beat, now), so the
    beat was recorded while the catheter was held still for one beat."""
    for now in (12.345, 0.9, 100.0):
        clock = SimClock(now)
        imager = SimulatedBeatImager(TrackedPlant(), renderer, clock.now, frames_per_beat=4)
        beat = imager.beat_duration_s
        assert beat == pytest.approx(60.0 / renderer.phantom.motion.heart_rate_bpm)
        times = imager.frame_times(now)
        assert np.all(times >= now - beat - 1e-9) and np.all(times < now)
        phases = [renderer.phantom.cardiac_phase(float(t)) for t in times]
        d = np.abs(np.mod(np.array(phases) - [0, 0.25, 0.5, 0.75] + 0.5, 1.0) - 0.5)
        assert np.all(d < 1e-9)
        clip = imager.acquire_beat()
        assert len(clip.frames) == 4 and clip.images.shape[0] == 4


def test_thresholds_follow_the_noise_of_the_saved_beats() -> None:
    """min_improvement and stop_within are at least noise_factor times the standard
    deviation of the saved beats' scores against each other (fixed with noise_factor 0 or
    fewer than three saved beats); started at the optimum on beats that decorrelate, the
    noise-aware search wanders off less than the fixed threshold lets it."""
    robot, _, q_view = _blob_setup()
    imager = JitterBlobImager(robot, q_view.copy(), noise=0.0, seed=1)
    refs = imager.saved_beats(4)
    task = RefinementTask(q_view, refs, imager, config=RefinementConfig(**SESSION7))
    assert math.isfinite(task.noise) and task.noise > 0.0
    assert task.min_improvement == pytest.approx(max(0.003, 1.5 * task.noise))
    assert task.min_improvement > 0.003
    assert task.stop_within == pytest.approx(max(0.01, 1.5 * task.noise))
    fixed = RefinementTask(
        q_view, refs, imager, config=RefinementConfig(**{**SESSION7, "noise_factor": 0.0})
    )
    assert (fixed.min_improvement, fixed.stop_within) == (0.003, 0.01)
    two = RefinementTask(q_view, refs[:2], imager)
    assert math.isnan(two.noise) and two.min_improvement == 0.003
    scale = np.array([DEG, DEG, DEG, 1.0])
    drift = {}
    for factor in (0.0, 1.5):
        d = []
        for seed in range(6):
            robot, _, q_view = _blob_setup(seed)
            imager = JitterBlobImager(robot, q_view.copy(), noise=0.0, seed=seed)
            cfg = RefinementConfig(
                **{**SESSION7, "noise_factor": factor}, stop_within=0.0, max_evaluations=16
            )
            res = refine(robot, q_view, imager.saved_beats(4), imager, config=cfg)
            d.append(float(np.linalg.norm((res.q_final - q_view) / scale)))
        drift[factor] = float(np.mean(d))
    assert drift[1.5] < 0.5 * drift[0.0]


class _LuckyImager(BlobImager):
    """A flat landscape (the blob at the view wherever the catheter is) whose beats are
    noisy except the ones numbered in ``lucky`` (0-based), which match the saved beat."""

    def __init__(self, robot: SimulatedRobot, q_view: Array, lucky: set[int]) -> None:
        super().__init__(robot, q_view, noise=0.3, seed=3)
        self.lucky = lucky

    def acquire_beat(self) -> BeatClip:
        k = self.calls
        self.calls += 1
        base = self.image_at(self.q_best)
        sd = 0.0 if k in self.lucky else self.noise
        imgs = np.stack([base + self.rng.normal(0, sd, base.shape) for _ in range(3)])
        return BeatClip(imgs, np.array([0.0, 1 / 3, 2 / 3]))


def test_verify_end_goes_back_to_the_start_when_fresh_beats_do_not_confirm() -> None:
    """A trial accepted on lucky beats (a flat landscape: nothing to gain) is measured again
    with fresh beats at the end; they do not beat the start's, so the stage goes back to
    the start (UNDONE); without ``verify_end`` it would stay at the lucky state."""
    ends = {}
    for verify in (False, True):
        robot, _, q_view = _blob_setup()
        imager = _LuckyImager(robot, q_view, lucky={2, 3})  # the first trial and its confirm
        cfg = RefinementConfig(stop_within=0.0, max_evaluations=8, beats=1, verify_end=verify,
                               significance=2.0, search=True)  # fmt: skip
        res = refine(robot, q_view, reference(imager), imager, config=cfg)
        assert res.trials[1].accepted is False and res.trials[2].accepted is True
        ends[verify] = res
        np.testing.assert_allclose(robot.read_state().q, res.q_final)
    assert not np.array_equal(ends[False].q_final, q_view)
    assert ends[True].status == RefinementStatus.UNDONE
    np.testing.assert_allclose(ends[True].q_final, q_view)
    assert ends[True].best_score == ends[True].start_score


def test_joints_beats_and_verify_keep_a_real_gain() -> None:
    """Noise-free blob 2 deg off in phi1 and 1 mm in d4, translation not searched, two beats
    per measurement, the end verified: the search moves phi1 towards the optimum, never d4,
    keeps its end (the fresh beats confirm it) and measures in pairs of beats."""
    robot, imager, q_view = _blob_setup()
    cfg = RefinementConfig(stop_within=0.0, max_evaluations=40, max_duration_s=200.0,
                           joints=(True, True, True, False), beats=2, significance=2.0,
                           verify_end=True, search=True)  # fmt: skip
    sent: list[Array] = []
    res = refine(robot, q_view, reference(imager), imager, config=cfg, on_command=sent.append)
    assert res.status in (RefinementStatus.CONVERGED, RefinementStatus.BUDGET)
    assert np.all(np.array(sent)[:, 3] == q_view[3])
    assert abs(res.q_final[0] - imager.q_best[0]) < 0.5 * DEG
    assert res.best_score > res.start_score
    assert imager.calls == len(res.trials) and len(res.trials) % 2 == 0


def test_a_good_start_on_decorrelating_beats_is_left_alone() -> None:
    """At the optimum, the saved beats alike but the live beats decorrelating (the blob
    jitters 0.2 deg / mm between saved beats, 1.2 between live ones): the default stage
    learns the noise per beat from its start's beats and does not search (AT_VIEW, no
    move) in any seed, where the session-7 search, trusting the saved beats' scatter,
    moves in most."""
    moved = {}
    for name, extra in (("default", {}), ("session7", SESSION7)):
        n = 0
        for seed in range(8):
            robot, _, q_view = _blob_setup(seed)
            imager = JitterBlobImager(robot, q_view.copy(), noise=0.0, seed=seed)
            imager.jitter = 0.2
            refs = imager.saved_beats(4)
            imager.jitter = 1.2
            cfg = RefinementConfig(max_evaluations=12, **extra)  # type: ignore[arg-type]
            res = refine(robot, q_view, refs, imager, config=cfg)
            if name == "default":
                assert res.status == RefinementStatus.AT_VIEW and res.n_commands == 0
            n += res.n_commands > 0
        moved[name] = n
    assert moved["default"] == 0 and moved["session7"] >= 4


def test_by_default_it_reports_a_lost_view_and_never_moves() -> None:
    """The default stage (``search`` off) measures the start: 2 deg and 1 mm off the
    optimum it reports LOST, at the optimum AT_VIEW; it holds still either way."""
    for off, status in ((np.array([2 * DEG, 0, 0, 1.0]), RefinementStatus.LOST),
                        (np.zeros(4), RefinementStatus.AT_VIEW)):  # fmt: skip
        robot, _, q_view = _blob_setup()
        imager = JitterBlobImager(robot, q_view + off, noise=0.0, seed=2)
        imager.jitter = 0.2
        sent: list[Array] = []
        res = refine(robot, q_view, imager.saved_beats(4), imager, on_command=sent.append)
        assert res.status == status
        # it only held still while it measured
        assert res.n_commands == 0 and all(np.array_equal(q, q_view) for q in sent)
        np.testing.assert_array_equal(res.q_final, q_view)
