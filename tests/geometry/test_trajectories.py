"""Tests of icenav.geometry.trajectories: image spinning, smoothing, time parameterisation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError, JointLimitError, UnreachablePoseError
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import savgol_smooth, spin_trajectory

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
