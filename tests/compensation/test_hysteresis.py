"""Tests of icenav.compensation.hysteresis: the backlash + dead-zone model and its inverse
(identification: tests/calibration/test_hysteresis.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.calibration.hysteresis import sweep_path
from icenav.compensation.bend_play import BendPlay, KnobPlanePlay
from icenav.compensation.hysteresis import HysteresisCompensator, JointHysteresis
from icenav.errors import ConfigurationError

DEG = math.pi / 180


def play_reference(x: np.ndarray, r: float, p0: float, r1: float = 0.0) -> np.ndarray:
    """Independent backlash reference: the output moves only when the input drags it."""
    out = []
    p = p0
    for xi in x:
        w = r + r1 * abs(xi)
        if xi - p > w:
            p = xi - w
        elif p - xi > w:
            p = xi + w
        out.append(p)
    return np.array(out)


def test_model_matches_an_independent_backlash_and_dead_zone() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        r, d, c = rng.uniform(0, 5) * DEG, rng.uniform(0, 5) * DEG, rng.uniform(-1, 1) * DEG
        r1 = rng.uniform(0, 0.2)
        m = JointHysteresis(backlash=r, backlash_slope=r1, dead_zone=d, centre=c)
        x = np.cumsum(rng.normal(0, 2 * DEG, 300))
        z = m.simulate(x, p0=0.0)
        p = play_reference(x, r, 0.0, r1)
        u = p - c
        ref = np.where(np.abs(u) > d, u - np.sign(u) * d, 0.0)
        assert np.allclose(z, ref, atol=1e-12)


def test_loop_width_is_twice_the_backlash() -> None:
    m = JointHysteresis(backlash=3 * DEG)
    x = sweep_path(40 * DEG, 0.5 * DEG)
    z = m.simulate(x, p0=0.0)
    # at the same input on the way up and on the way down the outputs differ by 2 r
    up = (np.diff(x, prepend=x[0]) > 0) & (np.abs(x - 10 * DEG) < 1e-9)
    down = (np.diff(x, prepend=x[0]) < 0) & (np.abs(x - 10 * DEG) < 1e-9)
    assert np.allclose(z[down].min() - z[up].max(), 6 * DEG)  # lags behind: up x-r, down x+r


def test_compensator_cancels_the_model() -> None:
    rng = np.random.default_rng(1)
    for _ in range(10):
        m = JointHysteresis(
            backlash=rng.uniform(0.5, 5) * DEG,
            backlash_slope=rng.uniform(0.0, 0.2),
            dead_zone=rng.uniform(0.5, 5) * DEG,
            centre=rng.uniform(-1, 1) * DEG,
            smoothing=0.2 * DEG,
        )
        comp = HysteresisCompensator([m, m, None, None])
        t = np.linspace(0, 4 * math.pi, 800)
        want = np.zeros((t.size, 4))
        want[:, 0] = 50 * DEG * np.sin(t) + 5 * DEG
        want[:, 1] = 30 * DEG * np.cos(1.5 * t)
        want[:, 2] = -t
        comp.reset(want[0], direction=[1, -1, 0, 0])
        # the plant's play must start where the compensator thinks it is
        cmd = comp.command_path(want)
        p0 = [float(m.dead_zone_inverse(want[0, j])) for j in (0, 1)]
        got = np.stack([m.simulate(cmd[:, j], p0=p0[j]) for j in (0, 1)], -1)
        far = np.all(np.abs(want[:, :2]) >= m.smoothing, axis=1)
        assert np.max(np.abs(got[far] - want[far, :2])) < 1e-9
        # near the cross-over the smoothed dead-zone inverse leaves less than eps
        assert np.max(np.abs(got - want[:, :2])) < m.smoothing
        assert np.array_equal(cmd[:, 2:], want[:, 2:])
    # the state is the direction of motion
    assert comp.direction.tolist()[:2] in ([1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0])


@pytest.mark.parametrize("seed", range(6))
def test_reversal_threshold_bounds_the_error_and_ignores_wiggles(seed: int) -> None:
    """With a reversal threshold delta the compensated play output stays within delta (+ the
    dead-zone ramp) of the wanted one, and a wiggle smaller than delta on a still target
    makes no jump across the play (the exact inverse jumps 2 r on each)."""
    rng = np.random.default_rng(seed)
    m = JointHysteresis(
        backlash=rng.uniform(1, 5) * DEG,
        backlash_slope=rng.uniform(0.0, 0.1),
        dead_zone=rng.uniform(0.5, 3) * DEG,
        smoothing=0.2 * DEG,
    )
    delta = rng.uniform(0.3, 2.0) * DEG
    t = np.linspace(0, 4 * math.pi, 600)
    want = np.zeros((t.size, 4))
    want[:, 0] = 40 * DEG * np.sin(t) + 10 * DEG
    want[:, 0] += rng.uniform(-0.2 * delta, 0.2 * delta, t.size)  # jitter well below delta
    exact = HysteresisCompensator([m, None, None, None])
    shaped = exact.with_reversal_threshold(delta)
    results = []
    for comp in (exact, shaped):
        comp.reset(want[0], direction=[1, 0, 0, 0])
        cmd, dirs = [], []
        for row in want:
            cmd.append(comp.command(row)[0])
            dirs.append(comp.direction[0])
        got = m.simulate(np.array(cmd), p0=float(m.dead_zone_inverse(want[0, 0])))
        flips = int(np.sum(np.diff(dirs) != 0))  # each flip jumps the command across the play
        results.append((np.max(np.abs(got - want[:, 0])), flips))
    (err_exact, jumps_exact), (err_shaped, jumps_shaped) = results
    assert err_exact < m.smoothing
    assert err_shaped < delta + m.smoothing + 1e-9
    # the sine reverses 4 times; the exact inverse also flips on the jitter
    assert jumps_shaped == 4 < jumps_exact


def test_reversal_threshold_is_validated() -> None:
    with pytest.raises(ConfigurationError, match="reversal_threshold"):
        HysteresisCompensator([None] * 4, reversal_threshold=-0.1)
    with pytest.raises(ConfigurationError, match="reversal_threshold"):
        HysteresisCompensator([None] * 4, reversal_threshold=math.nan)


def test_without_compensation_the_error_is_the_backlash() -> None:
    m = JointHysteresis(backlash=3 * DEG)
    x = 40 * DEG * np.sin(np.linspace(0, 4 * math.pi, 400))
    z = m.simulate(x, p0=0.0)
    assert np.max(np.abs(z - x)) == pytest.approx(3 * DEG, rel=1e-6)


def test_effective_path_matches_simulate() -> None:
    m = JointHysteresis(backlash=2 * DEG, dead_zone=1 * DEG)
    comp = HysteresisCompensator([m, None, m, None])
    x = np.zeros((100, 4))
    x[:, 0] = np.linspace(0, 1, 100)
    x[:, 2] = np.linspace(0, -1, 100)
    eff = comp.effective_path(x)
    assert np.allclose(eff[:, 0], m.simulate(x[:, 0]))
    assert np.allclose(eff[:, 2], m.simulate(x[:, 2]))
    assert np.array_equal(eff[:, 1], x[:, 1])


def test_bad_parameters_are_rejected() -> None:
    with pytest.raises(ConfigurationError, match=r"backlash must be in \[0, .*\] rad"):
        JointHysteresis(backlash=-0.1)
    with pytest.raises(ConfigurationError, match="dead_zone must be"):
        JointHysteresis(dead_zone=float("nan"))
    with pytest.raises(ConfigurationError, match=r"backlash_slope must be in \[0, 0.5\]"):
        JointHysteresis(backlash_slope=0.7)
    with pytest.raises(ConfigurationError, match="smoothing must be finite and > 0"):
        JointHysteresis(smoothing=0.0)
    with pytest.raises(ConfigurationError, match="4 entries"):
        HysteresisCompensator([None, None])


def test_compensator_cancels_play_that_grows_with_the_bend() -> None:
    knob = JointHysteresis(backlash=1 * DEG, backlash_slope=0.05, smoothing=0.2 * DEG)
    roll = JointHysteresis(backlash=0.5 * DEG)
    comp = HysteresisCompensator(
        [knob, knob, roll, None], roll_play_per_bend=0.08, knob_play_per_bend=0.03
    )
    t = np.linspace(0, 2 * math.pi, 361)
    want = np.stack([0.8 * np.cos(t), 0.8 * np.sin(t), -t, np.zeros_like(t)], axis=-1)
    approach = np.linspace(np.zeros(4), want[0], 21)[1:]
    path = np.vstack([approach, want])
    comp.reset(np.zeros(4))
    cmd = comp.command_path(path)  # bend from the effective knobs: hypot(phi1, phi2)
    # an independent simulation of the same transmission, driven by the commands
    got = np.zeros_like(path)
    p = [0.0, 0.0, 0.0]
    for i, x in enumerate(cmd):
        z = path[i]
        widths = [
            knob.backlash + knob.backlash_slope * abs(x[0]) + 0.03 * abs(z[1]),
            knob.backlash + knob.backlash_slope * abs(x[1]) + 0.03 * abs(z[0]),
            roll.backlash + 0.08 * math.hypot(z[0], z[1]),
        ]
        for j in range(3):
            p[j] = min(max(p[j], x[j] - widths[j]), x[j] + widths[j])
        got[i, :3] = p
    spin = slice(20, None)
    assert np.max(np.abs(got[spin, 2] - want[:, 2])) < 1e-9  # the roll follows exactly
    far = np.all(np.abs(want[:, :2]) > knob.smoothing, axis=1)
    assert np.max(np.abs(got[spin, :2][far] - want[far, :2])) < 1e-9
    # without compensation the roll lags by its play
    lag = HysteresisCompensator([None] * 4).effective_path(path)
    assert np.allclose(lag, path)
    with pytest.raises(ConfigurationError, match="roll_play_per_bend must be in"):
        HysteresisCompensator([None] * 4, roll_play_per_bend=-1.0)
    with pytest.raises(ConfigurationError, match="bends must have 381 values"):
        comp.command_path(path, bends=np.zeros(3))


def test_a_roll_play_over_the_knob_plane_is_looked_up_by_the_bend_s_direction() -> None:
    """A roll play twice as wide bent by the RL knob as by the AP knob (a play growing with
    the total tendon tension): the compensator cancels it along a spin, whose bend goes
    round the knob plane; the AP law alone leaves the difference."""
    roll = JointHysteresis(backlash=0.5 * DEG)
    plane = KnobPlanePlay(
        (0.0, math.pi / 2), (BendPlay("power", (0.05, 2.0)), BendPlay("power", (0.10, 2.0)))
    )
    t = np.linspace(0, 2 * math.pi, 361)
    want = np.stack([0.9 * np.cos(t), 0.9 * np.sin(t), -t, np.zeros_like(t)], axis=-1)
    path = np.vstack([np.linspace(np.zeros(4), want[0], 21)[1:], want])

    def roll_reached(comp: HysteresisCompensator) -> np.ndarray:
        comp.reset(np.zeros(4))
        cmd = comp.command_path(path)
        p, out = 0.0, []
        for x, z in zip(cmd, path, strict=True):  # the plant: its play by the direction
            w = roll.backlash + plane.at(math.hypot(z[0], z[1]), math.atan2(z[1], z[0]))
            p = min(max(p, x[2] - w), x[2] + w)
            out.append(p)
        return np.array(out[20:])

    ours = HysteresisCompensator([None, None, roll, None], roll_play=plane)
    assert np.max(np.abs(roll_reached(ours) - want[:, 2])) < 1e-9
    ap_only = HysteresisCompensator([None, None, roll, None], roll_play=plane.laws[0])
    err = np.abs(roll_reached(ap_only) - want[:, 2])
    assert np.max(err) > math.radians(2.0)  # 0.05 * 0.9^2 rad short where RL bends
    # the model's own simulation reads the play by the direction too (from the first
    # command, where it starts relaxed)
    ours.reset(np.zeros(4))
    eff = ours.effective_path(ours.command_path(path), q_start=np.zeros(4))
    assert np.max(np.abs(eff[20:, 2] - want[:, 2])) < 1e-9


def test_twist_preshaping_turns_the_image_frame_about_its_own_axis() -> None:
    from icenav.geometry.kinematics import forward

    comp = HysteresisCompensator([None] * 4, twist_play_per_bend=0.15)
    t = np.linspace(0, 2 * math.pi, 181)
    a = 50 * DEG
    path = np.stack([a * np.cos(t), a * np.sin(t), -t, np.zeros_like(t)], axis=-1)
    shaped = comp.preshape_model(path)
    before, after = forward(path), forward(shaped)
    # the tip does not move and its axis does not tilt ...
    assert np.allclose(after[:, :3, 3], before[:, :3, 3], atol=1e-9)
    assert np.allclose(after[:, :3, 2], before[:, :3, 2], atol=1e-9)
    # ... the image frame turns ahead in the direction of the roll (phi3 decreasing) by h_t
    rel = np.swapaxes(before[:, :3, :3], -1, -2) @ after[:, :3, :3]
    delta = np.arctan2(rel[:, 1, 0], rel[:, 0, 0])
    assert delta[0] == 0.0  # no motion yet: direction unknown
    assert np.allclose(delta[1:], -0.15 * a, atol=1e-9)
    assert np.array_equal(HysteresisCompensator([None] * 4).preshape_model(path), path)
