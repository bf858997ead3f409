"""Roll and twist plays that grow with bend x tension (the play at 2x bend is not 2x, unlike
the default twin's line), and the Bouc-Wen tendon loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError
from icenav.sim import CatheterPlant
from icenav.sim.families.nonlinear_play import (
    BETA,
    DELTA_PER_WIDTH,
    BoucWen,
    NonlinearPlayParams,
    NonlinearPlayPlant,
)

DEG = math.pi / 180.0


def measured_plays(plant: object, knob: float) -> tuple[float, float, float]:
    """Bend (rad), roll play and twist play (rad) measured through the state: bend the AP
    knob from rest, roll up by 0.5 rad, then read how far the section's roll and the image's
    twist lag behind (a Coulomb play lags by its half-width)."""
    plant.reset()  # type: ignore[attr-defined]
    plant.move_along(np.linspace([0, 0, 0, 0], [knob, 0, 0, 0], 30))  # type: ignore[attr-defined]
    plant.move_along(np.linspace([knob, 0, 0, 0], [knob, 0, 0.5, 0], 30))  # type: ignore[attr-defined]
    s = plant.state  # type: ignore[attr-defined]
    return s.bend_angle, 0.5 - s.roll, -s.twist


def test_the_play_at_twice_the_bend_is_not_twice_the_play() -> None:
    plant = NonlinearPlayPlant(seed=201)
    b1, r1, t1 = measured_plays(plant, 25 * DEG)
    b2, r2, t2 = measured_plays(plant, 50 * DEG)
    assert 1.8 < b2 / b1 < 2.2  # about twice the bend
    h0 = plant.plays.roll_play_rad
    # growth above the relaxed play: about the bend squared times the stiffening tension
    assert (r2 - h0) / (r1 - h0) > 3.0
    assert t2 / t1 > 3.0
    # the measured lag is the law's play (N1)-(N2) at the state reached
    assert r2 == pytest.approx(plant.roll_play(), rel=1e-6)
    assert t2 == pytest.approx(plant.twist_play(), rel=1e-6)


def test_the_default_twins_plays_grow_linearly_for_contrast() -> None:
    plant = CatheterPlant(seed=201)
    b1, r1, t1 = measured_plays(plant, 25 * DEG)
    b2, r2, t2 = measured_plays(plant, 50 * DEG)
    h0 = plant.params.roll_play_rad
    assert (r2 - h0) / (r1 - h0) == pytest.approx(b2 / b1, rel=1e-6)
    assert t2 / t1 == pytest.approx(b2 / b1, rel=1e-6)


def test_the_play_grows_with_the_tension_at_a_fixed_bend() -> None:
    """Same bend, more tension: both tendons of a pair pulled (a stiffer state)."""
    plant = NonlinearPlayPlant(seed=202)
    plant.move([40 * DEG, 0.0, 0.0, 0.0])
    loose_tension, loose = plant.tension_sum_n, plant.twist_play() / plant.bend
    plant.move([40 * DEG, 60 * DEG, 0.0, 0.0])
    tight_tension, tight = plant.tension_sum_n, plant.twist_play() / plant.bend
    assert tight_tension > loose_tension and tight > loose


def _euler(bw_width: float, p: np.ndarray) -> np.ndarray:
    """(N3)-(N4) integrated by explicit Euler in 20,000 substeps per unit (a reference)."""
    y = 0.0
    out = [p[0]]
    delta = DELTA_PER_WIDTH * bw_width
    for a, b in zip(p[:-1], p[1:], strict=True):
        n = max(1, int(abs(b - a) * 20000))
        dp = (b - a) / n
        for _ in range(n):
            sgn = 1.0 if dp * y > 0 else -1.0 if dp * y < 0 else 0.0
            y += dp * (1.0 - (BETA * sgn + (1.0 - BETA)) * abs(y)) / delta
        out.append(b - bw_width * y)
    return np.array(out)


def test_bouc_wen_is_integrated_exactly() -> None:
    p = np.concatenate([np.linspace(0, 1, 21), np.linspace(1, 0.2, 17), np.linspace(0.2, 0.7, 11)])
    bw = BoucWen()
    bw.reset(0.0)
    exact = np.array([bw(x, 0.12) for x in p])
    np.testing.assert_allclose(exact, _euler(0.12, p), atol=2e-5)


def test_bouc_wen_loop_stands_still_at_a_reversal_and_lags_by_its_width() -> None:
    bw = BoucWen()
    bw.reset(0.0)
    w = 0.12
    assert bw(5.0, w) == pytest.approx(5.0 - w, abs=1e-9)  # saturated: lags by W
    first = bw(5.0 - 1e-4, w)
    assert abs(first - (5.0 - w)) / 1e-4 < 1e-3  # zero slope at the reversal (no jump)
    later = bw(5.0 - 3 * w, w)
    assert 0.2 < (5.0 - w - later) / (3 * w) < 0.8  # and it picks up, smoothly
    # minor loops of a Bouc-Wen operator do not close: repeated small cycles drift
    ends = []
    for _ in range(3):
        bw(4.9, w)
        ends.append(bw(4.95, w))
    assert abs(ends[1] - ends[0]) > 1e-4


def test_parameters_are_checked() -> None:
    with pytest.raises(ConfigurationError, match="roll_play_per_n_rad"):
        NonlinearPlayParams(roll_play_per_n_rad=-1.0)
