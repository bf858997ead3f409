"""Out of tolerance: every parameter 2-3x outside today's band, the default twin's laws."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from icenav.sim import TOLERANCES, CatheterPlant, PlantParams
from icenav.sim.families import FAMILIES
from icenav.sim.families.out_of_tolerance import out_of_tolerance_params, out_of_tolerance_plant


@pytest.mark.parametrize("seed", [200, 201, 202, 203])
def test_every_parameter_lies_outside_todays_band_within_three_times_it(seed: int) -> None:
    nominal = PlantParams.nominal()
    drawn = out_of_tolerance_params(seed)
    signs = []
    for f in fields(PlantParams):
        kind, tol = TOLERANCES[f.name]
        base = float(getattr(nominal, f.name))
        dev = float(getattr(drawn, f.name)) - base
        m = abs(dev) / (tol * abs(base) if kind == "rel" else tol)
        assert 2.0 - 1e-9 <= m <= 3.0 + 1e-9, f.name
        signs.append(np.sign(dev))
    assert 0 < sum(s > 0 for s in signs) < len(signs)  # both directions occur


def test_the_plant_is_the_default_law_with_these_parameters() -> None:
    plant, _ = FAMILIES["out-of-tolerance"](204, "moderate")
    assert isinstance(plant, CatheterPlant) and plant.params == out_of_tolerance_params(204)
    q = np.array([0.6, 0.4, 0.3, 1.0])
    ref = CatheterPlant(params=out_of_tolerance_params(204), vessel="moderate")
    np.testing.assert_array_equal(out_of_tolerance_plant(204, "moderate").move(q), ref.move(q))
    assert plant.params != PlantParams.sample(204)
