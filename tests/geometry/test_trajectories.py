"""Tests of icenav.geometry.trajectories: image spinning, smoothing, time parameterisation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError, JointLimitError, UnreachablePoseError
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import savgol_smooth, spin_trajectory, time_parameterize

DEG = math.pi / 180


@pytest.mark.parametrize("a_deg", [20.0, 40.0, 60.0])
def test_spin_from_an_ap_bend_is_the_papers_closed_form(a_deg: float) -> None:
    a = a_deg * DEG
    sp = spin_trajectory([a, 0.0, 0.0, 0.0], 360)
    t = np.arange(360) * 2 * math.pi / 360
    assert np.allclose(sp.spin_angle, t)
    assert np.allclose(sp.q_model[:, 0], a * np.cos(t), atol=1e-9)
    assert np.allclose(sp.q_model[:, 1], a * np.sin(t), atol=1e-9)
    assert np.allclose(sp.q_model[:, 2], -t, atol=1e-9)
    assert np.allclose(sp.q_model[:, 3], 0.0, atol=1e-9)


def test_spin_keeps_the_tip_and_turns_the_image_plane_360_deg() -> None:
    rng = np.random.default_rng(0)
    for _ in range(25):
        bend, plane = rng.uniform(0, 88) * DEG, rng.uniform(-math.pi, math.pi)
        q0 = np.array(
            [
                bend * math.cos(plane),
                bend * math.sin(plane),
                rng.uniform(-3, 3),
                rng.uniform(-20, 20),
            ]
        )
        direction = int(rng.choice([-1, 1]))
        sp = spin_trajectory(q0, 200, direction=direction, include_end=True)
        t = forward(sp.q_model)
        assert np.allclose(t, sp.tip2base, atol=1e-8)
        assert np.max(np.abs(t[:, :3, 3] - t[0, :3, 3])) < 1e-8  # the tip stays put
        assert np.allclose(t[:, :3, 2], t[0, :3, 2], atol=1e-9)  # so does the tip axis
        # the image direction (tip x) turns about the tip axis: unwrap its angle
        x0, y0 = t[0, :3, 0], t[0, :3, 1]
        ang = np.unwrap(np.arctan2(t[:, :3, 0] @ y0, t[:, :3, 0] @ x0))
        assert ang[-1] - ang[0] == pytest.approx(direction * 2 * math.pi, abs=1e-9)
        assert np.all(np.diff(ang) * direction > 0)
        # the joint path is continuous (no 2 pi jumps in phi3)
        assert np.max(np.abs(np.diff(sp.q_model[:, 2]))) < 0.2
        assert np.allclose(sp.q_model[0], q0, atol=1e-9) or abs(q0[0]) + abs(q0[1]) < 1e-9


def test_spin_rejects_bad_input() -> None:
    # a corner of the knob square: the bend cannot turn to the axes within the limits
    with pytest.raises(UnreachablePoseError, match="not reachable"):
        spin_trajectory([80 * DEG, 80 * DEG, 0.0, 0.0])
    with pytest.raises(JointLimitError, match="phi1"):
        spin_trajectory([2.0, 0.0, 0.0, 0.0])
    with pytest.raises(ConfigurationError, match="direction must be"):
        spin_trajectory([0.3, 0.0, 0.0, 0.0], direction=2)
    with pytest.raises(ConfigurationError, match="n_samples must be >= 2"):
        spin_trajectory([0.3, 0.0, 0.0, 0.0], 1)


def test_savgol_keeps_quadratics_and_removes_noise() -> None:
    s = np.linspace(-1, 1, 200)
    quad = np.stack([1 + 2 * s - 3 * s**2, 0.5 * s**2, -s], axis=-1)
    assert np.allclose(savgol_smooth(quad, 21), quad, atol=1e-10)
    rng = np.random.default_rng(1)
    noisy = quad + rng.normal(0, 0.05, quad.shape)
    sm = savgol_smooth(noisy, 21)
    assert np.std(sm - quad) < 0.5 * np.std(noisy - quad)
    with pytest.raises(ConfigurationError, match="window must be odd"):
        savgol_smooth(quad, 20)


def _discrete(t: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    dt = np.diff(t)
    v = np.diff(q, axis=0) / dt[:, None]
    zeros = np.zeros((1, q.shape[1]))
    vv = np.vstack([zeros, v, zeros])
    dd = np.concatenate([[dt[0]], dt, [dt[-1]]])
    a = np.diff(vv, axis=0) / (0.5 * (dd[:-1] + dd[1:]))[:, None]
    return np.abs(v).max(axis=0), np.abs(a).max(axis=0)


def test_time_parameterisation_meets_the_limits() -> None:
    rng = np.random.default_rng(2)
    v_max = np.array([1.0, 1.0, 2.0, 10.0])
    a_max = np.array([2.0, 3.0, 4.0, 20.0])
    for _ in range(10):
        n = int(rng.integers(20, 300))
        q = np.cumsum(rng.normal(0, 0.02, (n, 4)), axis=0)
        q = savgol_smooth(q, 11)
        tp = time_parameterize(q, v_max, a_max)
        assert tp.t[0] == 0.0
        assert np.all(np.diff(tp.t) > 0)
        v, a = _discrete(tp.t, tp.q)
        assert np.all(v <= v_max * (1 + 1e-6))
        assert np.all(a <= a_max * (1 + 1e-6))
        # no faster than the velocity bound allows, and not absurdly slow
        lower = np.max(np.sum(np.abs(np.diff(tp.q, axis=0)), axis=0) / v_max)
        assert tp.duration >= lower * (1 - 1e-9)


def test_time_parameterisation_of_a_spin_is_near_optimal() -> None:
    sp = spin_trajectory([60 * DEG, 0.0, 0.0, 0.0], 720)
    tp = time_parameterize(sp.q_model, 1.0, 100.0)
    # with a generous acceleration limit the roll (2 pi at 1 rad/s) sets the time
    assert 2 * math.pi <= tp.duration < 1.1 * 2 * math.pi
    samples = tp.sample(100.0)
    assert np.allclose(samples[0], sp.q_model[0])
    assert np.allclose(samples[-1], sp.q_model[-1])


def test_time_parameterisation_rejects_bad_limits() -> None:
    with pytest.raises(ConfigurationError, match="must be > 0"):
        time_parameterize(np.zeros((3, 2)), [1.0, 0.0], 1.0)
    with pytest.raises(ConfigurationError, match=r"shape \(n >= 2, k\)"):
        time_parameterize(np.zeros(3), 1.0, 1.0)
    still = time_parameterize(np.zeros((5, 2)), 1.0, 1.0)
    assert still.duration == 0.0
