"""The in-vivo pose stage's dead band follows the targets and the estimator's scatter."""

from __future__ import annotations

import math

import pytest

from icenav.refinement.presets import (
    CYCLE_POSE_STAGE,
    CYCLE_POSE_STAGE_PHANTOM,
    ESTIMATE_SCATTER,
    IN_VIVO_TARGET,
    product_stage,
)


def test_the_in_vivo_dead_band_is_the_target_less_two_scatters() -> None:
    """A held state whose estimate lies in the dead band is within the targets with at least
    about 95 % probability (1.5-2.5 standard deviations of the estimate below them): not
    wider, and not much narrower (a narrower band moves states that are already within the
    targets, and every move is a new draw)."""
    for tol, target, scatter in zip(
        (CYCLE_POSE_STAGE.tolerance_mm, CYCLE_POSE_STAGE.tolerance_rad),
        IN_VIVO_TARGET,
        ESTIMATE_SCATTER,
        strict=True,
    ):
        assert target - 2.5 * scatter <= tol <= target - 1.5 * scatter
    assert math.degrees(CYCLE_POSE_STAGE.tolerance_rad) == pytest.approx(1.3)


def test_the_product_keeps_the_dead_bands() -> None:
    """The product's controller task uses the same dead band as the evaluation; the phantom's
    lies below the phantom's targets (0.5 mm / 0.5 deg)."""
    for base in (CYCLE_POSE_STAGE, CYCLE_POSE_STAGE_PHANTOM):
        own = product_stage(9.0, base)
        assert (own.tolerance_mm, own.tolerance_rad) == (base.tolerance_mm, base.tolerance_rad)
        assert own.max_duration_s == pytest.approx(base.max_duration_s + 36.0)
    assert CYCLE_POSE_STAGE_PHANTOM.tolerance_mm < 0.5
    assert math.degrees(CYCLE_POSE_STAGE_PHANTOM.tolerance_rad) < 0.5


def test_the_in_vivo_stage_has_the_longer_budget_and_the_phantom_keeps_its_own() -> None:
    """In vivo: 120 s and at most 9 corrections (more measured draws, the best kept); the
    phantom's preset keeps session 7's 60 s and 5 corrections, and neither uses the secant
    update or the stop after an unpaid correction (tried, not kept)."""
    assert (CYCLE_POSE_STAGE.max_duration_s, CYCLE_POSE_STAGE.max_iterations) == (120.0, 9)
    ph = CYCLE_POSE_STAGE_PHANTOM
    assert (ph.max_duration_s, ph.max_iterations) == (60.0, 5)
    for base in (CYCLE_POSE_STAGE, ph):
        assert base.secant_weight == 0.0 and not base.stop_unpaid
