"""Tests of icenav.compensation.transmission: the per-tendon capstan model, its stateful
inverse, and bad input (identification: tests/calibration/test_transmission.py)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from icenav.calibration.transmission import (
    CalibrationMotion,
    circle_path,
    identify_transmission,
    observed_knobs,
)
from icenav.compensation.hysteresis import HysteresisCompensator, JointHysteresis
from icenav.compensation.transmission import (
    COUPLING_FORMS,
    PairTransmission,
    TendonCompensator,
    TendonTransmission,
    g_minus,
    g_plus,
)
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import forward
from tests.support.transmission import TRUTH, spin_like

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


def test_vessel_wrap_widens_every_play() -> None:
    m = TRUTH.with_vessel(0.9)
    assert m.wrap == pytest.approx(TRUTH.wrap + TRUTH.friction * 0.9)
    x = spin_like(40 * DEG)
    zs, zc = TRUTH.simulate(x, x_start=[0, 0]), m.simulate(x, x_start=[0, 0])
    assert np.sqrt(np.mean((zc - x[:, :2]) ** 2)) > np.sqrt(np.mean((zs - x[:, :2]) ** 2))
    with pytest.raises(ConfigurationError, match="vessel_curvature"):
        TRUTH.with_vessel(-0.1)


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


def test_the_stretch_form_lets_the_other_pairs_bend_relieve_a_tendon() -> None:
    """(TR3s): a tendon's tension is its stretch, which the other pair's bend can shorten;
    (TR3) only ever adds to it. With no coupling the two forms are the same model."""

    def ap_lag(form: str, coupling: float, rl_bend: float) -> float:
        """Lag (rad) of z1 behind x1 halfway up a 0 -> 40 deg AP ramp, the RL knob held."""
        pair = PairTransmission(seal_play=0.5 * DEG, tension_play=0.5, coupling=coupling)
        m = TendonTransmission(ap=pair, rl=pair, wrap=0.5, friction=0.3, coupling_form=form)
        x1 = np.linspace(0, 40, 201) * DEG
        x = np.stack([x1, np.full_like(x1, rl_bend)], axis=-1)
        return float(x1[100] - m.simulate(x, x_start=[0.0, rl_bend])[100, 0])

    bend = -40 * DEG  # with coupling > 0 this RL bend shortens tendon A (sigma gamma z2 < 0)
    free = ap_lag("added", 0.0, bend)
    assert ap_lag("stretch", 0.0, bend) == pytest.approx(free, abs=1e-12)
    assert ap_lag("added", 0.6, bend) == pytest.approx(free, abs=1e-12)  # never relieved
    assert ap_lag("stretch", 0.6, bend) < 0.5 * free  # relieved down to its seal play
    # the other way round both forms add the same tension
    assert ap_lag("stretch", -0.6, bend) == pytest.approx(ap_lag("added", -0.6, bend))
    assert ap_lag("added", -0.6, bend) > 1.5 * free
    with pytest.raises(ConfigurationError, match="coupling_form"):
        TendonTransmission(coupling_form="mixed")


def backlash(x: np.ndarray, half_width: float) -> np.ndarray:
    """A play operator of half-width ``half_width`` (rad) along x (n,), from rest at x[0]."""
    p, out = float(x[0]), []
    for v in x:
        p = min(max(p, v - half_width), v + half_width)
        out.append(p)
    return np.array(out)


def test_two_play_elements_are_a_weighted_mean_of_two_backlashes() -> None:
    """(TR4b-c): with a tension-free band each tendon is a Prandtl-Ishlinskii operator of two
    elements, weights 1 - a and a, half-widths w and rho w; a = 0 is the one-element model."""
    w, a, rho = 2.0 * DEG, 0.4, 0.25
    one = TendonTransmission(ap=PairTransmission(seal_play=w))
    two = one.with_extension("two-play", [a, rho])
    assert two.state_size == 8 and two.form == "added+two-play"
    x = np.zeros((300, 2))
    x[:, 0] = 30 * DEG * np.sin(np.linspace(0.1, 6 * math.pi, 300)) + 30 * DEG  # tendon A pulled
    z = two.simulate(x, x_start=[0.0, 0.0])[:, 0]
    expected = (1 - a) * backlash(x[:, 0], w) + a * backlash(x[:, 0], rho * w)
    np.testing.assert_allclose(z[5:], expected[5:], atol=1e-12)
    np.testing.assert_array_equal(
        one.with_extension("two-play", [0.0, rho]).simulate(x), one.simulate(x)
    )
    with pytest.raises(ConfigurationError, match="second_weight"):
        TendonTransmission(second_weight=0.3)
    with pytest.raises(ShapeError, match="2 parameters"):
        one.with_extension("two-play", [0.3])


def test_bend_tension_widens_a_band_with_the_other_knobs_bend_without_coupling() -> None:
    """(TR3b): a share eta of the total bend loads every tendon, so AP's play grows when the
    RL knob bends the section even with no coupling (gamma = 0) and no capstan growth (mu = 0)."""
    pair = PairTransmission(seal_play=0.3 * DEG, tension_play=0.5)
    base = TendonTransmission(ap=pair, rl=pair, wrap=0.3, friction=0.0)  # no capstan growth
    loaded = base.with_extension("bend-tension", [0.5])

    def ap_loop(m: TendonTransmission, rl_bend: float) -> float:
        """Width (rad) of the z1 loop of a small AP sweep about 10 deg, RL held."""
        x1 = 10 * DEG + 3 * DEG * np.sin(np.linspace(0, 4 * math.pi, 241))
        x = np.stack([x1, np.full_like(x1, rl_bend)], axis=-1)
        z = m.simulate(x, x_start=[0.0, rl_bend])[120:, 0] - x1[120:]
        return float(np.max(z) - np.min(z))

    assert ap_loop(base, 50 * DEG) == pytest.approx(ap_loop(base, 0.0), rel=0.1)
    assert ap_loop(loaded, 50 * DEG) > 1.5 * ap_loop(loaded, 0.0)
    assert loaded.form == "added+bend-tension"


@pytest.mark.parametrize("extension", ["two-play", "bend-tension"])
def test_compensator_cancels_a_model_with_an_extension(extension: str) -> None:
    rng = np.random.default_rng(31)
    m = random_model(rng).with_extension(extension, [0.5, 0.2][: len(EXTRA[extension])])
    comp = TendonCompensator(m, dead_zone_ramp=0.5 * DEG)
    wanted = spin_like(50 * DEG, n=120)
    wanted[:, :2] += rng.normal(0, 0.3 * DEG, (wanted.shape[0], 2))
    cmd = comp.command_path(wanted)
    z = m.simulate(cmd, x_start=[0.0, 0.0])
    outside = np.all(np.abs(wanted[:, :2]) >= 0.5 * DEG, axis=1)
    assert np.max(np.abs(z - wanted[:, :2])[outside]) < 0.1 * DEG
    assert len(comp.state()[0]) == m.state_size


EXTRA = {"two-play": ("second_weight", "second_width"), "bend-tension": ("bend_tension",)}


@pytest.mark.parametrize("coupling_form", COUPLING_FORMS)
@pytest.mark.parametrize("extension", ["none", "bend-tension"])
def test_simulate_in_one_loop_equals_stepping_row_by_row(
    coupling_form: str, extension: str
) -> None:
    # simulate's one-loop path (4 pulls: the identification's hot loop) must be step +
    # effective, bit for bit, on random models (one without capstan friction: the inlined
    # small-exponent branch) along a random knob path
    rng = np.random.default_rng(17)
    for k in range(6):
        model = replace(random_model(rng), coupling_form=coupling_form)
        if k == 0:
            model = replace(model, wrap=0.0, friction=0.0)
        model = model.with_extension(extension, [rng.uniform(0.05, 0.5)] * (extension != "none"))
        assert model.state_size == 4
        path = np.clip(np.cumsum(rng.normal(0.0, 4.0 * DEG, (150, 2)), axis=0), -1.4, 1.4)
        got = model.simulate(path)
        d, prev, want = model.relaxed_state(path[0]).tolist(), path[0].tolist(), []
        for row in path.tolist():
            d = model.step(d, prev, row)
            prev = row
            want.append(model.effective(d))
        np.testing.assert_array_equal(got, np.array(want))
        assert np.ptp(got) > 0.1  # the path does bend the model
