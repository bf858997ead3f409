"""Tests of icenav.compensation.section_length: the bending section's length from tracked
poses, on arcs of another length than the model's, with a tracker's jitter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.compensation.calibration_set import CalibrationSet
from icenav.compensation.section_length import (
    SectionLength,
    fit_section_length,
    tracked_bends,
)
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward

DEG = math.pi / 180


def arcs(scale: float, n: int = 120, seed: int = 0, jitter_mm: float = 0.3) -> CalibrationSet:
    """Tracked poses of a section ``scale`` times the model's length (the model's arcs with
    the true length, random bends up to 110 deg, rolls and translations), each tip moved by
    an axial offset of 0.4 mm and an isotropic jitter."""
    rng = np.random.default_rng(seed)
    q = np.column_stack(
        [
            rng.uniform(-70, 70, n) * DEG,
            rng.uniform(-70, 70, n) * DEG,
            rng.uniform(-90, 90, n) * DEG,
            rng.uniform(-5.0, 5.0, n),
        ]
    )
    geo = CatheterGeometry(bending_length=scale * DEFAULT_GEOMETRY.bending_length)
    poses = forward(q, geo, check=False)
    poses[:, :3, 3] += rng.normal(0.0, jitter_mm, (n, 3))
    poses[:, 2, 3] += 0.4
    return CalibrationSet(q_motor=q, tip2base=poses, method="synthetic")


@pytest.mark.parametrize("scale", [0.955, 1.044])
def test_fit_recovers_a_length_outside_the_tolerance(scale: float) -> None:
    """A section 4-5 % off the model's (3x the twin's tolerance) is found within 0.3 %, the
    offset within 0.2 mm, and the held-out residual chooses the fitted length."""
    fit = fit_section_length(arcs(scale))
    assert fit.scale == pytest.approx(scale, abs=0.003)
    assert fit.offset_mm == pytest.approx(0.4, abs=0.2)
    assert fit.cv_residual_mm < fit.cv_residual_nominal_mm
    assert fit.n_samples == 120


def test_model_length_is_kept_when_the_data_do_not_ask_for_another() -> None:
    """On arcs of the model's own length, the fitted scale is 1 or within the jitter's
    reach, and correcting with it moves no tip by more than 0.1 mm."""
    data = arcs(1.0, seed=3)
    fit = fit_section_length(data)
    assert abs(fit.scale - 1.0) < 0.002
    moved = fit.correct_poses(data.tip2base)[:, :3, 3] - data.tip2base[:, :3, 3]
    assert float(np.max(np.abs(moved))) < 0.1


def test_correction_gives_the_model_length_heights() -> None:
    """The corrected tips of a longer section have the model's heights (to the jitter's
    size), and the excess is what the formula says at straight and at 90 deg."""
    data = arcs(1.04, jitter_mm=0.0)
    fit = fit_section_length(data)
    fixed = fit.correct(data)
    model = forward(data.q_motor, check=False)
    err = fixed.tip2base[:, 2, 3] - 0.4 - model[:, 2, 3]
    assert float(np.max(np.abs(err))) < 0.05
    assert np.allclose(fixed.tip2base[:, :3, :3], data.tip2base[:, :3, :3])
    s = SectionLength(scale=1.04)
    assert float(s.axial_excess(0.0)) == pytest.approx(0.04 * 60.0)
    assert float(s.axial_excess(math.pi / 2)) == pytest.approx(0.04 * 60.0 * 2 / math.pi)
    assert SectionLength.none().correct(data) is data


def test_bends_are_read_from_the_orientation() -> None:
    q = np.array([[30 * DEG, 40 * DEG, 1.0, 3.0], [0.0, 0.0, 0.5, 0.0]])
    bends = tracked_bends(forward(q, check=False))
    assert bends[0] == pytest.approx(DEFAULT_GEOMETRY.knob_ratio * 50 * DEG, abs=1e-9)
    assert bends[1] == pytest.approx(0.0, abs=1e-6)


def test_bad_inputs_raise_naming_the_value() -> None:
    with pytest.raises(ConfigurationError, match="at least 5"):
        fit_section_length(arcs(1.0).subset([0, 1, 2, 3]))
    with pytest.raises(ConfigurationError, match="CalibrationSet"):
        fit_section_length(np.zeros((5, 4, 4)))  # type: ignore[arg-type]
    with pytest.raises(ConfigurationError, match="scale"):
        SectionLength(scale=2.0)
    with pytest.raises(ShapeError, match="tip2base"):
        tracked_bends(np.zeros((4, 4)))
