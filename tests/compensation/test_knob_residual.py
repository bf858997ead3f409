"""Tests of icenav.compensation.knob_residual: the circle residual's table (KR1-KR3), its
sense of turning, and the per-tendon transmission and its inverse with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.compensation.knob_residual import KnobResidual, update_sense
from icenav.compensation.transmission import TendonCompensator, TendonTransmission
from icenav.errors import ConfigurationError, ShapeError
from tests.support.transmission import TRUTH, wave_residual

DEG = math.pi / 180


def test_the_table_is_each_circles_series_interpolated_in_radius_tapered_at_the_centre() -> None:
    res = wave_residual(amplitude=3.0 * DEG, radii=(30 * DEG, 60 * DEG))
    psi = 0.7
    # on the outer circle: a0 + b1 sin psi + a2 cos 2 psi, the sign of b1 the sense's
    for s in (1.0, -1.0):
        d1, d2 = res.delta(60 * DEG * math.cos(psi), 60 * DEG * math.sin(psi), s)
        assert d1 == pytest.approx(3 * DEG * (s * math.sin(psi) + 0.5 * math.cos(2 * psi)))
        assert d2 == pytest.approx(0.9 * DEG)
    # never turned: the mean of both senses; beyond the largest circle: constant
    d1, _ = res.delta(90 * DEG * math.cos(psi), 90 * DEG * math.sin(psi), 0.0)
    assert d1 == pytest.approx(1.5 * DEG * math.cos(2 * psi))
    # half-way between the circles: the mean of their values; below the first: tapered
    a = res.delta(45 * DEG * math.cos(psi), 45 * DEG * math.sin(psi), 1.0)
    b = res.delta(30 * DEG * math.cos(psi), 30 * DEG * math.sin(psi), 1.0)
    c = res.delta(60 * DEG * math.cos(psi), 60 * DEG * math.sin(psi), 1.0)
    assert a == pytest.approx(tuple(0.5 * (x + y) for x, y in zip(b, c, strict=True)))
    e = res.delta(15 * DEG * math.cos(psi), 15 * DEG * math.sin(psi), 1.0)
    assert e == pytest.approx(tuple(0.5 * x for x in b))
    assert res.delta(0.0, 0.0, 1.0) == (0.0, 0.0)
    assert res.table.shape == (2, 2, 5, 2)
    with pytest.raises(ConfigurationError, match="radii"):
        KnobResidual(radii=(0.5, 0.2), harmonics=0, coefficients=(0.0,) * 8)
    with pytest.raises(ShapeError, match="coefficients"):
        KnobResidual(radii=(0.5,), harmonics=1, coefficients=(0.0,) * 8)


def test_the_sense_is_set_by_turns_about_the_centre_and_kept_by_radial_moves() -> None:
    r = 40 * DEG
    assert update_sense(0.0, (r, 0.0), (r * math.cos(0.05), r * math.sin(0.05))) == 1.0
    assert update_sense(1.0, (r, 0.0), (r * math.cos(0.05), -r * math.sin(0.05))) == -1.0
    assert update_sense(-1.0, (r, 0.0), (2 * r, 0.0)) == -1.0  # a ray keeps it
    assert update_sense(1.0, (0.0, 0.0), (0.0, r)) == 1.0  # from the centre: no azimuth
    z = np.array([[r * math.cos(t), r * math.sin(t)] for t in np.linspace(0, 1, 5)])
    res = wave_residual()
    along = res.along(z, 0.0, (r, 0.0))
    assert along[-1] == pytest.approx(res.delta(*z[-1], 1.0))


def test_a_model_with_a_residual_steps_as_it_simulates_and_its_inverse_reaches_it() -> None:
    """The residual adds to the band's effective knobs with the sense the state carries:
    stepping sample by sample equals the simulation, which is the band's plus the table
    along it; the compensator's commands bring the model's effective knobs to a spin-like
    circle turned either way."""
    res = wave_residual()
    model = TendonTransmission(
        ap=TRUTH.ap, rl=TRUTH.rl, wrap=TRUTH.wrap, friction=0.6, residual=res
    )
    assert model.state_size == 5 and model.form == "added+residual"
    t = np.linspace(0.0, 2.0 * math.pi, 48)
    ray = np.stack([np.linspace(0.0, 50 * DEG, 10), np.zeros(10)], -1)
    for sense in (1.0, -1.0):
        circle = np.stack([50 * DEG * np.cos(t), sense * 50 * DEG * np.sin(t)], -1)
        path = np.vstack([ray, circle])
        z = model.simulate(path, x_start=[0.0, 0.0])
        band = TendonTransmission(ap=TRUTH.ap, rl=TRUTH.rl, wrap=TRUTH.wrap, friction=0.6)
        zb = band.simulate(path, x_start=[0.0, 0.0])
        np.testing.assert_allclose(z, zb + res.along(zb, 0.0, (0.0, 0.0)), atol=1e-12)
        d, prev, stepped = model.relaxed_state([0.0, 0.0]).tolist(), [0.0, 0.0], []
        for row in path.tolist():
            d = model.step(d, prev, row)
            prev = row
            stepped.append(model.effective(d))
        np.testing.assert_allclose(np.array(stepped), z, atol=1e-12)
        assert d[-1] == sense
        if sense > 0.0:
            continue  # the inverse: one sense (the cost of the root search)
        comp = TendonCompensator(model)
        targets = np.vstack([ray * 0.8, 0.8 * circle])
        got = []
        for z1, z2 in targets:
            x = comp.knob_command(z1, z2)
            comp.advance(*x)
            got.append(comp.effective_knobs)
        err = np.abs(np.array(got) - targets)[15:]
        assert float(np.max(err)) < 0.2 * DEG
