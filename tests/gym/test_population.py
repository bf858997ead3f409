"""Seeded patients: reproducible, within their documented ranges, a rigid base seat."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError
from icenav.gym.population import check_seed_range, sample_patient
from icenav.sim.anatomy import BASE2ANATOMY


def test_patients_are_reproducible_and_within_their_ranges() -> None:
    assert sample_patient(5) == sample_patient(5)
    patients = [sample_patient(s) for s in range(200)]
    assert len({p.heart_rate_bpm for p in patients}) == 200
    for p in patients:
        assert 60.0 <= p.heart_rate_bpm <= 80.0
        assert 3.0 <= p.respiratory_period_s <= 5.0
        assert 0.5 <= p.respiratory_scale <= 1.5
        assert abs(p.seat_roll_rad) <= math.radians(10.0)
        assert max(abs(p.seat_offset_mm[0]), abs(p.seat_offset_mm[1])) <= 2.0
        assert abs(p.seat_offset_mm[2]) <= 5.0


def test_the_seat_is_a_rigid_move_of_the_phantom_base_and_the_heart_beats_at_its_rate() -> None:
    p = sample_patient(11)
    b = p.base2anatomy
    np.testing.assert_allclose(b[:3, :3] @ b[:3, :3].T, np.eye(3), atol=1e-12)
    # the catheter axis (base z) stays along the IVC (anatomy z)
    np.testing.assert_allclose(b[:3, 2], BASE2ANATOMY[:3, 2], atol=1e-12)
    shift = b[:3, 3] - BASE2ANATOMY[:3, 3]
    assert np.linalg.norm(shift[:2]) > 0 or abs(p.seat_roll_rad) > 0
    phantom = p.phantom()
    assert phantom.motion.period_s == pytest.approx(60.0 / p.heart_rate_bpm)
    assert phantom.motion.respiratory_period_s == p.respiratory_period_s


@pytest.mark.parametrize("seed", [-1, 1.5, True])
def test_bad_patient_seeds_are_rejected(seed: object) -> None:
    with pytest.raises(ConfigurationError, match="patient seed must be an int >= 0"):
        sample_patient(seed)  # type: ignore[arg-type]


def test_seed_ranges_are_checked() -> None:
    assert check_seed_range((1, 3), "s") == (1, 3)
    with pytest.raises(ConfigurationError, match="two ints"):
        check_seed_range(5, "s")
