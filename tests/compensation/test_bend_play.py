"""The play against the bend: the form with the smallest held-out residual is kept, and it
predicts bends it was not fitted on for laws of several shapes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.compensation.bend_play import MAX_EXTRA, BendPlay, select_bend_play
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
