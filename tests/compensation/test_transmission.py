"""Tests of icenav.compensation.transmission: the per-tendon capstan model, its identification from
two-knob motions, its stateful inverse, and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.compensation.hysteresis import HysteresisCompensator, JointHysteresis
from icenav.compensation.tracker_bias import TrackerBias
from icenav.compensation.transmission import (
    CalibrationMotion,
    PairTransmission,
    TendonCompensator,
    TendonTransmission,
    circle_path,
    g_minus,
    g_plus,
    identify_transmission,
    observed_knobs,
    record_motion,
    transmission_commands,
)
from icenav.errors import ConfigurationError, ShapeError, TrackerError
from icenav.geometry.kinematics import forward

DEG = math.pi / 180


def random_model(rng: np.random.Generator) -> TendonTransmission:
    def pair() -> PairTransmission:
        return PairTransmission(
            slack=rng.uniform(0.0, 2.0) * DEG,
            seal_play=rng.uniform(0.0, 1.5) * DEG,
            tension_play=rng.uniform(0.0, 0.5),
            coupling=rng.uniform(-0.8, 0.8),
        )

    return TendonTransmission(
        ap=pair(), rl=pair(), wrap=rng.uniform(0.1, 1.0), friction=rng.uniform(0.0, 0.8)
    )


def spin_like(a: float, n: int = 200) -> np.ndarray:
    t = np.linspace(0.0, 2.0 * math.pi, n)
    path = np.zeros((n + 20, 4))
    path[:20, 0] = np.linspace(0.0, a, 21)[1:]
    path[20:, 0] = a * np.cos(t)
    path[20:, 1] = a * np.sin(t)
    path[20:, 2] = -t
    return path


def test_capstan_factors_match_their_series_and_order() -> None:
    for x in (1e-7, 1e-3, 0.1, 0.5, 1.0):
        # g+(x) = x/2 + x^2/6 + ..., g-(x) = x/2 - x^2/6 + ...
        assert g_plus(x) == pytest.approx(x / 2 + x**2 / 6 + x**3 / 24, rel=0.05)
        assert g_minus(x) == pytest.approx(x / 2 - x**2 / 6 + x**3 / 24, rel=0.05)
        assert g_plus(x) >= g_minus(x) >= 0.0


def test_play_free_transmission_is_the_identity() -> None:
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.normal(0, 3 * DEG, (300, 2)), axis=0)
    z = TendonTransmission().simulate(x, x_start=[0.0, 0.0])
    np.testing.assert_allclose(z, x - 0.0, atol=1e-12)


def test_slack_alone_is_a_dead_zone() -> None:
    s = 3 * DEG
    m = TendonTransmission(ap=PairTransmission(slack=s), rl=PairTransmission(slack=2 * s))
    x = np.linspace(-30, 30, 241)[:, None] * DEG * np.ones((1, 2))
    z = m.simulate(x, x_start=[0.0, 0.0])
    for j, sj in ((0, s), (1, 2 * s)):
        ref = np.sign(x[:, j]) * np.maximum(np.abs(x[:, j]) - sj, 0.0)
        np.testing.assert_allclose(z[:, j], ref, atol=1e-12)


def test_seal_play_alone_is_a_backlash_of_that_half_width() -> None:
    w = 2 * DEG
    m = TendonTransmission(ap=PairTransmission(seal_play=w))
    up = np.linspace(0, 40, 81) * DEG
    down = np.linspace(40, -40, 161) * DEG
    x = np.zeros((up.size + down.size, 2))
    x[:, 0] = np.concatenate([up, down])
    z = m.simulate(x, x_start=[0.0, 0.0])[:, 0]
    # going up from rest the output lags by w; after the reversal it holds until x has come
    # back by 2 w, then lags by w on the other side
    np.testing.assert_allclose(z[40:81], x[40:81, 0] - w, atol=1e-12)
    for k in range(9):  # x from 40 down to 36 deg: inside the play, the output holds
        assert z[up.size + k] == pytest.approx(40 * DEG - w, abs=1e-12)
    k = up.size + 20  # x = 30 deg on the way down
    assert z[k] == pytest.approx(x[k, 0] + w, abs=1e-12)
    np.testing.assert_allclose(z[-40:], x[-40:, 0] + w, atol=1e-12)  # through zero as well


def test_play_of_one_knob_grows_with_the_other_knobs_bend() -> None:
    """The physics the per-knob model lacks: the capstan wrap (bend) and coupling tension."""
    m = TendonTransmission(
        rl=PairTransmission(seal_play=0.5 * DEG, tension_play=0.4, coupling=-0.5),
        ap=PairTransmission(seal_play=0.5 * DEG, tension_play=0.4, coupling=-0.5),
        wrap=0.5,
        friction=0.5,
    )

    def rl_loop_width(ap_bend: float) -> float:
        """Width (rad) of the RL loop at z2 = 10 deg: x2 going up minus x2 coming down."""
        up = np.linspace(0, 25, 251)
        x2 = np.concatenate([up, up[::-1], -up, -up[::-1]]) * DEG
        x = np.stack([np.full_like(x2, ap_bend), x2], axis=-1)
        z = m.simulate(x, x_start=[ap_bend, 0.0])[:, 1]
        n = up.size
        k_up = int(np.argmax(z[:n] >= 10 * DEG))
        k_down = n + int(np.argmax(z[n : 2 * n] <= 10 * DEG))
        return float(x2[k_up] - x2[k_down])

    widths = [rl_loop_width(b * DEG) for b in (0.0, 30.0, 60.0)]
    assert widths[0] < widths[1] < widths[2]


def test_observed_knobs_inverts_the_model_tip_position() -> None:
    rng = np.random.default_rng(2)
    q = np.zeros((400, 4))
    q[:, :2] = rng.uniform(-90, 90, (400, 2)) * DEG
    q[:5, :2] = [[0, 0], [1e-5, 0], [0, -1e-5], [90 * DEG, 90 * DEG], [-90 * DEG, 0]]
    t = forward(q)
    t[:, :3, :3] = np.eye(3)  # position only: the orientation must not matter
    np.testing.assert_allclose(observed_knobs(t), q[:, :2], atol=1e-7)


@pytest.mark.parametrize("seed", range(6))
def test_compensator_cancels_a_known_model(seed: int) -> None:
    rng = np.random.default_rng(10 + seed)
    m = random_model(rng)
    comp = TendonCompensator(m, dead_zone_ramp=0.5 * DEG)
    wanted = spin_like(rng.uniform(15, 65) * DEG)
    wanted[:, :2] += rng.normal(0, 0.3 * DEG, (wanted.shape[0], 2))  # reversals everywhere
    cmd = comp.command_path(wanted)
    z = m.simulate(cmd, x_start=[0.0, 0.0])
    err = np.abs(z - wanted[:, :2])
    outside = np.abs(wanted[:, :2]) >= 0.5 * DEG
    # the substep count of a step changes in whole numbers with its length, so the model is
    # piecewise continuous in the command and the root search can land on a jump (< 0.1 deg)
    assert np.max(err[outside]) < 0.1 * DEG
    assert np.sqrt(np.mean(err[outside] ** 2)) < 0.01 * DEG
    # inside the dead-zone ramp (|z*| < eps = 0.5 deg) the commands for +-eps are interpolated;
    # the other knob's coupling shifts them a little
    assert np.max(err) < 0.75 * DEG
    np.testing.assert_array_equal(cmd[:, 2:], wanted[:, 2:])  # no roll model: passes through
    # without compensation the same model misses by much more
    z_raw = m.simulate(wanted, x_start=[0.0, 0.0])
    assert np.max(np.abs(z_raw - wanted[:, :2])) > 5 * np.max(err[outside]) + 0.5 * DEG


def test_compensator_crosses_the_dead_zone_without_a_jump() -> None:
    m = TendonTransmission(ap=PairTransmission(slack=4 * DEG))
    comp = TendonCompensator(m, dead_zone_ramp=0.5 * DEG)
    zpath = np.zeros((161, 4))
    zpath[:, 0] = np.linspace(-4, 4, 161) * DEG
    cmd = comp.command_path(zpath)
    assert np.max(np.abs(np.diff(cmd[:, 0]))) < 1.0 * DEG  # a ramp, not an 8 deg jump
    assert cmd[-1, 0] == pytest.approx(8 * DEG, abs=1e-6)


def test_compensator_delegates_roll_to_the_per_joint_model() -> None:
    roll = HysteresisCompensator(
        [JointHysteresis(backlash=3 * DEG), None, JointHysteresis(backlash=2 * DEG), None]
    )
    comp = TendonCompensator(TendonTransmission(), roll=roll)
    assert comp.roll is not None and comp.roll.joints[0] is None  # knobs are the tendon model's
    path = np.zeros((30, 4))
    path[:, 2] = np.linspace(0.0, 20 * DEG, 30)
    cmd = comp.command_path(path)
    np.testing.assert_allclose(cmd[1:, 2], path[1:, 2] + 2 * DEG, atol=1e-12)
    np.testing.assert_allclose(cmd[:, :2], 0.0, atol=1e-9)


def synthetic_catheter(
    model: TendonTransmission, rng: np.random.Generator, path: np.ndarray, noise: float
) -> CalibrationMotion:
    """Tracked model knobs of a synthetic catheter: a known static map of the effective
    knobs (gain, cross-coupling, a cubic), plus tracker noise."""
    z = model.simulate(path, x_start=[0.0, 0.0])
    y = np.stack(
        [
            0.9 * z[:, 0] + 0.08 * z[:, 1] - 0.1 * z[:, 0] ** 3,
            -0.05 * z[:, 0] + 1.1 * z[:, 1] + 0.06 * z[:, 0] * z[:, 1],
        ],
        axis=-1,
    )
    y += rng.normal(0.0, noise, y.shape)
    y[rng.uniform(size=y.shape[0]) < 0.03] = np.nan  # MISSING samples
    return CalibrationMotion(q_motor=path, observed=y)


TRUTH = TendonTransmission(
    ap=PairTransmission(slack=1.5 * DEG, seal_play=0.8 * DEG, tension_play=0.3, coupling=-0.4),
    rl=PairTransmission(slack=2.5 * DEG, seal_play=0.5 * DEG, tension_play=0.5, coupling=0.3),
    wrap=0.4,
    friction=0.6,
)


def test_identification_recovers_a_known_synthetic_model() -> None:
    rng = np.random.default_rng(5)
    circles = circle_path((25 * DEG, 50 * DEG), step=4 * DEG)
    sweep = np.zeros((120, 4))
    sweep[:, 0] = 60 * DEG * np.sin(np.linspace(0, 4 * math.pi, 120))
    sweep[:, 1] = 40 * DEG * np.sin(np.linspace(0, 3 * math.pi, 120))
    motions = [
        synthetic_catheter(TRUTH, rng, circles, 0.05 * DEG),
        synthetic_catheter(TRUTH, rng, sweep, 0.05 * DEG),
    ]
    fit = identify_transmission(motions, degree=3, max_nfev=40)
    assert fit.rms < 0.15 * DEG < fit.rms_without_play
    assert fit.model.ap.slack == pytest.approx(TRUTH.ap.slack, abs=0.3 * DEG)
    assert fit.model.rl.slack == pytest.approx(TRUTH.rl.slack, abs=0.3 * DEG)
    # held-out two-knob motion: the identified model predicts the truth's effective knobs
    test = spin_like(40 * DEG)
    err = fit.model.simulate(test, x_start=[0.0, 0.0]) - TRUTH.simulate(test, x_start=[0.0, 0.0])
    assert float(np.sqrt(np.mean(err**2))) < 0.2 * DEG

    # in situ: the same catheter in a curved vessel, re-identified from circles alone with
    # the static map kept; it must predict the wider plays there
    curved = TRUTH.with_vessel(1.0)
    in_situ = identify_transmission(
        [synthetic_catheter(curved, rng, circles, 0.05 * DEG)],
        initial=fit.model,
        degree=3,
        static_coefficients=fit.static_coefficients,
        max_nfev=30,
    )
    truth_z = curved.simulate(test, x_start=[0.0, 0.0])
    err_situ = in_situ.model.simulate(test, x_start=[0.0, 0.0]) - truth_z
    err_straight = fit.model.simulate(test, x_start=[0.0, 0.0]) - truth_z
    assert np.sqrt(np.mean(err_situ**2)) < 0.3 * np.sqrt(np.mean(err_straight**2))
    with pytest.raises(ShapeError, match="static_coefficients"):
        identify_transmission(motions, degree=3, static_coefficients=np.zeros((3, 2)))


def test_vessel_wrap_widens_every_play() -> None:
    m = TRUTH.with_vessel(0.9)
    assert m.wrap == pytest.approx(TRUTH.wrap + TRUTH.friction * 0.9)
    x = spin_like(40 * DEG)
    zs, zc = TRUTH.simulate(x, x_start=[0, 0]), m.simulate(x, x_start=[0, 0])
    assert np.sqrt(np.mean((zc - x[:, :2]) ** 2)) > np.sqrt(np.mean((zs - x[:, :2]) ** 2))
    with pytest.raises(ConfigurationError, match="vessel_curvature"):
        TRUTH.with_vessel(-0.1)


def test_record_motion_reads_the_tracker_and_marks_missing() -> None:
    moves: list[np.ndarray] = []

    class Tracker:
        n = 0

        def measure_tip2base(self) -> np.ndarray | None:
            self.n += 1
            return None if self.n == 2 else forward(moves[-1])

    path = circle_path((20 * DEG,), step=5 * DEG)
    rec = record_motion(lambda q: moves.append(np.array(q)), Tracker(), path)
    assert np.isnan(rec.observed[1]).all()
    ok = np.isfinite(rec.observed[:, 0])
    np.testing.assert_allclose(rec.observed[ok], path[ok, :2], atol=1e-7)
    with pytest.raises(TrackerError, match="measure_tip2base"):
        record_motion(lambda q: None, object(), path)


def test_transmission_commands_compose_like_the_spin() -> None:
    class IdentityMap:
        def model_to_motor(self, q: np.ndarray, check: bool = False) -> np.ndarray:
            return np.array(q, dtype=np.float64)

    m = TendonTransmission(ap=PairTransmission(seal_play=2 * DEG), rl=PairTransmission(slack=DEG))
    q_model = spin_like(30 * DEG)[20:]
    cmd = transmission_commands(q_model, IdentityMap(), TendonCompensator(m))
    assert cmd.shape == (q_model.shape[0] + 20, 4)
    z = m.simulate(cmd, x_start=[0.0, 0.0])
    assert np.max(np.abs(z[20:] - q_model[:, :2])) < 0.5 * DEG  # savgol + dead-zone ramp only
    with pytest.raises(ConfigurationError, match="model_to_motor"):
        transmission_commands(q_model, object(), TendonCompensator(m))
    # a tracker bias shifts the model path first (icenav.compensation.tracker_bias); none changes
    # nothing
    same = transmission_commands(
        q_model, IdentityMap(), TendonCompensator(m), tracker_bias=TrackerBias.none()
    )
    np.testing.assert_allclose(same, cmd, atol=1e-9)
    bias = TrackerBias(np.array([1.0, -1.0, 0.0]), np.zeros((3, 3)))
    moved = transmission_commands(q_model, IdentityMap(), TendonCompensator(m), tracker_bias=bias)
    shifted = bias.shift_model_path(q_model)
    z = m.simulate(moved, x_start=[0.0, 0.0])
    assert np.max(np.abs(z[20:] - shifted[:, :2])) < 0.5 * DEG
    assert np.max(np.abs(shifted[:, :2] - q_model[:, :2])) > 0.5 * DEG


def test_bad_input_is_refused() -> None:
    with pytest.raises(ConfigurationError, match="slack"):
        PairTransmission(slack=-1 * DEG)
    with pytest.raises(ConfigurationError, match="coupling"):
        PairTransmission(coupling=3.0)
    with pytest.raises(ConfigurationError, match="friction"):
        TendonTransmission(friction=math.nan)
    with pytest.raises(ShapeError, match="10 values"):
        TendonTransmission.from_vector(np.zeros(9))
    with pytest.raises(ShapeError, match=r"\(n, 2\) or \(n, 4\)"):
        TendonTransmission().simulate(np.zeros((5, 3)))
    with pytest.raises(ShapeError, match="observed"):
        CalibrationMotion(q_motor=np.zeros((5, 4)), observed=np.zeros((4, 2)))
    with pytest.raises(ShapeError, match="tip2base"):
        observed_knobs(np.eye(4))
    with pytest.raises(ConfigurationError, match="radii"):
        circle_path((100 * DEG,))
    with pytest.raises(ConfigurationError, match="need >= 50"):
        identify_transmission(
            [CalibrationMotion(q_motor=np.zeros((20, 4)), observed=np.zeros((20, 2)))]
        )
    with pytest.raises(ConfigurationError, match="non-empty"):
        identify_transmission([])
    with pytest.raises(ShapeError, match="q_effective"):
        TendonCompensator(TendonTransmission()).command(np.zeros(3))
    with pytest.raises(ConfigurationError, match="TendonTransmission"):
        TendonCompensator("model")  # type: ignore[arg-type]


class SyntheticCatheter:
    """A catheter whose knobs reach the bending section through a known TendonTransmission
    and whose section bends by a known static map of the effective knobs; tracked exactly."""

    def __init__(self, model: TendonTransmission) -> None:
        self.model = model
        self.reset()

    def reset(self) -> None:
        self.x = [0.0, 0.0]
        self.d = self.model.relaxed_state([0.0, 0.0]).tolist()
        self.pose = forward(np.zeros(4))

    def move(self, q: np.ndarray) -> np.ndarray:
        self.d = self.model.step(self.d, self.x, [float(q[0]), float(q[1])])
        self.x = [float(q[0]), float(q[1])]
        z1, z2 = self.model.effective(self.d)
        bend = [0.9 * z1 + 0.06 * z2 - 0.08 * z1**3, -0.04 * z1 + 1.08 * z2, q[2], q[3]]
        self.pose = forward(np.array(bend), check=False)
        return self.pose

    def measure_tip2base(self) -> np.ndarray:
        return self.pose.copy()


def test_calibration_and_compensation_end_to_end_on_a_synthetic_catheter() -> None:
    from icenav.calibration.plans import calibrate_points, raster_grid
    from icenav.compensation.transmission import (
        TransmissionCalibration,
        build_transmission,
        calibrate_transmission,
        reidentify_in_situ,
    )

    cat = SyntheticCatheter(TRUTH)
    raster = raster_grid(step=30 * DEG)
    dense = calibrate_points(cat.move, cat, raster).calibration
    cat.reset()
    tcal = calibrate_transmission(
        cat.move,
        cat,
        dense,
        raster,
        radii=(30 * DEG, 60 * DEG),
        step=8 * DEG,
        degree=3,
        max_nfev=25,
        circles_in_map=False,  # (faster: F from the raster alone)
    )
    assert isinstance(tcal, TransmissionCalibration) and tcal.n_moves > 100
    assert tcal.fit.rms < 0.3 * tcal.fit.rms_without_play
    q_model = spin_like(40 * DEG)[20:]
    target = forward(q_model)
    errors = []
    for cmd in (
        np.vstack([np.linspace(np.zeros(4), q_model[0], 21)[1:], q_model]),  # uncompensated
        transmission_commands(q_model, tcal.effective_map, tcal.compensator),
    ):
        cat.reset()
        tips = np.array([cat.move(q)[:3, 3] for q in cmd])[20:]
        errors.append(float(np.sqrt(np.mean(np.sum((tips - target[:, :3, 3]) ** 2, -1)))))
    assert errors[1] < 1.0 < 4.0 < errors[0]  # mm
    # in situ with the same (straight) plays: the re-identified model predicts as well
    cat.reset()
    situ = reidentify_in_situ(
        cat.move, cat, tcal, radii=(30 * DEG, 60 * DEG), step=8 * DEG, max_nfev=15
    )
    assert situ.effective_map is tcal.effective_map
    assert situ.fit.rms < 2.0 * tcal.fit.rms + 0.1 * DEG
    with pytest.raises(ConfigurationError, match="not on the raster"):
        build_transmission(dense, raster + 0.1)
    with pytest.raises(ConfigurationError, match="TransmissionCalibration"):
        reidentify_in_situ(cat.move, cat, "calibration")  # type: ignore[arg-type]
