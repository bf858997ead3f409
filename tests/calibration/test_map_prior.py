"""Tests of icenav.calibration.map_prior: the product line's mean tip over the knob plane,
turned each way (M0), and the short calibration's F as that mean plus the samples'
interpolated difference (M1, M2). The catheters here are not of the twin's form: a play on
each knob, then a warp of the knob plane with a three-lobed swirl and a per-catheter
turn and gain, then the model's kinematics."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from icenav.calibration.map_prior import MapPrior, make_map_prior, stop_senses, turned_positions
from icenav.calibration.play_prior import PlayPrior, load_play_prior, save_play_prior
from icenav.calibration.short import RING_RADII, ring_path
from icenav.compensation.calibration_set import CalibrationSet
from icenav.compensation.elasticity import ElasticityMap
from icenav.errors import ConfigurationError, FileFormatError
from icenav.geometry.kinematics import forward

DEG = math.pi / 180


def line_catheter(turn: float, gain: float, swirl: float, play: float = 2 * DEG) -> Callable:
    """A catheter of the line: its drive (a motor knob path (n, 2) from rest -> tips (n, 3),
    knob frame). Play ``play`` on each knob, then the knob plane turned by ``turn``, scaled
    by ``gain`` and swirled by ``swirl`` rad at most, three lobes around the origin."""

    def drive(path: np.ndarray) -> np.ndarray:
        p = np.zeros(2)
        eff = np.empty((len(path), 2))
        for i, q in enumerate(np.asarray(path, dtype=np.float64)):
            p = np.minimum(np.maximum(p, q - play), q + play)
            eff[i] = p
        r = np.hypot(eff[:, 0], eff[:, 1])
        a = np.arctan2(eff[:, 1], eff[:, 0])
        a = a + turn + swirl * np.sin(3 * a) * (r / (90 * DEG)) ** 2
        r = gain * r * (1.0 - 0.15 * (r / (90 * DEG)) ** 2)
        q = np.zeros((len(path), 4))
        q[:, 0], q[:, 1] = r * np.cos(a), r * np.sin(a)
        return forward(q, check=False)[:, :3, 3]

    return drive


LINE = [line_catheter(0.10, 1.05, 0.12), line_catheter(0.06, 0.97, 0.10)]
NEW = line_catheter(0.08, 1.02, 0.11)


RINGS = ring_path(RING_RADII, 10, 1, both_ways=True)[:, :2]


def short_samples(drive: Callable) -> CalibrationSet:
    """The new catheter's five points (reached straight out from rest) and its rings' stops
    turned counter-clockwise (the short plan's rings driven from rest; F+ is built on
    them)."""
    five = np.array([[0, 0], [60, 0], [0, 60], [-60, 0], [0, -60]], dtype=np.float64) * DEG
    tips = [drive(np.linspace([0.0, 0.0], k, 7)[1:])[-1] for k in five]
    ccw = stop_senses(RINGS) > 0
    x = np.vstack([five, RINGS[ccw]])
    p = np.vstack([np.array(tips), drive(RINGS)[ccw]])
    q = np.zeros((len(x), 4))
    q[:, :2] = x
    t = np.tile(np.eye(4), (len(x), 1, 1))
    t[:, :3, 3] = p
    return CalibrationSet(q_motor=q, tip2base=t, method="short")


def circle(radius: float) -> np.ndarray:
    a = np.linspace(0.0, 2 * math.pi, 48, endpoint=False) + 7 * DEG
    return np.stack([radius * np.cos(a), radius * np.sin(a)], -1)


@pytest.fixture(scope="module")
def prior() -> MapPrior:
    return make_map_prior(LINE, "line", ["a", "b"], RINGS, radius_step=5 * DEG)


def test_the_line_prior_corrects_the_short_interpolant_between_the_stops(
    prior: MapPrior,
) -> None:
    samples = short_samples(NEW)
    truth = turned_positions(NEW, 1, radius_step=5 * DEG)
    plain = ElasticityMap.build(samples)  # the short calibration's own F (thin-plate)
    with_prior = prior.position(samples, sense=1)
    scaled = prior.position(samples, sense=1, scaled=True)
    x = samples.q_motor[:, :2]
    # (M1) at a sample: the line's mean there plus the sample's difference from the line's
    # reading of it
    expected = (
        samples.tip2base[:, :3, 3] - prior.expected(x, 1) + prior.mean_position(x[:, 0], x[:, 1], 1)
    )
    np.testing.assert_allclose(with_prior(x[:, 0], x[:, 1]), expected, atol=1e-6)
    for radius in (38 * DEG, 62 * DEG):  # between the rings (25 / 50 / 75 deg)
        c = circle(radius)
        t = truth(c[:, 0], c[:, 1])

        def rms(f: Callable, c: np.ndarray = c, t: np.ndarray = t) -> float:
            return float(np.sqrt(np.mean(np.sum((f(c[:, 0], c[:, 1]) - t) ** 2, -1))))

        base = rms(plain.real_position)
        assert base > 0.3  # the short interpolant misses the swirl between the stops
        assert rms(with_prior) < 0.2 * base
        assert rms(scaled) < 0.3 * base


def test_each_sense_has_its_own_mean_and_the_built_map_follows_it(prior: MapPrior) -> None:
    c = circle(50 * DEG)
    ccw, cw = prior.mean_position(c[:, 0], c[:, 1], 1), prior.mean_position(c[:, 0], c[:, 1], -1)
    # the knobs' play lags the tip behind the turn: the senses differ by about 2 x the lag
    assert 0.5 < float(np.mean(np.linalg.norm(ccw - cw, axis=-1))) < 10.0
    samples = short_samples(NEW)
    fmap = prior.build_map(samples, sense=1)
    at = prior.position(samples, sense=1)
    np.testing.assert_allclose(
        fmap.real_position(c[:, 0], c[:, 1]), at(c[:, 0], c[:, 1]), atol=0.05
    )
    assert fmap.calibration.method == "short+map-prior"
    with pytest.raises(ConfigurationError, match="sense"):
        prior.mean_position(0.0, 0.0, 2)


def test_the_map_prior_round_trips_in_the_play_prior_file(prior: MapPrior, tmp_path: Path) -> None:
    plays = PlayPrior("line", ("a", "b"), (0.0,), (0.5, 1.0), ((0.5, 1.0),), ((0.5, 1.0),))
    path = tmp_path / "prior.json"
    save_play_prior(dataclasses.replace(plays, map=prior), path)
    back = load_play_prior(path)
    assert back.map is not None and back.map.catheters == ("a", "b")
    np.testing.assert_allclose(back.map.positions, prior.positions, atol=1e-3)
    np.testing.assert_allclose(back.map.reverse, prior.reverse, atol=1e-3)
    doc = json.loads(path.read_text())
    # a file of version 1 (no map) still reads
    path.write_text(json.dumps({k: v for k, v in doc.items() if k != "map"} | {"version": 1}))
    assert load_play_prior(path).map is None
    doc["map"]["reverse_mm"] = doc["map"]["reverse_mm"][:-1]
    path.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError, match=r"prior.json: malformed map prior"):
        load_play_prior(path)
    with pytest.raises(ConfigurationError, match="one name each"):
        make_map_prior(LINE, "line", ["a"], RINGS)
