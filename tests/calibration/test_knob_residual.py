"""Tests of icenav.calibration.knob_residual and of the circle residual's choice by the
held-out circle (icenav.calibration.transmission.identify_transmission_form), on synthetic
catheters whose miss is a wave no capstan band makes."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from icenav.calibration.knob_residual import circle_residual, effective_miss
from icenav.calibration.transmission import (
    FORM_MARGIN,
    circle_blocks,
    circle_path,
    identify_transmission_form,
)
from icenav.compensation.transmission import TendonTransmission, TransmissionFit
from icenav.errors import ConfigurationError
from tests.support.transmission import TRUTH, synthetic_catheter, wave_residual

DEG = math.pi / 180


def _identity_fit(model: TendonTransmission) -> TransmissionFit:
    """A fit whose static map G is the identity (degree 1: terms 1, z2, z1)."""
    coef = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    return TransmissionFit(model, 0.0, 0.0, coef, 100, 1, degree=1)


def test_the_table_of_a_known_wave_is_recovered_from_the_circles() -> None:
    """Tracked knobs of a catheter whose effective knobs are its band's plus a known wave
    (G the identity): the miss mapped back through G is the wave, and the table fitted per
    circle and sense gives it back on the circles to 0.01 deg (a wave of 3 deg that does not
    change with the radius between 10 and 80 deg, so each circle's is its Fourier series)."""
    res = wave_residual(radii=(10 * DEG, 80 * DEG), grow=False)
    band = TendonTransmission(ap=TRUTH.ap, rl=TRUTH.rl, wrap=TRUTH.wrap, friction=TRUTH.friction)
    circles = circle_path((25 * DEG, 45 * DEG, 65 * DEG), step=5 * DEG)
    y = replace(band, residual=res).simulate(circles, x_start=[0.0, 0.0])
    y[::17] = np.nan  # MISSING samples
    fit = _identity_fit(band)
    z = band.simulate(circles, x_start=[0.0, 0.0])
    miss = effective_miss(fit, z, y)
    assert np.all(np.isnan(miss[::17]))
    blocks = circle_blocks(circles)
    got = circle_residual(fit, circles, y, blocks, [1, 2, 3])
    assert len(got.radii) == 3 and got.harmonics == 2
    want = res.along(z, 0.0, (0.0, 0.0))
    back = got.along(z, 0.0, (0.0, 0.0))
    qr = np.hypot(circles[:, 0], circles[:, 1])
    on = np.zeros(len(qr), dtype=bool)
    for c in (1, 2, 3):
        on |= (blocks == c) & (qr >= 0.99 * np.max(qr[blocks == c]))
    on &= np.hypot(z[:, 0], z[:, 1]) >= got.radii[0]  # below the first circle: tapered (KR2)
    assert float(np.max(np.abs(back - want)[on])) < 0.01 * DEG
    with pytest.raises(ConfigurationError, match="settled samples"):
        circle_residual(fit, circles, y, blocks, [1], keep=np.arange(len(y)) % 3 == 0)


def test_the_circle_residual_is_kept_only_where_it_predicts_the_held_out_circle_better() -> None:
    """On a catheter with the wave the outer circles' table, interpolated in radius, predicts
    the middle circle better and is kept (the model's form ``+residual``); on one of the
    model's own form it is scored and not kept."""
    circles = circle_path((25 * DEG, 45 * DEG, 65 * DEG), step=8 * DEG)
    middle = circle_blocks(circles) == 2
    band = TendonTransmission(ap=TRUTH.ap, rl=TRUTH.rl, wrap=TRUTH.wrap, friction=TRUTH.friction)
    kw = {"forms": ("added",), "extensions": (), "degree": 3, "train_nfev": 2, "refit_nfev": 1}
    kw["residual"] = True  # off by default (TRIED_RESIDUAL): the choice itself is tested here
    for truth, kept in ((replace(band, residual=wave_residual()), True), (band, False)):
        motion = synthetic_catheter(truth, np.random.default_rng(14), circles, 0.05 * DEG)
        fit = identify_transmission_form([motion], [middle], initial=band, **kw)
        scores = dict(fit.held_out_rms)
        assert set(scores) == {"added", "added+residual"}
        assert (scores["added+residual"] < scores["added"] * (1.0 - FORM_MARGIN)) == kept
        assert (fit.model.residual is not None) == kept
        assert fit.model.form == ("added+residual" if kept else "added")
