"""The play against the bend: the form with the smallest held-out residual is kept, and it
predicts bends it was not fitted on for laws of several shapes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.compensation.bend_play import MAX_EXTRA, BendPlay, KnobPlanePlay, select_bend_play
from icenav.errors import ConfigurationError

BENDS = np.radians([45.0, 80.0, 115.0])
HELD_OUT = np.radians([20.0, 60.0, 100.0])


def test_a_linear_law_is_kept_linear() -> None:
    law = BendPlay.linear(0.09)
    fit = select_bend_play(BENDS, law(BENDS))
    # every form reproduces a line exactly; the simplest wins the tie
    assert fit.form == "linear" and fit.coef[0] == pytest.approx(0.09)
    assert fit.loo_rms == pytest.approx(0.0, abs=1e-12)


def test_a_law_growing_with_the_bend_squared_is_found_and_predicts_held_out_bends() -> None:
    def law(b: np.ndarray) -> np.ndarray:  # the nonlinear-play family's form, about alpha^2
        return 0.012 * b + 0.08 * b * b

    fit = select_bend_play(BENDS, law(BENDS))
    assert fit.form == "quadratic"
    np.testing.assert_allclose(fit(HELD_OUT), law(HELD_OUT), atol=1e-9)
    line = select_bend_play(BENDS[1:2], law(BENDS[1:2]))  # one bend: the old two-point line
    assert line.form == "linear"
    assert np.max(np.abs(line(HELD_OUT) - law(HELD_OUT))) > math.radians(1.0)


def test_a_saturating_law_is_better_predicted_than_by_a_line() -> None:
    bends = np.radians([20.0, 40.0, 60.0, 80.0, 100.0])

    def law(b: np.ndarray) -> np.ndarray:
        return 0.1 * np.tanh(2.0 * b)

    fit = select_bend_play(bends, law(bends))
    assert fit.form != "linear"
    line = BendPlay.linear(float(bends @ law(bends) / (bends @ bends)))
    mid = np.radians([30.0, 50.0, 70.0, 90.0])
    assert np.max(np.abs(fit(mid) - law(mid))) < 0.5 * np.max(np.abs(line(mid) - law(mid)))


def test_a_law_steeper_than_the_square_is_followed_by_the_power_form() -> None:
    """A play growing as b^2.5 (bend x tension x wrap) through three bends: a quadratic with
    non-negative coefficients cannot bend that much (it misfits the largest point by over a
    degree, why bounding the quadratic alone broke the nonlinear-play test's criterion);
    the power form follows it, and predicts held-out bends below, between and beyond."""

    def law(b: np.ndarray) -> np.ndarray:
        return 0.11 * np.power(b, 2.5)

    fit = select_bend_play(BENDS, law(BENDS))
    assert fit.form == "power" and fit.coef[1] == pytest.approx(2.5, abs=0.03)
    np.testing.assert_allclose(fit(HELD_OUT), law(HELD_OUT), atol=math.radians(0.2))
    from icenav.compensation.bend_play import _fit  # the bounded quadratic, for contrast

    quad = _fit("quadratic", BENDS, law(BENDS))
    assert min(quad.coef) >= 0.0
    assert np.max(np.abs(quad(BENDS) - law(BENDS))) > math.radians(1.0)


def test_below_the_smallest_bend_every_law_goes_down_to_zero_monotonically() -> None:
    """Points read at 47 / 78 / 116 deg of bend (the twist of nonlinear-play catheter 210):
    an unconstrained quadratic through them has a negative linear term and gives no play
    below about 40 deg, where the spins are; every form now is non-negative, non-decreasing
    in the bend and non-zero at 20 deg."""
    bends = np.radians([47.0, 78.0, 116.0])
    extra = np.radians([4.1, 13.0, 33.5])
    a = np.stack([bends, bends * bends], axis=-1)
    free, *_ = np.linalg.lstsq(a, extra, rcond=None)
    assert free[0] < 0.0  # the unbounded fit's dip: zero at 20 deg once clipped
    grid = np.radians(np.linspace(0.0, 180.0, 361))
    chosen = select_bend_play(bends, extra)
    from icenav.compensation.bend_play import BEND_PLAY_FORMS, _fit

    for form in (*BEND_PLAY_FORMS, chosen.form):
        law = chosen if form == chosen.form else _fit(form, bends, extra)
        e = law(grid)
        assert np.all(e >= 0.0) and np.all(np.diff(e) >= -1e-12), form
        assert law.at(math.radians(20.0)) > 0.0, form
        assert law.at(math.radians(40.0)) <= law.at(bends[0]) + 1e-12, form
    assert chosen.at(math.radians(40.0)) > math.radians(1.5)  # the family's own: about 3


def test_a_table_through_noisy_points_is_made_monotone() -> None:
    """A table whose middle reading came out above the last: pooled, never decreasing, and
    the slope beyond the last point is never negative."""
    law = BendPlay("table", (), tuple(BENDS), tuple(np.radians([3.0, 7.0, 6.0])))
    e = law(np.radians(np.linspace(0.0, 180.0, 181)))
    assert np.all(np.diff(e) >= -1e-12)
    np.testing.assert_allclose(law(BENDS[1:]), np.radians([6.5, 6.5]))


def test_a_file_s_unbounded_quadratic_still_loads_and_is_clipped_at_zero() -> None:
    """Calibration files written before the bounds hold quadratics with a negative term."""
    law = BendPlay("quadratic", (-0.05, 0.1), tuple(BENDS), (0.01, 0.02, 0.05))
    assert law.at(math.radians(20.0)) == 0.0 and law.at(2.0) == pytest.approx(0.3)
    with pytest.raises(ConfigurationError, match="exponent must be in"):
        BendPlay("power", (0.1, 9.0))


def test_the_play_is_never_negative_nor_unbounded() -> None:
    fit = select_bend_play(BENDS, [-0.01, 0.02, 0.4])
    assert np.all(fit(np.radians(np.linspace(0.0, 180.0, 50))) >= 0.0)
    assert float(fit(10.0)) == MAX_EXTRA


@pytest.mark.parametrize(
    ("bends", "extra", "message"),
    [
        ([0.5, 1.0], [0.1], "as many extra plays as bends"),
        ([0.0, 1.0], [0.0, 0.1], "> 0 rad"),
        ([1.0, 1.0], [0.1, 0.1], "distinct"),
        ([1.0, math.nan], [0.1, 0.1], "finite"),
    ],
)
def test_bad_points_are_refused(bends: list[float], extra: list[float], message: str) -> None:
    with pytest.raises(ConfigurationError, match=message):
        select_bend_play(bends, extra)


def test_bad_forms_are_refused() -> None:
    with pytest.raises(ConfigurationError, match="form must be one of"):
        BendPlay("cubic", (1.0,))
    with pytest.raises(ConfigurationError, match="needs 2 coefficient"):
        BendPlay("quadratic", (1.0,))
    with pytest.raises(ConfigurationError, match="at least one measured point"):
        BendPlay("table")


# --- the play over the knob plane (B5) --------------------------------------------------------

DIRS = (0.0, math.pi / 4, math.pi / 2, 3 * math.pi / 4)


def _plane() -> KnobPlanePlay:
    """Four laws of different forms and levels, as the directions of a catheter whose play
    grows with the total tendon tension would give."""
    return KnobPlanePlay(
        DIRS,
        (
            BendPlay("power", (0.06, 2.3)),
            BendPlay.linear(0.05),
            BendPlay("quadratic", (0.02, 0.1)),
            select_bend_play(BENDS, [0.05, 0.2, 0.21]).scaled(1.5),
        ),
    )


def test_the_knob_plane_law_is_each_direction_s_law_and_periodic() -> None:
    plane = _plane()
    b = np.radians(np.linspace(0.0, 130.0, 27))
    for d, law in zip(DIRS, plane.laws, strict=True):
        np.testing.assert_allclose(plane(b, d), law(b), atol=1e-15)
        # the bending plane's axis, not its sense: psi and psi + pi (and - pi) are one law
        np.testing.assert_allclose(plane(b, d + math.pi), law(b), atol=1e-15)
        np.testing.assert_allclose(plane(b, d - math.pi), law(b), atol=1e-15)
    # between two directions it lies between their laws; past 135 deg it returns to 0 deg's
    mid = plane(b, math.radians(22.5))
    lo, hi = (
        np.minimum(plane.laws[0](b), plane.laws[1](b)),
        np.maximum(plane.laws[0](b), plane.laws[1](b)),
    )
    assert np.all(mid >= lo - 1e-15) and np.all(mid <= hi + 1e-15)
    np.testing.assert_allclose(
        plane(b, math.radians(157.5)), 0.5 * (plane.laws[3](b) + plane.laws[0](b)), atol=1e-15
    )


def test_the_knob_plane_law_is_non_negative_and_non_decreasing_in_every_direction() -> None:
    plane = _plane()
    b = np.radians(np.linspace(0.0, 140.0, 141))
    for psi in np.radians(np.arange(-180.0, 180.0, 7.5)):
        e = plane(b, psi)
        assert e[0] == 0.0 and np.all(e >= 0.0) and np.all(np.diff(e) >= -1e-15)
        assert np.all(e <= MAX_EXTRA)
    # arrays of bends and directions broadcast (a path's samples)
    psis = np.radians(np.linspace(-90.0, 270.0, b.size))
    np.testing.assert_allclose(
        plane(b, psis), [plane.at(x, p) for x, p in zip(b, psis, strict=True)]
    )


def test_a_law_of_the_bend_alone_is_the_same_in_every_direction() -> None:
    law = select_bend_play(BENDS, [0.05, 0.2, 0.21])
    b = np.radians(np.linspace(0.0, 130.0, 14))
    for psi in np.radians([0.0, 33.0, 90.0, -120.0]):
        np.testing.assert_array_equal(law(b, psi), law(b))
        np.testing.assert_array_equal(KnobPlanePlay.uniform(law)(b, psi), law(b))


def test_a_scaled_law_keeps_its_form_and_bounds() -> None:
    for law in (
        _plane().laws[0],
        BendPlay.linear(0.05),
        select_bend_play(BENDS, [0.05, 0.2, 0.21]),
    ):
        s = law.scaled(1.7)
        assert s.form == law.form
        np.testing.assert_allclose(s(BENDS), np.minimum(1.7 * law(BENDS), MAX_EXTRA))
    with pytest.raises(ConfigurationError, match="scale"):
        BendPlay.linear(0.05).scaled(-1.0)


@pytest.mark.parametrize(
    ("directions", "n_laws", "message"),
    [
        ((), 0, "one law per direction"),
        ((0.0, 1.0), 1, "one law per direction"),
        ((0.0, math.pi), 2, r"in \[0, 3.1416\)"),
        ((1.0, 0.5), 2, "ascending"),
    ],
)
def test_bad_knob_plane_laws_are_refused(
    directions: tuple[float, ...], n_laws: int, message: str
) -> None:
    with pytest.raises(ConfigurationError, match=message):
        KnobPlanePlay(directions, (BendPlay.linear(0.1),) * n_laws)


def test_a_knob_plane_law_of_period_360_deg_tells_the_two_senses_of_an_axis_apart() -> None:
    """Period 2 pi (the spin circle's twist, read over the whole knob plane): psi and psi +
    180 deg are different directions, each its own law, interpolated (B5) across 360 deg."""
    laws = _plane().laws
    dirs = tuple(k * math.pi / 4 for k in range(8))
    plane = KnobPlanePlay(dirs, (*laws, *(law.scaled(2.0) for law in laws)), period=2 * math.pi)
    b = np.radians(np.linspace(0.0, 130.0, 27))
    for d, law in zip(dirs, plane.laws, strict=True):
        np.testing.assert_allclose(plane(b, d), law(b), atol=1e-15)
        np.testing.assert_allclose(plane(b, d - 2 * math.pi), law(b), atol=1e-15)
    np.testing.assert_allclose(plane(b, math.pi), 2.0 * laws[0](b), atol=1e-15)
    np.testing.assert_allclose(
        plane(b, math.radians(337.5)), 0.5 * (2.0 * laws[3](b) + laws[0](b)), atol=1e-15
    )
    assert "360" in plane.describe() and "360" not in _plane().describe()
    with pytest.raises(ConfigurationError, match="period"):
        KnobPlanePlay((0.0,), (laws[0],), period=1.0)
    with pytest.raises(ConfigurationError, match=r"\[0, 6.2832\)"):
        KnobPlanePlay((0.0, 2 * math.pi), laws[:2], period=2 * math.pi)
