"""Contact and flow: the catheter stays out of the walls, the force is the series stiffness
of catheter and wall, a cantilever's analytical compliance, flow drag's magnitude."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import forward
from icenav.sim.anatomy import BASE2ANATOMY, EXAMPLE_VIEWS, default_phantom
from icenav.sim.conditions import build_twin
from icenav.sim.contact import (
    STRUCTURES,
    ContactModel,
    ContactParams,
    FlowParams,
    Walls,
    catheter_nodes,
)

PHANTOM = default_phantom()
WALLS = Walls(PHANTOM, BASE2ANATOMY)


def test_nodes_follow_the_kinematics_arc() -> None:
    """The reconstructed arc ends where the kinematics put the section's end and the image
    centre, for bends in any plane."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = np.array([*rng.uniform(-1.2, 1.2, 2), rng.uniform(-3, 3), rng.uniform(-20, 20)])
        tip = forward(q)
        pts, tan = catheter_nodes(tip, np.array([0.0, 60.0, 70.0]))
        np.testing.assert_allclose(pts[0], [0, 0, q[3]], atol=1e-9)
        np.testing.assert_allclose(pts[2], tip[:3, 3], atol=1e-9)
        np.testing.assert_allclose(tan[1], tip[:3, 2], atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(tan, axis=1), 1.0, atol=1e-12)


def test_compliance_is_the_cantilevers() -> None:
    """Straight section, a load at its end: deflection F L^3 / 3 EI (Euler-Bernoulli), a
    symmetric positive semi-definite compliance."""
    p = ContactParams(base_compliance_mm_per_n=0.0, n_segments=64)
    model = ContactModel(None, p)
    shape = model.shape(forward(np.zeros(4)))
    c = shape.compliance
    end = p.n_section_nodes - 1  # node at s = L
    L, ei = 60.0, p.bending_stiffness_nmm2
    assert c[end, end, 0, 0] == pytest.approx(L**3 / (3 * ei), rel=2e-3)
    assert c[end, end, 2, 2] == pytest.approx(0.0, abs=1e-12)  # axial: rigid
    n = c.shape[0]
    flat = c.transpose(0, 2, 1, 3).reshape(3 * n, 3 * n)
    np.testing.assert_allclose(flat, flat.T, atol=1e-9)
    assert np.linalg.eigvalsh(flat).min() > -1e-9
    # the image centre, rigidly beyond the end: deflection + slope x offset
    expected = L**3 / (3 * ei) + L**2 / (2 * ei) * 10.0
    assert shape.tip_row[end, 0, 0] == pytest.approx(expected, rel=2e-3)


def test_no_contact_in_the_example_views() -> None:
    """The example views keep the catheter clear of the walls at end-diastole."""
    model = ContactModel(WALLS)
    for q in EXAMPLE_VIEWS.values():
        tip = forward(np.asarray(q))
        sol = model.solve(model.shape(tip), tip, 0.0)
        assert sol.force_n == 0.0
        np.testing.assert_array_equal(sol.tip2base, tip)


@pytest.mark.parametrize("q", [(0.6, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0), (0.8, 0, 0, -20.0)])
def test_a_bend_into_the_wall_is_stopped(q: tuple[float, ...]) -> None:
    """A bend that would put the catheter through the wall: a positive force, the deflected
    catheter (nearly) out of the wall, the tip moved back towards the blood."""
    model = ContactModel(WALLS)
    tip = forward(np.asarray(q))
    shape = model.shape(tip)
    d_free, _, _ = WALLS.distance(shape.points, 0.0)
    assert np.max(d_free + 1.65) > 2.0  # the free catheter would be in the wall
    sol = model.solve(shape, tip, 0.0)
    assert 0.0 < sol.force_n < 1.0
    assert {c.structure for c in sol.contacts} <= set(STRUCTURES)
    deflected = model.shape(sol.tip2base)
    d_after, _, _ = WALLS.distance(deflected.points[shape.tip_index :], 0.0)
    d_before, _, _ = WALLS.distance(shape.points[shape.tip_index :], 0.0)
    assert np.max(d_after) < np.max(d_before) - 1.0


def test_force_is_the_series_stiffness_for_one_contact() -> None:
    """One node against a wall: f = p / (n^T C n + 1 / k_wall), Eq. (C4)."""
    model = ContactModel(WALLS)
    tip = forward(np.array([0.6, 0.0, 0.0, 0.0]))
    shape = model.shape(tip)
    d, _, mat = WALLS.distance(shape.points, 0.0)
    pen = d + 1.65
    j = int(np.argmax(pen))
    n = WALLS.normals(mat[j : j + 1])[0]
    f = model._lcp(shape.compliance[j : j + 1, j : j + 1], n[None], pen[j : j + 1])[0]
    expected = pen[j] / (n @ shape.compliance[j, j] @ n + 1.0 / 0.12)
    assert f == pytest.approx(expected, rel=1e-9)


def test_flow_drag_moves_the_tip_over_the_beat() -> None:
    """Drag 1/2 rho C_d d v^2 per length (C5): sub-millimetre tip motion over a beat, none
    outside the flow waves."""
    model = ContactModel(None, flow=FlowParams(), phantom=PHANTOM, base2anatomy=BASE2ANATOMY)
    tip = forward(np.asarray(EXAMPLE_VIEWS["aortic_valve"]))
    shape = model.shape(tip)
    period = PHANTOM.motion.period_s
    moves = [model.solve(shape, tip, k * period / 40).deflection_mm for k in range(40)]
    assert 0.05 < max(moves) < 2.0
    assert min(moves) == 0.0  # between the waves (phase 0.40-0.45, 0.70-0.82)
    speed, _ = model.flow_speed(0.575 * period)  # peak of the E wave
    assert speed == pytest.approx(0.25)
    loads = model.flow_loads(shape, 0.575 * period)
    assert loads is not None
    per_mm = 0.5 * 1060 * 1.1 * 3.3e-3 * 0.25**2 * 1e-3  # N per mm of catheter at most
    assert np.linalg.norm(loads, axis=1).max() <= per_mm * 10.0 + 1e-12


def test_the_walls_evaluate_each_point_on_its_own() -> None:
    """The contact solve asks the moving walls for the free and the flow-bent nodes in one
    call: each row's distance, shape and material point equal those of a call of its own
    (in vivo: beat, beat-to-beat shape and breathing)."""
    twin = build_twin("in-vivo", 100, 0, lambda: 0.0)
    walls = twin.plant.contact.walls if twin.plant.contact is not None else None
    assert walls is not None
    rng = np.random.default_rng(9)
    for _ in range(50):
        a = rng.normal(0.0, 15.0, (8, 3))
        b = a + rng.normal(0.0, 0.3, (8, 3))
        t = float(rng.uniform(0.0, 60.0))
        both = walls.distance(np.concatenate([a, b]), t)
        for got, one, two in zip(both, walls.distance(a, t), walls.distance(b, t), strict=True):
            assert np.array_equal(got, np.concatenate([one, two]))


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ConfigurationError, match="wall_stiffness"):
        ContactParams(wall_stiffness_n_per_mm=0.0)
    with pytest.raises(ConfigurationError, match="n_section_nodes"):
        ContactParams(n_section_nodes=1)
    with pytest.raises(ConfigurationError, match="early_filling"):
        FlowParams(early_filling_m_s=-1.0)
    with pytest.raises(ConfigurationError, match="flow drag needs"):
        ContactModel(None, flow=FlowParams())
    assert math.isclose(ContactParams().catheter_radius_mm, 1.65)
