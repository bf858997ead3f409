"""Shared helpers for tests on the disturbed twin."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

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
