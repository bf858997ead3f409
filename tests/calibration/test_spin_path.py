"""The transmission scored on a spin-like path that turns the knobs and the roll together
(:mod:`icenav.calibration.spin_path`): the roll's lag per sense is not the model's miss, the
bend's size and the direction's variation are."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from icenav.calibration.spin_path import (
    MIN_SETTLED,
    SPIN_LEAD,
    scorable,
    settled_mask,
    spin_path_rms,
)
from icenav.calibration.twist_circle import spin_circle_path
from icenav.compensation.transmission import TransmissionFit, static_terms
from icenav.errors import ConfigurationError, ShapeError
from tests.support.transmission import DEG, TRUTH, spin_path_motion, static_map


def _fit(model: object, coef: np.ndarray) -> TransmissionFit:
    return TransmissionFit(
        model=model,  # type: ignore[arg-type]
        rms=0.0,
        rms_without_play=0.0,
        static_coefficients=coef,
        n_samples=0,
        n_evaluations=0,
        degree=3,
    )


def _coefficients() -> np.ndarray:
    """The synthetic catheters' static map (tests.support.transmission.static_map) as G's rows."""
    rows = {(1, 0): (0.9, -0.05), (0, 1): (0.08, 1.1), (3, 0): (-0.1, 0.0), (1, 1): (0.0, 0.06)}
    return np.array([rows.get(t, (0.0, 0.0)) for t in static_terms(3)])


def test_the_model_of_the_data_scores_zero_whatever_the_rolls_lag_per_sense() -> None:
    """Data of a known transmission and static map on the calibration's spin circle, seen
    in the base frame with the roll lagging 6 deg one way and 9 deg the other: the true
    model scores 0; a wrong band, a wrong static map or a lag that changes along the turn
    (not one angle per sense) score more."""
    rng = np.random.default_rng(3)
    motion = spin_path_motion(TRUTH, rng, lag=(6.0 * DEG, -9.0 * DEG), noise=0.0)
    coef = _coefficients()
    exact = spin_path_rms(_fit(TRUTH, coef), motion.q_motor, motion.observed, motion.q_start)
    assert exact < 1e-9
    wide = replace(TRUTH, ap=replace(TRUTH.ap, seal_play=4.0 * DEG))
    assert spin_path_rms(_fit(wide, coef), motion.q_motor, motion.observed, motion.q_start) > (
        0.3 * DEG
    )
    scaled = spin_path_rms(
        _fit(TRUTH, 1.05 * coef), motion.q_motor, motion.observed, motion.q_start
    )
    assert scaled > 1.0 * DEG  # 5 % of a 50-deg bend
    turning = spin_path_motion(TRUTH, rng, lag=(6.0 * DEG, -9.0 * DEG), noise=0.0, wobble=3 * DEG)
    wobbly = spin_path_rms(_fit(TRUTH, coef), turning.q_motor, turning.observed, turning.q_start)
    assert wobbly > 1.0 * DEG


def test_only_samples_after_the_lead_in_each_sense_count() -> None:
    path = spin_circle_path(step=10 * DEG)
    sense, settled = settled_mask(path, np.array([50 * DEG, 0.0, 0.0, 0.0]))
    assert set(np.unique(sense)) == {-1.0, 1.0}
    # the roll turns down (-1) first on the spin circle, then back up
    first_up = int(np.argmax(sense > 0))
    assert not settled[: round(SPIN_LEAD / (10 * DEG)) - 1].any()
    assert settled[round(SPIN_LEAD / (10 * DEG))]
    assert not settled[first_up : first_up + round(SPIN_LEAD / (10 * DEG)) - 1].any()


def test_a_path_that_turns_the_roll_one_way_only_is_refused() -> None:
    path = spin_circle_path(step=10 * DEG)
    one_way = path[: int(np.argmax(np.diff(path[:, 2]) > 0)) + 1]
    obs = static_map(one_way[:, :2])
    assert not scorable(one_way, obs, np.zeros(4))
    assert scorable(path, static_map(path[:, :2]), np.zeros(4))
    lost = static_map(path[:, :2])
    lost[np.diff(np.concatenate([[0.0], path[:, 2]])) > 0] = np.nan  # the way back untracked
    assert not scorable(path, lost, np.zeros(4))
    with pytest.raises(ConfigurationError, match=f">= {MIN_SETTLED}"):
        spin_path_rms(_fit(TRUTH, _coefficients()), one_way, obs, np.zeros(4))
    with pytest.raises(ShapeError, match="observed"):
        spin_path_rms(_fit(TRUTH, _coefficients()), path, obs, np.zeros(4))
