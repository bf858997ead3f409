"""Our dense + hysteresis compensation as the controller's compensation (beyond the
paper): model joint states <-> motor joint states through the per-tendon transmission.

The paper's F (:class:`icenav.compensation.elasticity.ElasticityMap`) is a fixed map of the knobs.
The
per-tendon model of :mod:`icenav.compensation.transmission` is not: what a motor command achieves
depends
on where the tendons' friction bands and the roll's play sit, that is on the history of the
commands. :class:`TendonKnobMap` therefore keeps that state and is told every motor command
the robot is sent (:meth:`TendonKnobMap.observe`, which the controller calls each cycle,
whoever moves the robot: the operator in knob mode, a path, a spin). Asking it is pure:

- :meth:`~TendonKnobMap.model_to_motor`: the motor command that brings the catheter from its
  present state to a model joint state (4,), or the commands of a whole model path (n, 4)
  executed in order from the present state; nothing is committed;
- :meth:`~TendonKnobMap.motor_to_model`: the model joint state the catheter is in now.

Chain (the ``dense+hysteresis`` condition of ``icenav eval spin``,
one sample at a time, as ``icenav eval spin`` drives it too)::

    model q -> twist pre-shape (direction of the roll) -> F_eff (knobs)
            -> tendon inverse (knobs) and roll play inverse (phi3) -> motor q

What it leaves out of that condition, on purpose: the Savitzky-Golay filter (a stream of
set-points has no future samples; F_eff is a smoothed RBF already) and the tracker-bias shift
(which aims the *true* tip where the tracker reads the intended one: in a procedure without a
tracker the true tip is what counts; the bias still keeps F_eff bias-free). Translation passes
takes the section's axial excess when its length differs from the model's
(:mod:`icenav.compensation.section_length`; its play is not identified).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.compensation.hysteresis import JointHysteresis
from icenav.compensation.transmission import TendonCompensator, TransmissionCalibration
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry

__all__ = ["TendonKnobMap"]


class TendonKnobMap:
    """The per-tendon dead-zone / hysteresis compensation with F, with state.

    Parameters
    ----------
    calibration : TransmissionCalibration
        From :func:`icenav.calibration.catheter.fit_catheter` (the ``dense+hysteresis``
        procedure) or
        :func:`~icenav.compensation.transmission.build_transmission`, with the roll's per-joint
        model
        (``calibration.compensator.roll``: its play, and the roll's and the twist's play
        against the bend, :meth:`~icenav.compensation.hysteresis.HysteresisCompensator.roll_extra`
        and ``twist_extra``); without one the roll passes through.
    q_motor : array-like, shape (4,)
        Motor joint state the catheter rests at now (rad, rad, rad, mm): the state is a
        relaxed transmission there.
    geometry : CatheterGeometry
        Knob limits and knob ratio (the intended bend of a model state is
        ``knob_ratio * hypot(phi1, phi2)``).
    """

    def __init__(
        self,
        calibration: TransmissionCalibration,
        q_motor: ArrayLike = (0.0, 0.0, 0.0, 0.0),
        *,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    ) -> None:
        if not isinstance(calibration, TransmissionCalibration):
            raise ConfigurationError(
                f"calibration must be a TransmissionCalibration, got {type(calibration).__name__}"
            )
        self.calibration = calibration
        """The calibration behind the map."""
        self.geometry = geometry
        self._f = calibration.effective_map
        old = calibration.compensator
        self._knobs = TendonCompensator(
            calibration.fit.model,
            None,
            knob_limit=old.knob_limit,
            dead_zone_ramp=old.dead_zone_ramp,
        )
        roll = old.roll
        self._roll: JointHysteresis | None = None if roll is None else roll.joints[2]
        self._plays = roll  # the roll's and the twist's play against the bend
        self._section = calibration.section  # the section's length: its axial excess
        self._x3 = 0.0  # last motor roll (rad)
        self._p3 = 0.0  # the roll's play output: the section's roll (rad)
        self._i = 0.0  # the image frame's roll after the distal twist play (rad)
        self.reset(q_motor)

    # --- state ---------------------------------------------------------------------------

    def reset(self, q_motor: ArrayLike) -> None:
        """A relaxed transmission at motor joint state ``q_motor`` (4,): plays centred."""
        q = self._check(q_motor, "q_motor", single=True)
        self._knobs.reset(q)
        self._x3 = self._p3 = self._i = float(q[2])

    def observe(self, q_motor: ArrayLike) -> None:
        """The robot was sent ``q_motor`` (4,): advance the tendons, the roll's play and the
        distal twist play (the twin's T9 and T9b structure: motor -> section -> image)."""
        self._advance(self._check(q_motor, "q_motor", single=True))

    def _advance(self, q: Array) -> None:
        self._knobs.advance(float(q[0]), float(q[1]))
        x3 = float(q[2])
        self._x3 = x3
        if self._roll is None:
            self._p3 = self._i = x3
            return
        bend, psi = self._model_bend()
        m = self._roll
        w = m.backlash + m.backlash_slope * abs(x3) + self._roll_extra(bend, psi)
        self._p3 = min(max(self._p3, x3 - w), x3 + w)
        h = self._twist_extra(bend, psi)
        self._i = min(max(self._i, self._p3 - h), self._p3 + h)

    def _roll_extra(self, bend: float, direction: float) -> float:
        """The roll's extra play (rad) at a model ``bend`` (rad) in ``direction`` (rad in the
        knob plane; a law of the bend alone ignores it)."""
        return 0.0 if self._plays is None else float(self._plays.roll_extra(bend, direction))

    def _twist_extra(self, bend: float, direction: float) -> float:
        return 0.0 if self._plays is None else float(self._plays.twist_extra(bend, direction))

    def _model_bend(self) -> tuple[float, float]:
        """Model bend (rad) of the present effective knobs and its direction in the knob
        plane (rad, ``atan2(phi2, phi1)`` of the model knobs)."""
        z1, z2 = self._knobs.effective_knobs
        k = self._f.motor_to_model(np.array([z1, z2, 0.0, 0.0]), check=False)
        bend = self.geometry.knob_ratio * math.hypot(float(k[0]), float(k[1]))
        return bend, math.atan2(float(k[1]), float(k[0]))

    # --- the map -------------------------------------------------------------------------

    @staticmethod
    def _turn(a: float, b: float, t: float) -> tuple[float, float]:
        """Knobs (a, b) of a model state whose image frame is turned by t about its own axis
        (with phi3 + t): ``R_z(phi3 + t) R_z(theta - t) ... = R_z(phi3) R_z(theta) ... R_z(t)``
        (as :meth:`icenav.compensation.hysteresis.HysteresisCompensator.preshape_model`)."""
        c, s = math.cos(t), math.sin(t)
        return c * a + s * b, -s * a + c * b

    def _present_model(self) -> Array:
        """The model joint state (4,) of the present state (d4 NaN): the section's state from
        F_eff^-1 of the effective knobs and the section's roll, turned by the twist."""
        z1, z2 = self._knobs.effective_knobs
        p3 = self._p3 if self._roll is None else float(self._roll.dead_zone_out(self._p3))
        section = self._f.motor_to_model(np.array([z1, z2, p3, 0.0]), check=False)
        t = self._i - self._p3
        a, b = self._turn(float(section[0]), float(section[1]), t)
        return np.array([a, b, p3 + t, float("nan")])

    def _command(self, q: Array) -> Array:
        """The motor command (4,) for model state q from the present state (not advanced)."""
        a, b, phi3 = float(q[0]), float(q[1]), float(q[2])
        bend = self.geometry.knob_ratio * math.hypot(a, b)
        # the plays are looked up by the direction of the *section's* plane, as the state
        # advances them (_model_bend): the image frame's direction turned by the twist t
        psi = math.atan2(b, a)
        # (SL1): the translation takes what the section's length adds along the shaft
        out = np.array([0.0, 0.0, phi3, float(q[3]) - float(self._section.axial_excess(bend))])
        if self._roll is None:
            t = 0.0
        else:
            # the image must move: the section leads it by the twist play (it pushes at the
            # play's edge); else the twist stays as it is
            side = 1.0 if phi3 < self._i - 1e-12 else -1.0 if phi3 > self._i + 1e-12 else 0.0
            if side == 0.0:
                t = self._i - self._p3
            else:
                # t = side h(bend, psi + t): a fixed point (h changes slowly with the
                # direction), so the image lands where the advance will put it
                t = side * self._twist_extra(bend, psi)
                for _ in range(3):
                    t = side * self._twist_extra(bend, psi + t)
            psi = psi + t
        sa, sb = self._turn(a, b, -t)  # the section's model state: phi3 - t, turned back
        lim = self.geometry.knob_limit
        section = np.array([min(max(sa, -lim), lim), min(max(sb, -lim), lim), phi3 - t, 0.0])
        eff = self._f.model_to_motor(section, check=False)
        out[0], out[1] = self._knobs.knob_command(float(eff[0]), float(eff[1]))
        if self._roll is not None:
            m = self._roll
            p = float(m.dead_zone_inverse(float(eff[2])))
            extra = self._roll_extra(bend, psi)
            if p > self._p3 + 1e-12:
                out[2] = m.play_inverse(p, 1.0, extra)
            elif p < self._p3 - 1e-12:
                out[2] = m.play_inverse(p, -1.0, extra)
            else:
                out[2] = self._x3  # the section is there: stay inside the play
        return out

    def model_to_motor(self, q_model: ArrayLike, *, check: bool = True) -> Array:
        """Motor command(s) from the present state: (4,) for one model joint state, (n, 4)
        for a model path executed in order (the state is simulated along it and then
        restored). Nothing is committed; :meth:`observe` does that."""
        q = self._check(q_model, "q_model") if check else np.asarray(q_model, dtype=np.float64)
        if q.ndim == 1:
            return self._command(q)
        saved = self._save()
        try:
            out = np.empty_like(q)
            for i, row in enumerate(q):
                out[i] = self._command(row)
                self._advance(out[i])
            return out
        finally:
            self._restore(saved)

    def motor_to_model(self, q_motor: ArrayLike, *, check: bool = True) -> Array:
        """The model joint state (4,) the catheter is in once ``q_motor`` (4,) is the last
        command: the present state advanced to it, not committed. d4 is the commanded one."""
        q = (
            self._check(q_motor, "q_motor", single=True)
            if check
            else np.asarray(q_motor, dtype=np.float64)
        )
        saved = self._save()
        try:
            self._advance(q)
            out = self._present_model()
        finally:
            self._restore(saved)
        bend = self.geometry.knob_ratio * math.hypot(float(out[0]), float(out[1]))
        out[3] = float(q[3]) + float(self._section.axial_excess(bend))
        return out

    def _save(self) -> tuple[Any, float, float, float]:
        return (self._knobs.state(), self._x3, self._p3, self._i)

    def _restore(self, saved: tuple[Any, float, float, float]) -> None:
        knobs, self._x3, self._p3, self._i = saved
        self._knobs.set_state(knobs)

    @staticmethod
    def _check(q: ArrayLike, name: str, single: bool = False) -> Array:
        arr = check_finite(q, name)
        if single and arr.shape != (4,):
            raise ShapeError(f"{name} must have shape (4,), got {arr.shape}")
        if arr.shape[-1:] != (4,) or arr.ndim > 2:
            raise ShapeError(f"{name} must have shape (4,) or (n, 4), got {arr.shape}")
        return arr
