"""What the control loop reads besides the robot: the tracked tip pose (never waited for)
and the cycle-averaged EM pose of the refinement (Eq. R1 of
:mod:`icenav.refinement.cycle_pose`) over the loop's sample buffer."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from icenav._typing import Array
from icenav.devices.tracker import PoseSampleBuffer
from icenav.errors import ConfigurationError

__all__ = ["cycle_pose", "tip_pose_now"]


def tip_pose_now(tracker: Any) -> Array | None:
    """(4, 4) the tracked tip pose in the base frame now (mm): the tracker's newest sample
    through its registration; None without a tracker, a registration or a VALID sample, or
    when the tracker fails (non-blocking; the force check then falls back to Eq. F1)."""
    if tracker is None:
        return None
    try:
        frame = tracker.get_frame()
        registration = tracker.registration
        if frame.sensor2tracker is None or registration is None:
            return None
        return np.asarray(registration.tip2base(frame.sensor2tracker), np.float64)
    except Exception:  # noqa: BLE001 - no pose this cycle
        return None


def cycle_pose(
    buffer: PoseSampleBuffer | None,
    respiration: Any,
    cardiac_phase: Callable[[float], float] | None,
    window_s: float,
    rate_hz: float,
) -> Any:
    """The tip pose sensor of the refinement's EM stage: the buffered samples of the last
    ``window_s`` (s) averaged over complete breaths (respiratory signal), else complete beats
    (ECG), else plain over the whole window (a
    :class:`icenav.refinement.cycle_pose.CycleAveragedPose`). The catheter must have been
    still that long."""
    from icenav.refinement.cycle_pose import CycleAveragedPose  # scipy on use

    if buffer is None:
        raise ConfigurationError("the cycle-averaged pose needs a tracker (no sample buffer)")
    return CycleAveragedPose(buffer, respiration, cardiac_phase, window_s=window_s,
                             rate_hz=rate_hz)  # fmt: skip
