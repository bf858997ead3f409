"""Tests of icenav.compensation.tendon_map: the per-tendon compensation with state, against a
synthetic
catheter built from the same kind of transmission (tendons, roll play, distal twist play)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from icenav.calibration.plans import raster_grid
from icenav.compensation.bend_play import BendPlay, KnobPlanePlay
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.compensation.hysteresis import HysteresisCompensator, JointHysteresis
from icenav.compensation.section_length import SectionLength
from icenav.compensation.tendon_map import TendonKnobMap
from icenav.compensation.transmission import (
    PairTransmission,
    TendonCompensator,
    TendonTransmission,
    TransmissionCalibration,
    TransmissionFit,
)
from icenav.errors import ConfigurationError, NonFiniteError, ShapeError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, forward
from icenav.geometry.trajectories import spin_trajectory

DEG = math.pi / 180
TRUTH = TendonTransmission(
    ap=PairTransmission(slack=1.5 * DEG, seal_play=0.8 * DEG, tension_play=0.3, coupling=-0.4),
    rl=PairTransmission(slack=2.5 * DEG, seal_play=0.5 * DEG, tension_play=0.5, coupling=0.3),
    wrap=0.4,
    friction=0.6,
)
ROLL = JointHysteresis(backlash=1.5 * DEG)
ROLL_PER_BEND = 0.06
TWIST_PER_BEND = 0.1


def static(z: np.ndarray) -> np.ndarray:
    """Model knobs (..., 2) of the bend that effective knobs z (..., 2) give (rad)."""
    z1, z2 = z[..., 0], z[..., 1]
    return np.stack([0.9 * z1 + 0.06 * z2 - 0.08 * z1**3, -0.04 * z1 + 1.08 * z2], axis=-1)


def turned(pose: np.ndarray, t: float) -> np.ndarray:
    """The image frame of ``pose`` turned by t about its own z axis (the twin's T9b)."""
    c, s = math.cos(t), math.sin(t)
    out = pose.copy()
    out[:3, 0] = c * pose[:3, 0] + s * pose[:3, 1]
    out[:3, 1] = -s * pose[:3, 0] + c * pose[:3, 1]
    return out


class Catheter:
    """Motor -> tendons (TRUTH) -> static bend; motor roll -> play -> section -> twist play
    -> image; tracked exactly."""

    def __init__(self) -> None:
        self.x = [0.0, 0.0]
        self.d = TRUTH.relaxed_state([0.0, 0.0]).tolist()
        self.x3 = self.p3 = self.i = 0.0
        self.d4 = 0.0

    def move(self, q: np.ndarray) -> np.ndarray:
        self.d = TRUTH.step(self.d, self.x, [float(q[0]), float(q[1])])
        self.x = [float(q[0]), float(q[1])]
        k = static(np.array(TRUTH.effective(self.d)))
        bend = math.hypot(*k)
        w = ROLL.backlash + ROLL_PER_BEND * bend
        self.p3 = min(max(self.p3, float(q[2]) - w), float(q[2]) + w)
        h = TWIST_PER_BEND * bend
        self.i = min(max(self.i, self.p3 - h), self.p3 + h)
        self.d4 = float(q[3])
        return self.pose()

    def pose(self) -> np.ndarray:
        k = static(np.array(TRUTH.effective(self.d)))
        section = forward(np.array([k[0], k[1], self.p3, self.d4]), check=False)
        return turned(section, self.i - self.p3)


@pytest.fixture(scope="module")
def calibration() -> TransmissionCalibration:
    """The calibration a perfect identification of Catheter would give (F from exact data)."""
    raster = raster_grid(10 * DEG)
    k = static(raster[:, :2])
    poses = forward(np.column_stack([k, np.zeros((len(k), 2))]), check=False)
    fmap = ElasticityMap.build(
        CalibrationSet(q_motor=raster, tip2base=poses, method="synthetic"), smoothing=0.0
    )
    roll = HysteresisCompensator(
        [None, None, ROLL, None],
        roll_play_per_bend=ROLL_PER_BEND,
        twist_play_per_bend=TWIST_PER_BEND,
    )
    fit = TransmissionFit(
        model=TRUTH,
        rms=0.0,
        rms_without_play=0.0,
        static_coefficients=np.zeros((1, 2)),
        n_samples=0,
        n_evaluations=0,
        degree=0,
    )
    return TransmissionCalibration(
        fit=fit, effective_map=fmap, compensator=TendonCompensator(TRUTH, roll), n_moves=0
    )


def wander(rng: np.random.Generator, n: int = 240) -> np.ndarray:
    """A smooth random model path (n, 4) within +-45 deg (reachable with the plays), with
    reversals on every joint."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    f = rng.uniform(1.0, 3.0, (1, 4))
    ph = rng.uniform(0, 2 * math.pi, (1, 4))
    amp = np.array([[45 * DEG, 35 * DEG, 1.5, 5.0]])
    q = amp * np.sin(2 * math.pi * f * t + ph) * np.minimum(1.0, 5 * t)
    return q - q[0]


@pytest.mark.parametrize("seed", range(3))
def test_commands_put_the_catheter_where_the_model_says(
    calibration: TransmissionCalibration, seed: int
) -> None:
    """Streamed as the controller does (command, observe), the catheter's tip follows the
    model path through every reversal (tendon play, dead-zone, roll and twist play), and
    the map's own estimate of the model state agrees."""
    rng = np.random.default_rng(seed)
    path = wander(rng)
    cmap = TendonKnobMap(calibration)
    cat = Catheter()
    naive = Catheter()
    err, err_naive, err_est = [], [], []
    for q in path:
        cmd = cmap.model_to_motor(q)
        cmap.observe(cmd)
        pose = cat.move(cmd)
        want = forward(q, check=False)
        err.append(np.linalg.norm(pose[:3, 3] - want[:3, 3]))
        err_naive.append(np.linalg.norm(naive.move(q)[:3, 3] - want[:3, 3]))
        r = pose[:3, :3].T @ want[:3, :3]
        err_est.append(np.abs(cmap.motor_to_model(cmd)[:3] - q[:3]).max())
        assert math.acos(min(1.0, (np.trace(r) - 1) / 2)) < 1.0 * DEG
    assert max(err) < 0.6  # mm, along the whole path
    assert float(np.sqrt(np.mean(np.square(err_naive)))) > 4 * float(
        np.sqrt(np.mean(np.square(err)))
    )
    assert max(err_est) < 1.0 * DEG  # the dead-zone ramp (0.5 deg) and the maps


def test_asking_is_pure_and_a_path_is_the_stream(calibration: TransmissionCalibration) -> None:
    rng = np.random.default_rng(7)
    path = wander(rng, 80)
    cmap = TendonKnobMap(calibration)
    whole = cmap.model_to_motor(path)
    again = cmap.model_to_motor(path)  # the state was restored after the path
    np.testing.assert_array_equal(whole, again)
    for q, expected in zip(path, whole, strict=True):
        one = cmap.model_to_motor(q)
        np.testing.assert_array_equal(one, cmap.model_to_motor(q))  # asking changes nothing
        cmap.motor_to_model(one)
        np.testing.assert_allclose(one, expected, atol=1e-12)
        cmap.observe(one)


def test_a_reversal_jumps_the_roll_across_its_play(calibration: TransmissionCalibration) -> None:
    cmap = TendonKnobMap(calibration)
    bent = np.array([40 * DEG, 0.0, 0.0, 0.0])
    for q in np.linspace(np.zeros(4), bent + [0, 0, 0.5, 0], 30):
        cmap.observe(cmap.model_to_motor(q))
    up = cmap.model_to_motor(bent + [0, 0, 0.5 + 1e-3, 0])
    down = cmap.model_to_motor(bent + [0, 0, 0.5 - 1e-3, 0])
    bend = 40 * DEG
    play = 2 * (ROLL.backlash + ROLL_PER_BEND * bend) + 2 * TWIST_PER_BEND * bend
    assert up[2] - down[2] == pytest.approx(play, rel=0.15)


def test_the_roll_play_is_looked_up_by_the_bend_s_direction(
    calibration: TransmissionCalibration,
) -> None:
    """A roll play over the knob plane twice as wide along the RL knob as along the AP knob:
    the reversal jump at one bend is the AP law's bent by the AP knob and the RL law's bent
    by the RL knob (a law of the bend alone gives the AP one in both)."""
    ap, rl = BendPlay.linear(ROLL_PER_BEND), BendPlay.linear(2 * ROLL_PER_BEND)
    plane = KnobPlanePlay((0.0, math.pi / 2), (ap, rl))

    def jump(law: BendPlay | KnobPlanePlay, knobs: tuple[float, float]) -> float:
        roll = HysteresisCompensator([None, None, ROLL, None], roll_play=law)  # no twist
        cal = dataclasses.replace(calibration, compensator=TendonCompensator(TRUTH, roll))
        cmap = TendonKnobMap(cal)
        bent = np.array([knobs[0], knobs[1], 0.0, 0.0])
        for q in np.linspace(np.zeros(4), bent + [0, 0, 0.5, 0], 30):
            cmap.observe(cmap.model_to_motor(q))
        up = cmap.model_to_motor(bent + [0, 0, 0.5 + 1e-3, 0])
        down = cmap.model_to_motor(bent + [0, 0, 0.5 - 1e-3, 0])
        return float(up[2] - down[2])

    bend = 40 * DEG
    for knobs, k in (((bend, 0.0), ROLL_PER_BEND), ((0.0, bend), 2 * ROLL_PER_BEND)):
        play = 2 * (ROLL.backlash + k * bend)
        assert jump(plane, knobs) == pytest.approx(play, rel=0.05)
    assert jump(ap, (0.0, bend)) == pytest.approx(jump(ap, (bend, 0.0)), rel=0.05)


def test_observing_other_motions_keeps_the_state(calibration: TransmissionCalibration) -> None:
    """Motions the map did not command (knob jog) are followed through observe: afterwards it
    knows where the catheter is, and brings it back exactly."""
    rng = np.random.default_rng(3)
    cmap = TendonKnobMap(calibration)
    cat = Catheter()
    motor = np.cumsum(rng.normal(0, [3 * DEG, 3 * DEG, 0.05, 0.3], (150, 4)), axis=0)
    motor[:, :2] = np.clip(motor[:, :2], -60 * DEG, 60 * DEG)
    for q in motor:
        cmap.observe(q)
        pose = cat.move(q)
    estimate = forward(cmap.motor_to_model(motor[-1]), check=False)
    assert np.linalg.norm(estimate[:3, 3] - pose[:3, 3]) < 0.5
    target = np.array([30 * DEG, -20 * DEG, 0.4, 2.0])
    for q in np.linspace(cmap.motor_to_model(motor[-1]), target, 40):
        cmd = cmap.model_to_motor(q)
        cmap.observe(cmd)
        pose = cat.move(cmd)
    assert np.linalg.norm(pose[:3, 3] - forward(target)[:3, 3]) < 0.5


def test_bad_input_is_refused(calibration: TransmissionCalibration) -> None:
    cmap = TendonKnobMap(calibration)
    with pytest.raises(ConfigurationError, match="TransmissionCalibration"):
        TendonKnobMap("calibration")  # type: ignore[arg-type]
    with pytest.raises(ShapeError, match="q_model"):
        cmap.model_to_motor(np.zeros(3))
    with pytest.raises(ShapeError, match=r"q_motor must have shape \(4,\)"):
        cmap.observe(np.zeros((2, 4)))
    with pytest.raises(ShapeError, match=r"q_motor must have shape \(4,\)"):
        cmap.motor_to_model(np.zeros((2, 4)))
    with pytest.raises(NonFiniteError, match="q_motor must be finite"):
        cmap.observe([0.0, math.nan, 0.0, 0.0])


def test_a_longer_section_is_taken_by_the_translation(
    calibration: TransmissionCalibration,
) -> None:
    """With a section 4 % longer than the model's, the knobs are as before and the
    translation takes the axial excess at the model bend; asking back gives the model's d4."""
    longer = dataclasses.replace(calibration, section=SectionLength(scale=1.04))
    q = np.array([30 * DEG, -20 * DEG, 0.0, 2.0])
    plain = TendonKnobMap(calibration).model_to_motor(q)
    cmd = TendonKnobMap(longer).model_to_motor(q)
    bend = DEFAULT_GEOMETRY.knob_ratio * math.hypot(30 * DEG, 20 * DEG)
    excess = 0.04 * 60.0 * math.sin(bend) / bend
    assert np.allclose(cmd[:3], plain[:3])
    assert cmd[3] == pytest.approx(2.0 - excess)
    back = TendonKnobMap(longer).motor_to_model(cmd)
    assert back[3] == pytest.approx(2.0, abs=0.02)


def test_a_spin_with_plays_over_the_knob_plane_does_not_chatter(
    calibration: TransmissionCalibration,
) -> None:
    """A twist play twice as wide along the diagonal as along the knobs: in a one-way spin
    the roll command never reverses and the image lands on the wanted roll each sample
    (the command looks the plays up by the section's plane, as the state advances them;
    looked up by the image frame's, the image overshot and the command swung across the
    whole play every sample)."""
    narrow, wide = BendPlay.linear(TWIST_PER_BEND), BendPlay.linear(2 * TWIST_PER_BEND)
    twist = KnobPlanePlay((0.0, math.pi / 4, math.pi / 2, 3 * math.pi / 4), (narrow, wide) * 2)
    roll = HysteresisCompensator(
        [None, None, ROLL, None], roll_play=BendPlay.linear(ROLL_PER_BEND), twist_play=twist
    )
    cal = dataclasses.replace(calibration, compensator=TendonCompensator(TRUTH, roll))
    cmap = TendonKnobMap(cal)
    path = spin_trajectory([50 * DEG, 0.0, 0.0, 0.0], 180).q_model
    rolls = []
    for q in np.vstack([np.linspace(np.zeros(4), path[0], 20), path]):
        cmd = cmap.model_to_motor(q)
        cmap.observe(cmd)
        rolls.append(cmd[2])
        assert cmap.motor_to_model(cmd)[2] == pytest.approx(q[2], abs=0.2 * DEG)
    steps = np.diff(rolls[20:])
    assert np.all(steps <= 1e-9)  # the spin turns phi3 one way: so does the motor
