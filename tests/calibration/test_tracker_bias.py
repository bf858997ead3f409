"""Tests of icenav.calibration.tracker_bias: the roll circles and the fit of the tracker's
base-frame field bias (Eq. TB1), on synthetic stops and on the twin (whose field is not of the
fit's affine form), and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.tracker_bias import (
    choose_tracker_bias,
    fit_tracker_bias,
    fit_tracker_bias_from,
    held_out_rms,
    roll_circle_path,
    roll_circle_plan,
)
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import forward
from icenav.sim import CatheterPlant, EMTracker

DEG = math.pi / 180


def _rz(r: float) -> np.ndarray:
    c, s = math.cos(r), math.sin(r)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _synthetic_stops(
    rng: np.random.Generator,
    b0: np.ndarray,
    grad: np.ndarray,
    noise: float,
    field: object = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
    """Roll-circle stops of a catheter whose knob-frame tips P_k are the model's plus a
    random elastic deviation, measured through the affine field b0 + grad x (plus
    ``field(x)`` if given)."""
    path, mask = roll_circle_path()
    pose = np.cumsum(~mask) - 1
    lag = rng.uniform(-2.0, 2.0, size=pose.max() + 1) * DEG  # the roll play, per circle
    tips = [
        forward(np.array([a, 0.0, 0.0, 0.0]))[:3, 3] + rng.normal(0.0, 2.0, 3)
        for a in path[~mask, 0]
    ]
    q, t, k = [], [], []
    for row, meas, kk in zip(path, mask, pose, strict=True):
        if not meas:
            continue
        x = _rz(row[2] + lag[kk]) @ tips[kk]
        pose_ = np.eye(4)
        extra = np.zeros(3) if field is None else field(x)  # type: ignore[operator]
        pose_[:3, 3] = x + b0 + grad @ x + extra + rng.normal(0.0, noise, 3)
        q.append(row)
        t.append(pose_)
        k.append(kk)
    return np.array(q), np.array(t), np.array(k), tips


def _roll_spread(correct: object, tip: np.ndarray, b0: np.ndarray, grad: np.ndarray) -> float:
    """Largest distance (mm) between the corrected tips of a roll circle turned back to roll 0:
    0 when the correction leaves only what turns with the roll."""
    back = []
    for r in np.arange(0, 360, 45) * DEG:
        x = _rz(r) @ tip
        m = x + b0 + grad @ x
        back.append(_rz(r).T @ correct(m))  # type: ignore[operator]
    arr = np.array(back)
    return float(np.max(np.linalg.norm(arr - arr.mean(axis=0), axis=1)))


def test_roll_circles_approach_every_stop_with_increasing_roll() -> None:
    path, mask = roll_circle_path()
    assert path.shape == (36, 4) and int(mask.sum()) == 32
    pose = np.cumsum(~mask) - 1
    for k in range(4):
        rolls = path[pose == k, 2]
        assert np.all(np.diff(rolls) > 0)  # the pre-roll, then each stop, increasing
        assert np.ptp(path[pose == k, 0]) == 0.0 and np.all(path[pose == k, 1] == 0.0)


def test_fit_recovers_the_roll_dependent_part_of_a_known_field() -> None:
    rng = np.random.default_rng(4)
    for _ in range(20):
        b0 = rng.normal(0.0, 1.5, 3)
        grad = rng.normal(0.0, 0.02, (3, 3))
        q, t, k, tips = _synthetic_stops(rng, b0, grad, noise=0.02)
        est = fit_tracker_bias(q, t, k)
        assert est.rms_residual_mm < 0.1
        # identifiable (and all that matters): the corrected tips of a roll circle must turn
        # rigidly with the roll, as the true ones do (the tracked ones do not)
        for tip in tips:
            assert _roll_spread(lambda m: m, tip, b0, grad) > 0.3
            assert _roll_spread(est.correct_positions, tip, b0, grad) < 0.05


def test_no_field_gives_no_roll_dependent_bias() -> None:
    rng = np.random.default_rng(5)
    q, t, k, tips = _synthetic_stops(rng, np.zeros(3), np.zeros((3, 3)), noise=0.0)
    est = fit_tracker_bias(q, t, k)
    for tip in tips:
        x = np.array([_rz(r) @ tip for r in np.linspace(0, 2 * math.pi, 9)])
        b = est.at(x)
        assert np.max(np.abs(b[:, :2])) < 1e-6


def test_on_the_twin_the_roll_dependent_bias_is_found() -> None:
    plant = CatheterPlant(seed=53)
    tracker = EMTracker(plant, seed=53)
    est = fit_tracker_bias_from(run_visits(plan_visits(roll_circle_plan()), plant.move, tracker))
    t2b = tracker.config.tracker2base

    def true_bias(x: np.ndarray) -> np.ndarray:
        p = np.linalg.inv(t2b) @ np.append(x, 1.0)
        b, _ = tracker.distortion_at(p[:3])
        return np.asarray(t2b[:3, :3] @ b)

    def tracked(x: np.ndarray) -> np.ndarray:
        return x + true_bias(x)

    worst, before = 0.0, 0.0
    for a in (20, 40, 60):
        tip = forward(np.array([a * DEG, 0.0, 0.0, 0.0]))[:3, 3]
        raw, fixed = [], []
        for r in np.arange(0, 360, 45) * DEG:
            m = tracked(_rz(r) @ tip)
            raw.append(_rz(r).T @ m)
            fixed.append(_rz(r).T @ est.correct_positions(m))
        for arr, name in ((np.array(raw), "raw"), (np.array(fixed), "fixed")):
            spread = float(np.max(np.linalg.norm(arr - arr.mean(axis=0), axis=1)))
            if name == "raw":
                before = max(before, spread)
            else:
                worst = max(worst, spread)
    # the field is not exactly affine; the part that does not turn with the roll (what makes
    # the tip orbit during a spin) drops from over 1 mm to a few tenths
    assert before > 1.0
    assert worst < 0.5
    assert est.n_samples == 32


def test_bad_input_is_refused() -> None:
    with pytest.raises(ConfigurationError, match="three roll stops"):
        roll_circle_path(rolls=(0.0, 1.0))
    with pytest.raises(ConfigurationError, match="90 deg"):
        roll_circle_path(bends=(2.0,))
    q = np.zeros((4, 4))
    t = np.tile(np.eye(4), (4, 1, 1))
    with pytest.raises(ConfigurationError, match=">= 3 tracked stops"):
        fit_tracker_bias(q, t, np.array([0, 0, 1, 1]))
    with pytest.raises(ShapeError):
        fit_tracker_bias(q, t[:3], np.array([0, 0, 0, 0]))


def _wave(rng: np.random.Generator, wavelength: float) -> object:
    """A smooth non-affine field: three plane waves of ``wavelength`` (mm), 1 mm each."""
    w = rng.normal(size=(3, 3))
    w *= 2 * math.pi / wavelength / np.linalg.norm(w, axis=1, keepdims=True)
    ph = rng.uniform(0, 2 * math.pi, 3)
    amp = rng.normal(0.0, 1.0, (3, 3))
    return lambda x: np.sin(w @ x + ph) @ amp


def _spread(est: object, measured: object, tips: list[np.ndarray]) -> float:
    """RMS spread (mm) of the corrected tips of roll circles through ``tips``, turned back
    to roll 0 (0: the correction leaves only what turns with the roll)."""
    out = []
    for p in tips:
        back = [
            _rz(r).T @ est.correct_positions(measured(_rz(r) @ p))  # type: ignore[attr-defined, operator]
            for r in np.arange(0, 360, 45) * DEG
        ]
        arr = np.array(back)
        out.append(np.sum((arr - arr.mean(axis=0)) ** 2, axis=1))
    return float(np.sqrt(np.mean(out)))


def test_the_held_out_circles_choose_the_quadratic_field_only_where_it_predicts_better() -> None:
    rng = np.random.default_rng(7)
    for _ in range(4):
        b0, grad = rng.normal(0.0, 1.5, 3), rng.normal(0.0, 0.02, (3, 3))
        # an affine field: the quadratic form does not predict the inner circles better
        q, t, k, _ = _synthetic_stops(rng, b0, grad, noise=0.05)
        assert held_out_rms(q, t, k, quadratic=True) > 0.9 * held_out_rms(q, t, k, quadratic=False)
        assert choose_tracker_bias(q, t, k).quadratic is None
        # a curved field (a 150 mm wave): it does, and the chosen field leaves the tips of
        # each circle turning more rigidly with the roll than the affine one
        field = _wave(rng, 150.0)
        q, t, k, tips = _synthetic_stops(rng, b0, grad, noise=0.05, field=field)
        chosen = choose_tracker_bias(q, t, k)
        assert chosen.quadratic is not None and chosen.centre_mm is not None
        affine = fit_tracker_bias(q, t, k)

        mid = [forward(np.array([a * DEG, 0.0, 0.0, 0.0]))[:3, 3] for a in (35.0, 60.0)]

        def measured(
            x: np.ndarray, f: object = field, b: np.ndarray = b0, g: np.ndarray = grad
        ) -> np.ndarray:
            return np.asarray(x + b + g @ x + f(x))  # type: ignore[operator]

        assert _spread(chosen, measured, mid) < 0.8 * _spread(affine, measured, mid)


def test_a_held_out_check_needs_three_circles() -> None:
    rng = np.random.default_rng(8)
    q, t, k, _ = _synthetic_stops(rng, np.zeros(3), np.zeros((3, 3)), noise=0.05)
    two = k <= 1
    with pytest.raises(ConfigurationError, match=">= 3 roll circles"):
        held_out_rms(q[two], t[two], k[two], quadratic=True)
    assert choose_tracker_bias(q[two], t[two], k[two]).quadratic is None
