"""Image spinning as a controller task, open loop or closed on the EM tracker.

:class:`SpinTask` drives the paper's spin (the image plane turns 360 deg about the catheter
axis while the tip stays put) one set-point per control cycle:

    model path q_m(s) -> F (KnobMap.model_to_motor) -> + c (servo) -> play inverse -> motors

- the model path is :func:`icenav.geometry.trajectories.spin_trajectory` (inverse kinematics, so the
  model tip is fixed), the path parameter ``s`` runs at bounded joint speed with a
  trapezoidal rate (as :class:`icenav.control.tasks.PathTask`);
- ``F`` is the controller's compensation (identity without one);
- ``c`` is the correction of a :class:`icenav.control.servo.TipPoseServo`, updated once per *new*
  tracker frame (never twice on the same sample, held on MISSING) toward the intended pose
  ``forward(q_m(s))``; without a tracker the task is open loop;
- the play inverse (:class:`icenav.compensation.hysteresis.HysteresisCompensator`), when given,
pre-shapes
  the sum, so it also takes up the play for the servo's reversals (``docs/calibration.md``,
  section 4b: correcting after the inverse made the loop fight the play jumps).

The task never commands beyond the joint limits, and the servo's correction is bounded
(``PoseServoConfig.max_correction``), so a wrong tracker pose cannot take the catheter far
from the feed-forward path.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.compensation.hysteresis import HysteresisCompensator
from icenav.control.modes import Mode
from icenav.control.servo import TipPoseServo
from icenav.errors import InvalidValueError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward
from icenav.geometry.se3 import pose_mean as _average_poses
from icenav.geometry.se3 import rigid_inverse as _rigid_inverse

__all__ = ["SpinTask", "tracked_tip2base"]


def tracked_tip2base(tracker: Any) -> tuple[float, Array | None]:
    """The newest tracker frame as ``(timestamp s, tip2base (4, 4) mm or None)``.

    ``tip2base = tracker2base @ sensor2tracker @ inv(sensor2tip)`` with the tracker's
    registration (``tracker.registration``, an :class:`icenav.devices.registration.Registration`);
    None when the frame has no pose (MISSING, OUT_OF_VOLUME) or the tracker is not
    registered. Non-blocking: it reads ``get_frame()``, never waits for a sample.
    """
    frame = tracker.get_frame()
    registration = tracker.registration
    if frame.sensor2tracker is None or registration is None:
        return float(frame.timestamp), None
    return float(frame.timestamp), registration.tip2base(frame.sensor2tracker)


class SpinTask:
    """A spin (or any model-space path) with optional play inverse and EM closed loop.

    Parameters
    ----------
    q_model_path : array-like, shape (n, 4)
        Model joint states (rad, rad, rad, mm), e.g. ``spin_trajectory(...).q_model``;
        ``q_model_path[0]`` is where the robot is (in model terms).
    to_motor : callable
        ``(n, 4) or (4,) model -> motor`` joint states without play (F; identity if None).
    max_velocity : array-like, shape (4,)
        Joint speed limits (rad/s, rad/s, rad/s, mm/s).
    joint_limits : array-like, shape (4, 2)
        Commands are clipped to these (rad, rad, rad, mm).
    pose_source : callable, optional
        ``() -> (timestamp s, tip2base or None)``, e.g. ``lambda: tracked_tip2base(t)``;
        None: open loop.
    servo : TipPoseServo, optional
        The pose servo (default settings when a pose source is given).
    compensator : HysteresisCompensator, optional
        Play inverse applied to each command (its state is reset at the start, with the
        current command as relaxed state).
    speed_scale, ramp_s : float
        As :class:`icenav.control.tasks.PathTask`.
    hold_measured : bool
        With a pose source: hold the tip where the tracker *measures* it at the start (the
        intended poses become ``L @ forward(q_m)`` with ``L = measured_0 @ forward(q_m0)^-1``,
        ``measured_0`` the mean of the first ``reference_frames`` frames, taken while the
        task holds at the start), rather than at the model's tip (the paper's protocol,
        used by ``icenav eval spin``). What an operator expects: the image turns about
        where the catheter is. If no frame comes within ``reference_timeout_s`` the spin
        runs open loop.
    """

    mode = Mode.SPINNING

    def __init__(
        self,
        q_model_path: ArrayLike,
        to_motor: Callable[[Array], Array] | None,
        max_velocity: ArrayLike,
        joint_limits: ArrayLike,
        *,
        pose_source: Callable[[], tuple[float, Array | None]] | None = None,
        servo: TipPoseServo | None = None,
        compensator: HysteresisCompensator | None = None,
        speed_scale: float = 0.5,
        ramp_s: float = 0.3,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
        hold_measured: bool = False,
        reference_frames: int = 8,
        reference_timeout_s: float = 1.0,
    ) -> None:
        path = check_finite(q_model_path, "q_model_path")
        if path.ndim != 2 or path.shape[1] != 4 or path.shape[0] < 2:
            raise InvalidValueError(f"q_model_path must have shape (n >= 2, 4), got {path.shape}")
        v = check_finite(max_velocity, "max_velocity").ravel()
        lim = np.asarray(joint_limits, dtype=np.float64)  # +-inf: an unlimited joint
        if v.shape != (4,) or np.any(v <= 0) or lim.shape != (4, 2) or np.any(np.isnan(lim)):
            raise InvalidValueError(
                "max_velocity must be 4 values > 0 (rad/s, rad/s, rad/s, mm/s) and "
                f"joint_limits shape (4, 2); got {v.shape} and {lim.shape}"
            )
        if not 0.0 < speed_scale <= 1.0 or not ramp_s > 0.0:
            raise InvalidValueError(
                f"speed_scale must be in (0, 1] and ramp_s > 0 s, got {speed_scale}, {ramp_s}"
            )
        self.q_model_path = path
        self._to_motor = (lambda q: np.array(q, dtype=np.float64)) if to_motor is None else to_motor
        shaped = path if compensator is None else compensator.preshape_model(path)
        knob = geometry.knob_limit
        shaped[:, :2] = np.clip(shaped[:, :2], -knob, knob)
        self.feed_forward = np.asarray(self._to_motor(shaped), dtype=np.float64)
        """(n, 4) motor states without play or correction: F of the model path (turned ahead
        against the distal twist play when a compensator is given)."""
        self._knob_ratio = geometry.knob_ratio
        self.intended = forward(path, geometry, check=False)
        """(n, 4, 4) intended poses of the image centre frame (base frame, mm)."""
        self._lim = lim
        self.pose_source = pose_source
        self.servo = servo if servo is not None or pose_source is None else TipPoseServo()
        self.compensator = compensator
        if compensator is not None:
            compensator.reset(self.feed_forward[0])
        self.label = "spin 360 (EM closed loop)" if pose_source is not None else "spin 360"
        seg = np.abs(np.diff(self.feed_forward, axis=0)) / (v * speed_scale)
        self._cum = np.concatenate([[0.0], np.cumsum(seg.max(axis=1))])
        self._ramp = float(ramp_s)
        self._t = 0.0
        self._elapsed = 0.0
        self._last_stamp: float | None = None
        self.n_pose_updates = 0
        """Tracker frames used by the servo."""
        if reference_frames < 1 or not reference_timeout_s > 0:
            raise InvalidValueError(
                f"reference_frames must be >= 1 and reference_timeout_s > 0 s, got "
                f"{reference_frames}, {reference_timeout_s}"
            )
        self._hold = bool(hold_measured) and pose_source is not None
        self._ref_needed = int(reference_frames)
        self._ref_timeout = float(reference_timeout_s)
        self._ref_poses: list[Array] = []
        self._ref_waited = 0.0
        self.reference_correction: Array | None = None
        """L (4, 4), base frame: measured start pose @ inverse(model start pose), once set."""

    @property
    def duration(self) -> float:
        """Path time at full rate (s)."""
        return float(self._cum[-1])

    @property
    def progress(self) -> float:
        return 1.0 if self.duration == 0 else min(1.0, self._t / self.duration)

    def _at(self, t: float) -> tuple[Array, Array, Array]:
        """(model state, feed-forward motor state, intended pose) at path time t."""
        i = int(np.searchsorted(self._cum, t, side="right")) - 1
        i = min(max(i, 0), len(self._cum) - 2)
        span = self._cum[i + 1] - self._cum[i]
        f = 0.0 if span <= 0 else min(1.0, (t - self._cum[i]) / span)
        qm = (1 - f) * self.q_model_path[i] + f * self.q_model_path[i + 1]
        ff = (1 - f) * self.feed_forward[i] + f * self.feed_forward[i + 1]
        k = i + 1 if f >= 0.5 else i  # intended pose: the nearer sample's
        return qm, ff, self.intended[k]

    def _take_reference(self, dt: float) -> Array:
        """Hold at the start and average the first tracker frames into L."""
        assert self.pose_source is not None
        stamp, pose = self.pose_source()
        if stamp != self._last_stamp and pose is not None:
            self._ref_poses.append(pose)
        self._last_stamp = stamp
        self._ref_waited += dt
        if len(self._ref_poses) >= self._ref_needed:
            mean = _average_poses(np.stack(self._ref_poses))  # chordal mean rotation
            self.reference_correction = mean @ _rigid_inverse(self.intended[0])
        elif self._ref_waited >= self._ref_timeout:
            self._hold = False  # no tracker: open loop
            self.pose_source = None
            self.label = "spin 360 (open loop: no tracker pose)"
        first = self.feed_forward[0]
        out: Array = np.clip(
            first if self.compensator is None else self.compensator.command(first),
            self._lim[:, 0],
            self._lim[:, 1],
        )
        return out

    def next_command(self, q_measured: Array, dt: float) -> Array | None:
        """The next motor set-point (4,), or None when the spin is done."""
        if self._t >= self.duration:
            return None
        if self._hold and self.reference_correction is None:
            return self._take_reference(dt)
        self._elapsed += dt
        remaining = self.duration - self._t
        rate = min(1.0, self._elapsed / self._ramp, math.sqrt(2.0 * remaining / self._ramp))
        self._t = min(self.duration, self._t + dt * max(rate, 0.02))
        qm, ff, target = self._at(self._t)
        if self.reference_correction is not None:
            target = self.reference_correction @ target
        if self.pose_source is not None and self.servo is not None:
            stamp, pose = self.pose_source()
            if stamp != self._last_stamp:  # one update per tracker sample
                self._last_stamp = stamp
                self.servo.update(qm, target, pose)
                self.n_pose_updates += pose is not None
            ff = ff + self.servo.correction
        if self.compensator is None:
            cmd = ff
        else:  # the roll's play grows with the (intended) bend
            cmd = self.compensator.command(ff, self._knob_ratio * math.hypot(qm[0], qm[1]))
        out: Array = np.clip(cmd, self._lim[:, 0], self._lim[:, 1])
        return out
