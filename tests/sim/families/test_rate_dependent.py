"""Rate- and time-dependent transmission: the reached pose depends on the motor speed, drifts
after a stop, reproducibly for a seed, on the plant's own or an injected clock (never wall
time)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from icenav.errors import ConfigurationError
from icenav.sim.families.rate_dependent import (
    DEFAULT_MOTOR_SPEED,
    DahlJoint,
    RateDependentPlant,
    RateParams,
)

Q = np.array([0.8, -0.3, 0.6, 0.0])


def test_the_reached_pose_depends_on_the_commanded_speed() -> None:
    fast = RateDependentPlant(seed=201, motor_speed=DEFAULT_MOTOR_SPEED, settle_s=0.0)
    slow = RateDependentPlant(
        seed=201, motor_speed=np.array(DEFAULT_MOTOR_SPEED) / 10.0, settle_s=0.0
    )
    a, b = fast.move(Q), slow.move(Q)
    assert np.linalg.norm(a[:3, 3] - b[:3, 3]) > 0.3
    assert slow.time == pytest.approx(10.0 * fast.time)
    # the slow move lags less: it ends nearer to where the plant settles
    settled = fast.wait(2.0)
    assert np.linalg.norm(b[:3, 3] - settled[:3, 3]) < np.linalg.norm(a[:3, 3] - settled[:3, 3])


def test_the_pose_drifts_after_a_stop_reproducibly() -> None:
    runs = []
    for _ in range(2):
        plant = RateDependentPlant(seed=202)
        plant.move(Q)
        runs.append([plant.wait(0.0), plant.wait(2.0), plant.wait(20.0), plant.wait(200.0)])
    np.testing.assert_array_equal(np.array(runs[0]), np.array(runs[1]))
    p = np.array([r[:3, 3] for r in runs[0]])
    drift = np.linalg.norm(p - p[0], axis=1)
    assert drift[1] > 0.1 and drift[2] > drift[1]
    # it settles: the last 200 s move it less than its first 22 s did
    assert np.linalg.norm(p[3] - p[2]) < drift[2]
    # the roll's wind-up relaxes between moves, to the part the friction keeps holding
    roll = RateDependentPlant(seed=202)
    roll.move([0.8, 0.0, 0.0, 0.0])
    roll.move([0.8, 0.0, 1.0, 0.0])
    before = 1.0 - roll.state.roll
    roll.wait(60.0)
    after = 1.0 - roll.state.roll
    assert 0.3 * before < after < 0.8 * before


def test_time_is_the_plants_own_never_the_wall_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    reference = RateDependentPlant(seed=203).move_along(np.linspace(np.zeros(4), Q, 5))

    def no_wall_clock() -> float:
        raise AssertionError("the plant read the wall clock")

    for name in ("monotonic", "time", "perf_counter"):
        monkeypatch.setattr(time, name, no_wall_clock)
    plant = RateDependentPlant(seed=203)
    np.testing.assert_array_equal(plant.move_along(np.linspace(np.zeros(4), Q, 5)), reference)
    # each move: the ramp at the motor speed, then the settle
    ramp = np.max(np.abs(Q / 5) / np.array(DEFAULT_MOTOR_SPEED))
    assert plant.time == pytest.approx(5 * (ramp + plant.settle_s))


def test_an_injected_clock_drives_the_drift() -> None:
    now = [100.0]
    plant = RateDependentPlant(seed=204, clock=lambda: now[0])
    plant.move(Q)
    ramp = float(np.max(np.abs(Q) / np.array(DEFAULT_MOTOR_SPEED)))
    assert plant.time == pytest.approx(100.0 + ramp)  # no settle: the clock holds it
    start = plant.state.tip2base.copy()
    np.testing.assert_array_equal(plant.state.tip2base, start)  # the clock stood still
    now[0] += 10.0
    later = plant.state.tip2base  # read after the clock moved: the plant held until then
    assert np.linalg.norm(later[:3, 3] - start[:3, 3]) > 0.1
    assert plant.time == pytest.approx(110.0)
    # the same as its own clock with the same hold
    own = RateDependentPlant(seed=204, settle_s=0.0)
    own.move(Q)
    np.testing.assert_allclose(own.wait(10.0 - ramp), later, atol=1e-12)


def test_steady_sliding_lags_by_the_friction_level_plus_the_viscous_term() -> None:
    """(R1)-(R3) at a constant input speed V: v -> V, zeta -> its balance of (R2)."""
    lam, tau_v, tau_rel, held, s, v_s = 0.3, 0.05, 20.0, 0.5, 0.3, 0.5
    joint = DahlJoint(lam, tau_v, tau_rel, held, s, v_s)
    joint.reset(0.0)
    speed, w_c, dt = 2.0, 0.2, 0.002
    x = 0.0
    for _ in range(5000):
        x += speed * dt
        out = joint.step(x, dt, w_c)
    w = w_c * (1.0 + s * math.exp(-((speed / v_s) ** 2)))
    # d zeta / dt = 0 in (R2), with the floor r_h w of (R2b)
    zeta = (speed / lam + held * w / tau_rel) / (speed / (lam * w) + 1.0 / tau_rel)
    assert joint.v == pytest.approx(speed, rel=1e-6)
    assert x - out == pytest.approx(zeta + tau_v * speed, rel=2e-3)


def test_parameters_are_checked() -> None:
    with pytest.raises(ConfigurationError, match="tendon_viscous_s"):
        RateParams(tendon_viscous_s=0.0)
    with pytest.raises(ConfigurationError, match="motor_speed"):
        RateDependentPlant(motor_speed=[1.0, 1.0, 0.0, 1.0])
    with pytest.raises(ConfigurationError, match="settle_s"):
        RateDependentPlant(settle_s=-1.0)
    with pytest.raises(ConfigurationError, match="seconds"):
        RateDependentPlant().wait(-1.0)
