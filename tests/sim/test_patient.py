"""Patients: seeded draws within their bands, a heart placed and sized as drawn, and the
views an operator finds (the example views in the default heart)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import forward
from icenav.sim.anatomy import BASE2ANATOMY, EXAMPLE_VIEWS, default_phantom
from icenav.sim.patient import PATIENT_SD, Patient, aim_views


def test_the_nominal_patient_is_the_default_phantom() -> None:
    p = Patient.nominal()
    np.testing.assert_allclose(p.base2anatomy(), BASE2ANATOMY, atol=1e-12)
    assert p.phantom().chambers == default_phantom().chambers
    assert aim_views(p.phantom(), p.base2anatomy()) == EXAMPLE_VIEWS


def test_draws_are_seeded_and_within_two_sd() -> None:
    pats = [Patient.sample(s) for s in range(40)]
    assert Patient.sample(7) == pats[7] and pats[7] != pats[8]
    scales = np.array([p.heart_scale for p in pats])
    assert np.all(np.abs(scales - 1.0) <= 2 * PATIENT_SD["heart_scale"] + 1e-12)
    assert scales.std() > 0.03
    offs = np.array([p.offset_mm for p in pats])
    assert np.all(np.abs(offs) <= 2 * PATIENT_SD["offset_mm"] + 1e-12)


def test_the_heart_is_placed_and_sized_as_drawn() -> None:
    """The base stays where it is (the heart turns about it); structures scale about the
    IVC-RA junction."""
    p = Patient(heart_scale=1.1, offset_mm=(1.0, -2.0, 0.5), rotation_deg=(3.0, -2.0, 4.0))
    b2a = p.base2anatomy()
    base_in_anatomy = b2a[:3, 3]
    h = p.heart2world()
    np.testing.assert_allclose(
        h[:3, :3] @ base_in_anatomy + h[:3, 3], BASE2ANATOMY[:3, 3], atol=1e-9
    )
    # the heart turns about the base and shifts: its point at the base moves by the offset
    pivot = BASE2ANATOMY[:3, 3]
    np.testing.assert_allclose(h[:3, :3] @ pivot + h[:3, 3], pivot + [1.0, -2.0, 0.5], atol=1e-9)
    angle = math.degrees(math.acos((np.trace(b2a[:3, :3] @ BASE2ANATOMY[:3, :3].T) - 1) / 2))
    assert 4.0 < angle < 6.0
    ra = p.phantom().chamber("ra")
    ra0 = default_phantom().chamber("ra")
    np.testing.assert_allclose(ra.semi_axes, np.array(ra0.semi_axes) * 1.1)
    np.testing.assert_allclose(ra.centre, np.array(ra0.centre) * 1.1)


@pytest.mark.parametrize("seed", [0, 3])
def test_views_are_found_near_the_examples_and_see_their_valve(seed: int) -> None:
    p = Patient.sample(seed)
    ph, b2a = p.phantom(), p.base2anatomy()
    views = aim_views(ph, b2a)
    valves = {v.name: v for v in ph.valves}
    for name, q in views.items():
        dq = np.abs(np.asarray(q) - EXAMPLE_VIEWS[name])
        assert np.all(dq <= [0.21, 0.21, 0.42, 10.0 + 1e-9])
        t2a = b2a @ forward(np.asarray(q))
        rel = t2a[:3, :3].T @ (np.asarray(valves[name].centre) - t2a[:3, 3])
        assert abs(rel[1]) < 2.5 and rel[0] > 10.0


def test_bad_patients_are_refused() -> None:
    with pytest.raises(ConfigurationError, match="patient seed"):
        Patient.sample(-1)
    with pytest.raises(ConfigurationError, match="heart_scale"):
        Patient(heart_scale=2.0)
