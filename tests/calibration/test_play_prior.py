"""Tests of icenav.calibration.play_prior: the play shapes of a product line (P0), scaled to
one short reading (P1), stored as JSON. The laws here are not the model's forms: a power
of the bend times a factor that depends on the bend's direction."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from icenav.calibration.play_prior import (
    CIRCLE_TWIST_DIRECTIONS,
    PRIOR_BENDS,
    PRIOR_DIRECTIONS,
    PlayPrior,
    load_play_prior,
    make_play_prior,
    make_twist_circle,
    save_play_prior,
)
from icenav.compensation.bend_play import BendPlay, KnobPlanePlay
from icenav.compensation.hysteresis import HysteresisCompensator
from icenav.errors import ConfigurationError, FileFormatError, UnsupportedVersionError

DEG = math.pi / 180


def roll_law(level: float, bend: np.ndarray, psi: float, p: float = 2.3) -> np.ndarray:
    """A play growing as a power of the bend, 2.2x as wide along the RL knob as the AP."""
    return level * np.abs(bend) ** p * (1.0 + 1.2 * math.sin(psi) ** 2)


def full_calibration(level: float, p: float = 2.3) -> HysteresisCompensator:
    """A full calibration's compensator: the law tabulated on a fine grid in 8 directions."""
    grid = np.linspace(1 * DEG, 130 * DEG, 130)
    dirs = tuple(np.arange(8) * math.pi / 8)

    def over_plane(scale: float) -> KnobPlanePlay:
        laws = [
            BendPlay("table", (), tuple(grid), tuple(roll_law(scale, grid, d, p))) for d in dirs
        ]
        return KnobPlanePlay(dirs, tuple(laws))

    return HysteresisCompensator(
        [None, None, None, None], roll_play=over_plane(level), twist_play=over_plane(0.5 * level)
    )


def test_a_short_reading_scales_the_lines_shape_to_another_catheter() -> None:
    """(P0) over three catheters whose plays differ in level only, then (P1) from one
    reading of a fourth catheter along the AP knob: its play at every bend and direction
    (within the table's interpolation), where the line through the reading misses by a
    lot in the RL direction and at small bends."""
    prior = make_play_prior([full_calibration(a) for a in (0.03, 0.04, 0.05)], "line", "abc")
    assert prior.spread[0] < 1e-6 and prior.spread[1] < 1e-6  # one shape
    b_s, level = 75 * DEG, 0.06
    law = prior.law("roll", b_s, float(roll_law(level, np.array(b_s), 0.0)))
    assert law is not None
    line = roll_law(level, np.array(b_s), 0.0) / b_s
    for psi in (0.0, 45 * DEG, 90 * DEG, 135 * DEG, 225 * DEG):  # the directions tabulated
        bends = np.radians([20.0, 40.0, 60.0, 90.0])
        want = roll_law(level, bends, psi)
        got = law(bends, psi)
        np.testing.assert_allclose(got, want, rtol=0.06, atol=0.1 * DEG)
        if psi == 90 * DEG:
            assert np.max(np.abs(line * bends - want)) > 10 * np.max(np.abs(got - want))


def test_the_prior_keeps_every_law_non_negative_and_non_decreasing() -> None:
    comps = [full_calibration(0.08, p) for p in (1.5, 2.3, 3.0)]  # shapes differ
    prior = make_play_prior(comps, "mixed", ["a", "b", "c"])
    assert prior.spread[0] > 0.05  # the shapes' spread is stored
    law = prior.law("twist", 70 * DEG, 5 * DEG)
    assert law is not None
    bends = np.radians(np.linspace(0.0, 140.0, 57))
    for psi in np.radians(np.linspace(0.0, 360.0, 25)):
        e = law(bends, psi)
        assert np.all(e >= 0.0) and np.all(np.diff(e) >= -1e-12)
    assert prior.law("roll", 70 * DEG, math.nan) is None
    assert prior.law("roll", 0.0, 1.0) is None


