"""Shared helpers for tests on the disturbed twin."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from icenav.sim.disturbed import DisturbedTracker
from icenav.sim.tracker import EMTracker, TrackerConfig

EXACT = TrackerConfig(
    position_jitter_rms_mm=0.0,
    rotation_jitter_rms_rad=0.0,
    position_bias_rms_mm=0.0,
    rotation_bias_rms_rad=0.0,
    dropout_probability=0.0,
)
"""An EM tracker without jitter, bias or dropouts: it reports the true pose."""


def exact_tracker(plant: Any, clock: Callable[[], float], **config: Any) -> EMTracker:
    """An EM tracker of ``plant`` (the undisturbed plant a DisturbedTracker wraps) that
    reports the true pose (``config`` overrides :data:`EXACT`'s fields, e.g. latency_s)."""
    from dataclasses import replace

    return EMTracker(plant, seed=1, clock=clock, config=replace(EXACT, **config))


class WanderingTracker:
    """The twin's tracker with the tip carried about by a wall the operator cannot see
    move: offsets (base frame, mm) of periods no ECG phase explains, and ``jump`` (mm,
    along base x) from time ``t_jump`` on, as a moved patient would carry it."""

    def __init__(self, inner: DisturbedTracker) -> None:
        self.inner = inner
        self.t_jump = float("inf")
        self.jump = 8.0

    def _offset(self, t: float) -> np.ndarray:
        w = 2.0 * np.pi * t
        wander = 4.0 * np.array([np.sin(w / 1.7), np.sin(w / 2.9 + 1.0), np.sin(w / 5.3 + 2.0)])
        return wander + ([self.jump, 0.0, 0.0] if t >= self.t_jump else 0.0)

    def get_frame(self) -> Any:
        from icenav.devices.tracker import TrackerFrame

        frame = self.inner.get_frame()
        if frame.sensor2tracker is None:
            return frame
        t2b = np.asarray(self.inner.inner.config.tracker2base, np.float64)
        shift = np.eye(4)
        shift[:3, 3] = self._offset(float(frame.timestamp))
        s2t = np.linalg.inv(t2b) @ shift @ t2b @ np.asarray(frame.sensor2tracker)
        return TrackerFrame(frame.timestamp, s2t, frame.status, frame.quality)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)
