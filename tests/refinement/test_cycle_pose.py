"""The cycle-averaged pose, Eq. (R1): complete breaths (else beats, else all samples)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError, ShapeError
from icenav.refinement.cycle_pose import CycleAveragedPose, complete_cycles

RATE = 20.0
BREATH_S = 3.7
BEAT_S = 0.83


def _breath(t: np.ndarray) -> np.ndarray:
    """A bellows-like level: sin^4 pulses (0 at end-expiration, 1 at the peak)."""
    return np.sin(np.pi * np.mod(t, BREATH_S) / BREATH_S) ** 4


def _phase(t: float) -> float:
    return (t / BEAT_S) % 1.0


class _Stream:
    """A still catheter at ``static`` (x, y, z mm), moved 5 mm along z by breathing and
    1 mm along x by the beat; samples taken at RATE up to ``now``."""

    def __init__(self, static: tuple[float, float, float], now: float) -> None:
        self.static = np.asarray(static, np.float64)
        self.now = now
        self.calls = 0

    def pose(self, t: float) -> np.ndarray:
        out = np.eye(4)
        out[:3, 3] = self.static + [math.sin(2 * math.pi * _phase(t)), 0.0, 0.0]
        out[2, 3] += 5.0 * float(_breath(np.array(t)))
        return out

    def sample_window(self, duration_s: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        self.calls += 1
        n = int(round(duration_s * rate_hz))
        times = self.now - (n - 1 - np.arange(n)) / rate_hz
        return times, np.stack([self.pose(float(t)) for t in times])


def test_complete_breaths_cancel_the_breathing_wherever_the_window_starts() -> None:
    """Cut at inspiration onsets, the mean of a still catheter is the same whatever the
    respiratory phase the measurement ends at; a plain average over the same window is
    not (it is what the pose stage did before)."""
    cycle, plain = [], []
    for now in np.linspace(20.0, 20.0 + BREATH_S, 7, endpoint=False):
        stream = _Stream((1.0, 2.0, 3.0), float(now))
        times, poses = stream.sample_window(9.0, RATE)
        sel, window = complete_cycles(times, _breath(times), None)
        assert window.kind == "breath" and window.cycles in (1, 2)
        cycle.append(poses[sel, 2, 3].mean())
        plain.append(poses[-16:, 2, 3].mean())  # the last 0.8 s, as before
    assert np.ptp(cycle) < 0.15  # mm: whole breaths (the beat's residue remains)
    assert np.ptp(plain) > 2.0  # mm: the phase of the breath decides


def test_without_breathing_the_cut_is_at_the_r_waves() -> None:
    t = 10.0 + np.arange(60) / RATE
    phase = np.array([_phase(x) for x in t])
    sel, window = complete_cycles(t, np.zeros_like(t), phase)
    assert window.kind == "beat" and window.cycles >= 2
    assert phase[sel.start] < 0.1 and phase[sel.stop] < 0.1  # both ends at an R wave
    sel, window = complete_cycles(t, None, None)
    assert window.kind == "none" and sel == slice(0, len(t))
    with pytest.raises(ShapeError):
        complete_cycles(t, np.zeros(3), None)


def test_the_sensor_estimates_the_static_pose() -> None:
    stream = _Stream((4.0, -1.0, 60.0), 31.3)
    sensor = CycleAveragedPose(stream, _Resp(), _phase, window_s=9.0, rate_hz=RATE)
    pose = sensor.measure_tip2base()
    assert pose is not None and stream.calls == 1
    mean_breath = float(np.mean(_breath(np.linspace(0.0, BREATH_S, 1000))))
    np.testing.assert_allclose(pose[:3, 3], [4.0, -1.0, 60.0 + 5.0 * mean_breath], atol=0.12)
    assert sensor.last_window is not None and sensor.last_window.cycles >= 1
    with pytest.raises(ConfigurationError):
        CycleAveragedPose(object(), None, None)  # type: ignore[arg-type]


class _Resp:
    def signal(self, t: np.ndarray) -> np.ndarray:
        return _breath(np.asarray(t, np.float64))


class _Clock:
    def __init__(self) -> None:
        self.t = 10.0

    def __call__(self) -> float:
        return self.t


def test_the_expiration_gate_opens_in_the_end_expiratory_dwell_only() -> None:
    """Eq. (R3) on the sin^4 level: open where the level is in its lowest tenth and not
    rising (the dwell around the breath's start), closed through inspiration and its peak."""
    from icenav.refinement.cycle_pose import ExpirationGate

    class _Monitor:
        def signal(self, t: np.ndarray) -> np.ndarray:
            return _breath(np.asarray(t, np.float64))

    clock = _Clock()
    gate = ExpirationGate(_Monitor(), clock)
    opened = []
    for t in np.arange(20.0, 20.0 + 2 * BREATH_S, 0.05):
        clock.t = float(t)
        level = float(_breath(np.array(t)))
        rising = level > float(_breath(np.array(t - 0.1))) + 1e-6
        if gate():
            opened.append(t)
            assert level <= 0.1 and not rising
        elif level <= 0.05 and not rising:
            raise AssertionError(f"closed at t = {t:.2f} s in the dwell (level {level:.3f})")
    assert opened  # it opens in every breath ...
    phases = np.mod(np.asarray(opened), BREATH_S) / BREATH_S
    assert np.all((phases > 0.75) | (phases < 0.05))  # ... at the end of expiration only

    class _Flat:
        def signal(self, t: np.ndarray) -> np.ndarray:
            return np.zeros_like(np.asarray(t, np.float64))

    assert ExpirationGate(_Flat(), clock)()  # no breathing: nothing to wait for
    with pytest.raises(ConfigurationError, match="fraction"):
        ExpirationGate(_Flat(), clock, fraction=0.7)
