"""The plant's elastic statics agree with an independent Cosserat-rod (Rucker-Webster) solver."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.sim import PlantParams, elastic_tip2base_from_tensions
from icenav.sim.bending import Tendons
from icenav.sim.reference import solve_tendon_rod

US_OFFSET = 10.0


def _reference_tip(p: PlantParams, tensions: tuple[float, ...]) -> np.ndarray:
    arms = Tendons.from_params(p).arms
    positions = np.array([[a[1], -a[0]] for a in arms])  # r = (r_x, r_y), a = (-r_y, r_x)
    k = np.array([[p.ei_rl_nmm2, p.ei_coupling_nmm2], [p.ei_coupling_nmm2, p.ei_ap_nmm2]])
    sol = solve_tendon_rod(
        positions,
        np.array(tensions, dtype=float),
        k,
        torsional_stiffness_nmm2=0.7 * p.ei_ap_nmm2,
        stiffening=p.stiffening,
        length_mm=60.0 * p.bending_length_scale,
    )
    assert sol.residual < 1e-6
    return sol.positions[-1] + US_OFFSET * sol.tip_rotation[:, 2]


def test_reference_matches_the_analytic_arc_of_an_isotropic_rod() -> None:
    # one tendon at x = 1.2 mm, EI = 500 N mm^2, T = 4 N: constant curvature kappa = T r / EI
    sol = solve_tendon_rod(
        np.array([[1.2, 0.0]]), np.array([4.0]), 500.0 * np.eye(2), 400.0, 0.0, 60.0
    )
    kappa = 4.0 * 1.2 / 500.0
    s = sol.s
    expected = np.stack([(1 - np.cos(kappa * s)) / kappa, 0 * s, np.sin(kappa * s) / kappa], 1)
    np.testing.assert_allclose(sol.positions, expected, atol=1e-6)


@pytest.mark.parametrize(
    "tensions",
    [
        (4.0, 0.0, 0.0, 0.0),  # AP tendon, off the principal plane (routing error)
        (0.0, 0.0, 6.0, 0.0),  # RL tendon, the stiffer plane
        (3.0, 0.0, 5.0, 0.0),  # two tendons: coupled, anisotropic
        (0.0, 8.0, 0.0, 9.0),  # large bend: strain stiffening matters
    ],
)
def test_plant_elastic_tip_agrees_with_cosserat_reference(tensions: tuple[float, ...]) -> None:
    p = PlantParams.sample(4)  # anisotropic, coupled, stiffening, off-plane tendons
    ref = _reference_tip(p, tensions)
    plant = elastic_tip2base_from_tensions(p, tensions)[:3, 3]
    assert np.linalg.norm(ref[:2]) > 5.0  # a real bend, not the straight rod
    assert np.linalg.norm(plant - ref) < 1.0