def test_a_prior_round_trips_through_its_file_and_bad_files_are_named(tmp_path: Path) -> None:
    prior = make_play_prior([full_calibration(0.08)], "line", ["line 1"])
    path = tmp_path / "prior.json"
    save_play_prior(prior, path)
    back = load_play_prior(path)
    assert back.product == "line" and back.catheters == ("line 1",)
    np.testing.assert_allclose(back.roll, prior.roll, rtol=1e-12)
    np.testing.assert_allclose(back.directions, PRIOR_DIRECTIONS, atol=1e-12)
    np.testing.assert_allclose(back.bends, PRIOR_BENDS, atol=1e-12)
    doc = json.loads(path.read_text())
    path.write_text(json.dumps({**doc, "version": 99}))
    with pytest.raises(UnsupportedVersionError, match="prior.json"):
        load_play_prior(path)
    path.write_text(json.dumps({**doc, "roll": [[1.0, 0.5]]}))
    with pytest.raises(FileFormatError, match="roll table"):
        load_play_prior(path)
    path.write_text("{")
    with pytest.raises(FileFormatError, match="prior.json"):
        load_play_prior(path)


def test_a_prior_needs_a_play_to_normalise_and_valid_tables() -> None:
    still = HysteresisCompensator([None, None, None, None])
    with pytest.raises(ConfigurationError, match="roll play"):
        make_play_prior([still], "x", ["x"])
    with pytest.raises(ConfigurationError, match="one name each"):
        make_play_prior([still], "x", [])
    with pytest.raises(ConfigurationError, match="decrease"):
        PlayPrior("x", (), (0.0,), (1.0, 2.0), ((1.0, 0.5),), ((0.0, 0.0),))
    with pytest.raises(ConfigurationError, match="which"):
        make_play_prior([full_calibration(0.08)], "x", ["x"]).law("knob", 1.0, 1.0)


def circle_calibration(level: float) -> HysteresisCompensator:
    """A full calibration whose twist, read on the spin circle, depends on the bending
    plane's direction over the whole plane (period 360 deg: 1.5x wider towards 90 deg than
    towards 270 deg) and grows as a power of the bend."""
    grid = np.linspace(1 * DEG, 130 * DEG, 130)
    dirs = tuple(np.arange(12) * math.pi / 6)
    laws = tuple(
        BendPlay("table", (), tuple(grid), tuple(level * grid**1.7 * (1.0 + 0.2 * math.sin(d))))
        for d in dirs
    )
    return HysteresisCompensator(
        [None, None, None, None], twist_play=KnobPlanePlay(dirs, laws, period=2.0 * math.pi)
    )


def test_the_circles_twist_is_scaled_to_the_short_reading_over_the_whole_plane(
    tmp_path: Path,
) -> None:
    """(T0) over three catheters whose circle twist differs in level only, each divided by
    the short sweep's reading on it (here biased low: 0.7 of the circle's at 75 deg along
    the AP knob, as a reading held in one direction can be); (T1) for a fourth catheter's
    reading gives its circle twist in every direction, where the period-180 deg shape
    cannot tell 90 from 270 deg. The table survives the file; a prior without it gives
    None (the caller keeps P1)."""
    ref = 75 * DEG

    def reading(level: float) -> float:
        return 0.7 * level * ref**1.7

    comps = [circle_calibration(a) for a in (0.05, 0.07, 0.09)]
    table = make_twist_circle(comps, [reading(a) for a in (0.05, 0.07, 0.09)])
    prior = make_play_prior([full_calibration(a) for a in (0.03, 0.04, 0.05)], "line", "abc")
    assert prior.circle_twist(reading(0.06)) is None
    prior = PlayPrior(**{**prior.__dict__, "twist_circle": table})
    path = tmp_path / "prior.json"
    save_play_prior(prior, path)
    again = load_play_prior(path)
    assert again.twist_circle is not None
    np.testing.assert_allclose(again.twist_circle, table)
    law = again.circle_twist(reading(0.06))
    assert law is not None and law.period == 2.0 * math.pi
    want = circle_calibration(0.06)
    for bend in (30 * DEG, 60 * DEG, 90 * DEG):
        for psi in CIRCLE_TWIST_DIRECTIONS:
            assert law.at(bend, psi) == pytest.approx(want.twist_extra(bend, psi), rel=0.02)
    assert law.at(ref, 90 * DEG) > 1.4 * law.at(ref, 270 * DEG)
    assert again.circle_twist(math.nan) is None
    with pytest.raises(ConfigurationError, match="no short twist reading"):
        make_twist_circle(comps, [0.0, 0.0, 0.0])
    with pytest.raises(ConfigurationError, match="one reading each"):
        make_twist_circle(comps, [0.1])
    with pytest.raises(ConfigurationError, match="twist_circle table"):
        PlayPrior(**{**prior.__dict__, "twist_circle": ((1.0,),)})
