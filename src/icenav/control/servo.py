"""Closed-loop correction of the tip pose from the EM tracker (beyond the paper).

The elasticity map F and the hysteresis compensator are feed-forward: whatever they do not
model (the knob play's dependence on the other knob, the vessel's extra friction, the
roll and twist play) stays in the tip pose. A catheter with an EM sensor at its tip (the
paper attaches one for its evaluation; some clinical ICE catheters carry one) can measure
that error while it moves and correct it. :class:`TipPoseServo` is an integral controller
on the tracked pose: after every measurement it computes the joint correction that removes
the pose error in the model's tip frame, by damped, weighted least squares on the model's
body Jacobian (``icenav.geometry.jacobian.jacobian``), and adds a fraction ``gain`` of it to the
correction it keeps::

    e_k = [R_m^T (p_t - p_m) ; w vee(log(R_m^T R_t))]          # body pose error (mm, mm)
    dq_k = (J_w^T J_w + lambda^2 I)^-1 J_w^T e_k,  J_w = diag(1, 1, 1, w, w, w) J(q_k)
    c_{k+1} = clip(c_k + gain * clip(dq_k, +-max_step), +-max_correction)

``R_t, p_t`` the intended pose, ``R_m, p_m`` the measured one (base frame), ``w`` the
rotation weight (mm per rad). The correction is added to the model joint state before the
compensation, so the play inverse also pre-shapes it, or to the motor command when the
command path was computed ahead (the loop's integral action absorbs the difference between
the two). Integral action is what lets it cross the transmission's play: a correction
against the last direction first takes up the play, and the error that remains keeps
growing the correction until the tip moves.

What it cannot remove: the tracker's own error at the tip's position (its field
distortion, about 1.3 mm RMS on the twin, as the paper's tracker); it drives the *measured*
pose to the target, so the true pose keeps that offset. Evaluations report both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite, check_transform
from icenav.errors import ConfigurationError
from icenav.geometry.jacobian import jacobian
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry
from icenav.geometry.se3 import body_pose_error

__all__ = ["PoseServoConfig", "TipPoseServo", "body_pose_error"]  # the last from geometry.se3


def _tuple4(name: str, unit: str, values: tuple[float, float, float, float]) -> None:
    if len(values) != 4 or not all(math.isfinite(float(v)) and float(v) > 0 for v in values):
        raise ConfigurationError(
            f"{name} must be 4 finite values > 0 ({unit}) for phi1, phi2, phi3, d4, got {values}"
        )


@dataclass(frozen=True)
class PoseServoConfig:
    """Settings of :class:`TipPoseServo`."""

    gain: float = 0.5
    """Fraction of the least-squares correction applied per measurement, in (0, 1]. Chosen
    on development catheters 50-52 in the straight and steep vessels (of 0.2, 0.3, 0.5,
    0.8): 0.3 lags the wider plays of the steep vessel (3.1 mm at 60 deg against 1.6),
    0.8 rings against the knob play (docs/calibration.md)."""
    rotation_weight_mm_per_rad: float = 30.0
    """w: how many mm of position error one radian of orientation error is worth (> 0);
    30 mm/rad weighs 1 deg like 0.52 mm."""
    damping: float = 2.0
    """lambda: damping of the least squares (mm, > 0); keeps steps small near the straight
    catheter, where the knob directions degenerate."""
    max_step: tuple[float, float, float, float] = field(
        default=(math.radians(2.0), math.radians(2.0), math.radians(2.0), 0.5)
    )
    """Largest change of the correction per measurement (rad, rad, rad, mm)."""
    max_correction: tuple[float, float, float, float] = field(
        default=(math.radians(20.0), math.radians(20.0), math.radians(20.0), 3.0)
    )
    """Largest correction kept (rad, rad, rad, mm): the servo never moves the joints
    further than this from the feed-forward command."""

    def __post_init__(self) -> None:
        g = float(self.gain)
        if not math.isfinite(g) or not 0.0 < g <= 1.0:
            raise ConfigurationError(f"gain must be in (0, 1], got {g}")
        for name, unit in (("rotation_weight_mm_per_rad", "mm/rad"), ("damping", "mm")):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v <= 0.0:
                raise ConfigurationError(f"{name} must be finite and > 0 {unit}, got {v}")
        _tuple4("max_step", "rad, rad, rad, mm", self.max_step)
        _tuple4("max_correction", "rad, rad, rad, mm", self.max_correction)


class TipPoseServo:
    """Integral pose correction from tracked tip poses (see the module docstring).

    Parameters
    ----------
    config : PoseServoConfig
    geometry : CatheterGeometry
        Model geometry for the Jacobian.
    """

    def __init__(
        self,
        config: PoseServoConfig | None = None,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    ) -> None:
        self.config = PoseServoConfig() if config is None else config
        if not isinstance(self.config, PoseServoConfig):
            raise ConfigurationError(
                f"config must be a PoseServoConfig, got {type(self.config).__name__}"
            )
        self.geometry = geometry
        self._step = np.array(self.config.max_step, dtype=np.float64)
        self._limit = np.array(self.config.max_correction, dtype=np.float64)
        self._c = np.zeros(4)
        self.n_updates = 0
        """Measurements used so far."""
        self.n_missing = 0
        """Measurements that were missing (the correction held)."""

    @property
    def correction(self) -> Array:
        """The current joint correction (4,) (rad, rad, rad, mm); a copy."""
        return self._c.copy()

    def reset(self) -> None:
        """Forget the correction (e.g. before a new motion)."""
        self._c = np.zeros(4)
        self.n_updates = 0
        self.n_missing = 0

    def update(
        self, q_model: ArrayLike, target_tip2base: ArrayLike, measured_tip2base: ArrayLike | None
    ) -> Array:
        """Take one measurement and return the new correction (4,).

        Parameters
        ----------
        q_model : array-like, shape (4,)
            Model joint state the feed-forward aims at (rad, rad, rad, mm): where the
            Jacobian is evaluated.
        target_tip2base : array-like, shape (4, 4)
            Intended pose of the image centre frame (base frame, mm).
        measured_tip2base : array-like, shape (4, 4), or None
            Tracked pose (base frame, mm); None when the tracker had no pose (MISSING):
            the correction is held, never guessed.
        """
        q = check_finite(q_model, "q_model").ravel()
        if q.shape != (4,):
            raise ConfigurationError(f"q_model must have shape (4,), got {q.shape}")
        target = check_transform(target_tip2base, "target_tip2base")
        if measured_tip2base is None:
            self.n_missing += 1
            return self._c.copy()
        measured = check_transform(measured_tip2base, "measured_tip2base")
        cfg = self.config
        w = cfg.rotation_weight_mm_per_rad
        err = body_pose_error(target, measured, w)
        jac = jacobian(q, self.geometry, check=False).copy()
        jac[3:] *= w
        lam2 = cfg.damping**2
        dq = np.linalg.solve(jac.T @ jac + lam2 * np.eye(4), jac.T @ err)
        dq = np.clip(dq, -self._step, self._step)
        self._c = np.clip(self._c + cfg.gain * dq, -self._limit, self._limit)
        self.n_updates += 1
        return self._c.copy()
