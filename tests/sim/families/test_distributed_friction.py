"""Distributed (Prandtl-Ishlinskii) friction: rounded loops, minor loops that close inside the
major loop; the default twin's single play has sharp corners."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError
from icenav.sim import CatheterPlant
from icenav.sim.families.distributed_friction import (
    DistributedFrictionParams,
    DistributedFrictionPlant,
    PlayBank,
)

DEG = math.pi / 180.0


def bend_along(plant: object, knob: np.ndarray) -> np.ndarray:
    """AP effective knob (rad) after each AP motor knob of ``knob`` (the rest at 0)."""
    out = []
    for k in knob:
        plant.move([k, 0.0, 0.0, 0.0])  # type: ignore[attr-defined]
        out.append(plant.state.effective_knobs[0])  # type: ignore[attr-defined]
    return np.array(out)


def test_play_bank_is_a_prandtl_ishlinskii_operator() -> None:
    bank = PlayBank(10)
    bank.reset(0.0)
    # after a long rise, the output lags by the mean width R/2
    assert bank(5.0, 1.0) == pytest.approx(5.0 - 0.5)
    # a reversal: the first element turns at once, all of them after a travel of 2R
    outs = [bank(5.0 - x, 1.0) for x in np.linspace(0.0, 2.0, 41)]
    slopes = -np.diff(outs) / 0.05
    assert slopes[0] < 0.15 and slopes[-1] == pytest.approx(1.0)
    assert np.all(np.diff(slopes) >= -1e-12)  # the slope only grows: a rounded corner
    # weights: equal; widths graded (j + 1/2) / N
    np.testing.assert_allclose(bank.rho, (np.arange(10) + 0.5) / 10)


def test_minor_loops_close_and_lie_inside_the_major_loop() -> None:
    plant = DistributedFrictionPlant(seed=201)
    up = np.linspace(-60 * DEG, 60 * DEG, 121)
    bend_along(plant, np.linspace(0, -60 * DEG, 30))
    rising = bend_along(plant, up)
    falling = bend_along(plant, up[::-1])[::-1]
    # a minor loop: rise from the major loop's lower branch to +20, back to -10, up to +20
    bend_along(plant, np.linspace(60 * DEG, -60 * DEG, 121))
    first = bend_along(plant, np.linspace(-60 * DEG, 20 * DEG, 81))[-1]
    down = bend_along(plant, np.linspace(20 * DEG, -10 * DEG, 31))
    back = bend_along(plant, np.linspace(-10 * DEG, 20 * DEG, 31))
    assert back[-1] == pytest.approx(first, abs=1e-9)  # the minor loop closes (wiping out)
    knob_down = np.linspace(20 * DEG, -10 * DEG, 31)
    knob_back = knob_down[::-1]
    lo = np.interp(knob_down, up, rising)
    hi = np.interp(knob_down, up, falling)
    assert np.all(down >= lo - 1e-6) and np.all(down <= hi + 1e-6)
    lo = np.interp(knob_back, up, rising)
    hi = np.interp(knob_back, up, falling)
    assert np.all(back >= lo - 1e-6) and np.all(back <= hi + 1e-6)
    # and the minor loop is open in between (it is a loop, not a line)
    assert np.max(np.interp(knob_back, knob_down[::-1], down[::-1]) - back) > 0.5 * DEG


def _reversal_fraction(plant: object) -> float:
    """After a rise to +40 deg and a reversal, the fraction of the final slope reached
    halfway through the reversal's lost motion (0 or 1 for a sharp play)."""
    bend_along(plant, np.linspace(0.0, 40 * DEG, 41))
    knob = np.linspace(40 * DEG, 0.0, 161)
    bend = bend_along(plant, knob)
    slope = -np.diff(bend) / np.diff(-knob)
    slope = np.abs(slope) / np.max(np.abs(slope[-40:]))
    moving = np.nonzero(slope > 0.97)[0][0]  # where the whole output follows
    return float(slope[moving // 2])


def test_reversals_are_rounded_where_the_default_twins_are_sharp() -> None:
    rounded = _reversal_fraction(DistributedFrictionPlant(seed=202))
    sharp = _reversal_fraction(CatheterPlant(seed=202))
    assert 0.2 < rounded < 0.8
    assert sharp < 0.05 or sharp > 0.95


def test_the_roll_is_distributed_too_and_widens_with_the_tension() -> None:
    def roll_lag(knob: float) -> float:
        plant = DistributedFrictionPlant(seed=203)
        plant.move_along(np.linspace([0, 0, 0, 0], [knob, 0, 0, 0], 20))
        plant.move_along(np.linspace([knob, 0, 0, 0], [knob, 0, 1.0, 0], 40))
        return 1.0 - plant.state.roll

    straight, bent = roll_lag(0.0), roll_lag(60 * DEG)
    f = DistributedFrictionPlant(seed=203).friction
    assert straight == pytest.approx(f.roll_width_rad / 2, rel=0.05)  # mean width R/2
    assert bent > 2.0 * straight


def test_parameters_are_checked() -> None:
    with pytest.raises(ConfigurationError, match="tendon_width_ap_mm"):
        DistributedFrictionParams(tendon_width_ap_mm=-0.1)
    with pytest.raises(ConfigurationError, match="n_elements"):
        DistributedFrictionParams(n_elements=0)
