"""Settings of the control loop."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icenav._validation import check_finite, check_positive
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry
from icenav.recovery.drift import DEFAULT_DRIFT_MM
from icenav.recovery.force import CHECK_MARGIN_FRACTION, CHECK_MARGIN_N, DEFAULT_HOLD_S

__all__ = ["ControllerConfig"]


@dataclass(frozen=True)
class ControllerConfig:
    """Settings of the control loop."""

    rate_hz: float = 100.0
    """Control rate (Hz); the loop is tested at 100 and 500 Hz."""
    max_velocity: tuple[float, float, float, float] = (
        math.radians(60.0),
        math.radians(60.0),
        math.radians(90.0),
        10.0,
    )
    """Per-joint speed limit of every command (rad/s, rad/s, rad/s, mm/s)."""
    watchdog_s: float = 0.25
    """Operator input older than this counts as released (s)."""
    publish_every: int = 1
    """Publish a snapshot every this many cycles."""
    image_rate_hz: float = 20.0
    """Rate of the live ICE image (Hz), when an imager is configured."""
    backbone_points: int = 30
    """Points per drawn bending section."""
    background_plan_vertices: int = 2_000
    """From this roadmap size on, go-to-view plans in a background thread (the robot holds
    meanwhile) and a new view's shortest-path tree is prepared in the background (it was
    20,000: a plan inside the cycle then took up to 50 ms of CPU, 100-300 ms on a busy
    machine; see docs/safety.md, soak)."""
    plan_in_process: bool = True
    """Run the background Dijkstra of go-to-view / a new view's tree in a worker process
    (``Roadmap.tree_job(isolate=True)``): scipy's Dijkstra holds the GIL for its whole run,
    so in a thread it would stall the control loop (see the soak in docs/safety.md)."""
    gc_full_every_s: float = 300.0
    """With the real-time loop's GC policy (:meth:`Controller.settle_gc`): run a full
    garbage collection at most this often (s), between cycles, in a cycle's idle time."""
    spin_feedback: bool = True
    """Servo the spin on the EM tracker when one is configured with a registration
    (``tracker.registration``: tracker2base and sensor2tip): :class:`icenav.control.spin.SpinTask`
    with a :class:`icenav.control.servo.TipPoseServo` (``docs/calibration.md``, section 4b)."""
    plan_settle_s: float = 0.1
    """Wait at each tracked state of a calibration before reading the tracker (s); the
    dense + hysteresis sweeps and circles move 5-6 deg at a time (the whole calibration
    takes about 9.9 minutes at the controller's pace: ``icenav eval spin --costs``)."""
    calibration_ramp_s: float = 0.1
    """Ramp of each calibration move (s): most moves are short (5 rad/s^2 at 0.5 rad/s)."""
    stall_estop_s: float = 1.0
    """The supervisor e-stops the robot when the real-time loop has not finished a cycle
    for this long (s)."""
    geometry: CatheterGeometry = DEFAULT_GEOMETRY
    """Catheter geometry and joint limits (the motor limits equal the model limits)."""
    force_margin_n: float = CHECK_MARGIN_N
    """Absolute margin of a return's force check (N), Eqs. (F1, F2) of
    :mod:`icenav.recovery.force` (with a force channel only)."""
    force_margin_fraction: float = CHECK_MARGIN_FRACTION
    """Relative margin of a return's force check (fraction of the recorded force)."""
    force_hold_s: float = DEFAULT_HOLD_S
    """Time the force must stay above its limit before a return stops (s), Eq. (F4)."""
    force_drift_mm: float = DEFAULT_DRIFT_MM
    """Largest tip motion with the motors still before a return starts (mm), Eq. (F5)."""
    refine_window_s: float = 9.0
    """Window of the cycle-averaged EM pose of "refine view" and of the pose saved with a
    view (s): about 2.5 breaths gives 2 complete ones (``icenav.refinement.cycle_pose``)."""

    def __post_init__(self) -> None:
        check_positive(self.rate_hz, "rate_hz", "Hz")
        if self.rate_hz > 2000:
            raise ConfigurationError(f"rate_hz must be <= 2000 Hz, got {self.rate_hz} Hz")
        check_positive(self.watchdog_s, "watchdog_s", "s")
        check_positive(self.image_rate_hz, "image_rate_hz", "Hz")
        check_positive(self.gc_full_every_s, "gc_full_every_s", "s")
        v = check_finite(self.max_velocity, "max_velocity", "rad/s, rad/s, rad/s, mm/s")
        if v.shape != (4,) or np.any(v <= 0):
            raise ConfigurationError(
                f"max_velocity must be 4 positive values (rad/s, rad/s, rad/s, mm/s), got {v}"
            )
        if int(self.publish_every) < 1:
            raise ConfigurationError(f"publish_every must be >= 1 cycle, got {self.publish_every}")
        if not (math.isfinite(self.plan_settle_s) and 0.0 <= self.plan_settle_s <= 10.0):
            raise ConfigurationError(
                f"plan_settle_s must be in [0, 10] s, got {self.plan_settle_s} s"
            )
        check_positive(self.calibration_ramp_s, "calibration_ramp_s", "s")
        check_positive(self.refine_window_s, "refine_window_s", "s")
        for name in ("force_margin_n", "force_margin_fraction", "force_hold_s", "force_drift_mm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 100.0):
                raise ConfigurationError(
                    f"{name} must be in [0, 100] (N, fraction, s or mm), got {value}"
                )
        if not (math.isfinite(self.stall_estop_s) and 0.05 <= self.stall_estop_s <= 60.0):
            raise ConfigurationError(
                f"stall_estop_s must be in [0.05, 60] s, got {self.stall_estop_s} s"
            )

    @property
    def dt(self) -> float:
        """Control period (s)."""
        return 1.0 / self.rate_hz
