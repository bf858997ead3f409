"""Dead-zone and backlash (hysteresis) of each joint's transmission, and their inverse.

Beyond the paper (its Discussion leaves dead-zone and hysteresis to future work). Each
knob drives an antagonistic tendon pair through a long sheath: friction reverses with the
motion (a play / backlash loop of half-width ``r``) and slack in the pair leaves a dead-zone
of half-width ``d`` around the cross-over at ``c``. Per joint, from the commanded motor angle
``x`` to the *effective* angle ``z`` that reaches the bending section::

    r(x) = r0 + r1 |x|                                # play half-width (grows with tension)
    p_k = min(max(p_{k-1}, x_k - r(x_k)), x_k + r(x_k))   # play operator (backlash), H1
    z_k = sign(p_k - c) * max(|p_k - c| - d, 0)      # dead-zone around c, H2

(the backlash-plus-dead-zone model of tendon-sheath drives, e.g. Do et al., Mechatronics
2014; Kesner & Howe, ICRA 2011; the friction band, hence the play, widens with the tendon
tension, which grows with the knob angle: ``r1``). Its inverse pre-shapes commands: ``x``
solves ``x - s r(x) = p`` with ``s`` the current direction of motion of ``p`` (a state the
compensator keeps; at a reversal the command jumps across the play), and
``p = c + z + d * clip(z / eps, -1, 1)``: the dead-zone inverse, exact for ``|z| >= eps``
and a ramp across the dead-zone inside (error < eps), so the motors are never asked to
jump across the whole dead-zone at once.

The model is identified from a short up/down sweep of one joint (:func:`identify`): a grid
search over (r, d, c) with, for each, a linear least-squares fit of a static odd cubic
from ``z`` to the observed output (the tip's bend measured by the tracker, which also
carries the elastic nonlinearity), then a local refinement.

Composition with the elasticity map (model knob -> F -> hysteresis inverse -> motor)::

    z = F(phi_model)                 # effective angles that put the real tip there
    x = compensator.command(z)       # motor command
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.compensation.bend_play import PlayLaw
from icenav.errors import ConfigurationError

__all__ = [
    "HysteresisCompensator",
    "JointHysteresis",
]


@dataclass(frozen=True)
class JointHysteresis:
    """Backlash + dead-zone model of one joint's transmission (angles in rad)."""

    backlash: float = 0.0
    """r0: half-width of the play at x = 0 (rad); the loop is 2 r(x) wide."""
    backlash_slope: float = 0.0
    """r1: growth of the play half-width with |x| (rad/rad), in [0, 0.5]."""
    dead_zone: float = 0.0
    """d: half-width of the dead-zone around ``centre`` (rad)."""
    centre: float = 0.0
    """c: motor angle at the middle of the dead-zone (rad)."""
    smoothing: float = math.radians(0.5)
    """eps: width over which the inverse crosses the dead-zone (rad), > 0."""

    def __post_init__(self) -> None:
        # a bent roll's play with the twist's (the image frame's) can near 60 deg
        for name, top in (("backlash", 90.0), ("dead_zone", 45.0)):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v < 0.0 or v > math.radians(top):
                raise ConfigurationError(
                    f"{name} must be in [0, {math.radians(top):.4f}] rad ([0, {top:.0f}] deg), "
                    f"got {v} rad"
                )
        r1 = float(self.backlash_slope)
        if not math.isfinite(r1) or r1 < 0.0 or r1 > 0.5:
            raise ConfigurationError(f"backlash_slope must be in [0, 0.5] rad/rad, got {r1}")
        c = float(self.centre)
        if not math.isfinite(c) or abs(c) > math.radians(45.0):
            raise ConfigurationError(
                f"centre must be within +-{math.radians(45.0):.4f} rad (+-45 deg), got {c} rad"
            )
        e = float(self.smoothing)
        if not math.isfinite(e) or e <= 0.0:
            raise ConfigurationError(f"smoothing must be finite and > 0 rad, got {e} rad")

    def dead_zone_out(self, p: ArrayLike) -> Array:
        """H2: effective angle z for a play output p (rad)."""
        u = np.asarray(p, dtype=np.float64) - self.centre
        return np.sign(u) * np.maximum(np.abs(u) - self.dead_zone, 0.0)

    def dead_zone_inverse(self, z: ArrayLike) -> Array:
        """Continuous right-inverse of H2: p with H2(p) = z exactly for |z| >= eps and
        |H2(p) - z| < eps inside (a linear ramp across the dead-zone)."""
        zz = np.asarray(z, dtype=np.float64)
        return self.centre + zz + self.dead_zone * np.clip(zz / self.smoothing, -1.0, 1.0)

    def simulate(
        self, x_path: ArrayLike, p0: float | None = None, extra_width: ArrayLike | None = None
    ) -> Array:
        """Effective angles z (n,) for commanded angles x (n,), play state starting at p0
        (default: x_path[0], a relaxed start); ``extra_width`` (n,) widens the play per
        sample (rad; e.g. the roll's play growing with the bend)."""
        x = check_finite(x_path, "x_path", "rad").ravel()
        p0f = float(x[0]) if p0 is None else float(p0)
        extra = None if extra_width is None else np.asarray(extra_width, np.float64).ravel()
        p = _play(x, self.backlash, p0f, self.backlash_slope, extra)
        return self.dead_zone_out(p)

    def play_inverse(self, p: float, direction: float, extra_width: float = 0.0) -> float:
        """Command x whose play output is p when moving in ``direction`` (+1, -1; 0: x = p).

        Solves ``x - direction * (r0 + extra + r1 |x|) = p`` (monotone in x for r1 < 1).
        """
        if direction == 0.0:
            return p
        r0, r1 = self.backlash + extra_width, self.backlash_slope
        if direction > 0:
            x = (p + r0) / (1.0 - r1)
            return x if x >= 0.0 else (p + r0) / (1.0 + r1)
        x = (p - r0) / (1.0 + r1)
        return x if x >= 0.0 else (p - r0) / (1.0 - r1)


def _play(x: Array, r: float, p0: float, r1: float = 0.0, extra: Array | None = None) -> Array:
    """Play operator over a path (sequential); half-width r + r1 |x| (+ extra[k])."""
    out = np.empty_like(x)
    p = p0
    ex = [0.0] * x.size if extra is None else extra.tolist()
    for k, xk in enumerate(x.tolist()):
        w = r + r1 * abs(xk) + ex[k]
        lo = xk - w
        hi = xk + w
        if p < lo:
            p = lo
        elif p > hi:
            p = hi
        out[k] = p
    return out


class HysteresisCompensator:
    """Pre-shapes motor commands with the inverse backlash + dead-zone model, per joint.

    Keeps state: the last play output ``p`` and the direction of motion of each joint.
    Joints without a model (``None``) pass through. Joint order (phi1, phi2, phi3, d4).
    ``roll_play_per_bend`` (rad of play half-width per rad of bend) widens the roll's play
    with the bend of the bending section (a bent section rubs more); pass the bend (rad,
    e.g. the model bend of the intended pose, which compensation makes the true one) to
    :meth:`command`, else ``hypot(phi1, phi2)`` of the effective knobs stands in for it.
    """

    def __init__(
        self,
        joints: Sequence[JointHysteresis | None],
        roll_play_per_bend: float = 0.0,
        knob_play_per_bend: float = 0.0,
        twist_play_per_bend: float = 0.0,
        reversal_threshold: float = 0.0,
        *,
        roll_play: PlayLaw | None = None,
        twist_play: PlayLaw | None = None,
    ) -> None:
        if len(joints) != 4:
            raise ConfigurationError(f"joints must have 4 entries (phi1..d4), got {len(joints)}")
        for name, v in (
            ("roll_play_per_bend", roll_play_per_bend),
            ("knob_play_per_bend", knob_play_per_bend),
            ("twist_play_per_bend", twist_play_per_bend),
        ):
            fv = float(v)
            if not math.isfinite(fv) or fv < 0.0 or fv > 0.5:
                raise ConfigurationError(f"{name} must be in [0, 0.5] rad/rad, got {v!r}")
        rt = float(reversal_threshold)
        if not math.isfinite(rt) or rt < 0.0 or rt > math.radians(10.0):
            raise ConfigurationError(
                f"reversal_threshold must be in [0, {math.radians(10.0):.4f}] rad ([0, 10] deg), "
                f"got {reversal_threshold!r}"
            )
        self.reversal_threshold = rt
        """delta (rad): the wanted play output must come back by more than this from its
        furthest point before the compensator treats it as a reversal and jumps the command
        across the play. 0 is the exact inverse, which jumps the full play width (2 r) on every
        wiggle of a nearly still target; since the model's width is never exactly the
        plant's, each such jump moves the tip. With delta > 0, a small reversal is left to the
        play (error at most delta) instead."""
        k = float(roll_play_per_bend)
        self.joints: tuple[JointHysteresis | None, ...] = tuple(joints)
        """Model of each joint, or None."""
        self.roll_play_per_bend = k
        """Growth of the roll's play half-width with the bend (rad/rad)."""
        self.knob_play_per_bend = float(knob_play_per_bend)
        """Growth of a knob's play half-width with the *other* knob's angle (rad/rad): the
        other pair's bend adds sheath friction (capstan wrap)."""
        self.twist_play_per_bend = float(twist_play_per_bend)
        """Distal twist play per rad of bend (rad/rad): the image frame lags the roll about
        its own axis without moving the tip; see :meth:`preshape_model`."""
        self.roll_play = roll_play
        """The roll's extra play against the bend (:class:`~icenav.compensation.bend_play.BendPlay`,
        measured at several bends) or over the knob plane (``KnobPlanePlay``: against the bend
        and its direction); None: ``roll_play_per_bend * bend``."""
        self.twist_play = twist_play
        """The twist play against the bend; None: ``twist_play_per_bend * bend``."""
        self._p = [0.0, 0.0, 0.0, 0.0]
        self._dir = [0.0, 0.0, 0.0, 0.0]
        self._ext = [0.0, 0.0, 0.0, 0.0]

    def reset(
        self, q_effective: ArrayLike | None = None, direction: ArrayLike | None = None
    ) -> None:
        """Set the state: effective joint state (4,) (default 0) and direction of motion
        (+1, -1 or 0 for unknown, per joint; default 0: the first move decides)."""
        z = np.zeros(4) if q_effective is None else check_finite(q_effective, "q_effective")
        d = np.zeros(4) if direction is None else check_finite(direction, "direction")
        if z.shape != (4,) or d.shape != (4,):
            raise ConfigurationError("q_effective and direction must have shape (4,)")
        for j, m in enumerate(self.joints):
            self._p[j] = float(z[j]) if m is None else float(m.dead_zone_inverse(z[j]))
            self._dir[j] = float(np.sign(d[j]))
            self._ext[j] = self._p[j]

    def with_reversal_threshold(self, delta: float) -> HysteresisCompensator:
        """A fresh compensator (state reset) with the same models and ``reversal_threshold``
        = ``delta`` (rad)."""
        return self._fresh(reversal_threshold=delta)

    def with_plays(
        self, roll_play: PlayLaw | None, twist_play: PlayLaw | None
    ) -> HysteresisCompensator:
        """A fresh compensator (state reset) with the same models but the roll's and the
        twist's play laws (``roll_play`` / ``twist_play`` as the constructor takes them)."""
        return self._fresh(roll_play=roll_play, twist_play=twist_play)

    def _fresh(self, **changes: Any) -> HysteresisCompensator:
        kwargs: dict[str, Any] = {
            "roll_play_per_bend": self.roll_play_per_bend,
            "knob_play_per_bend": self.knob_play_per_bend,
            "twist_play_per_bend": self.twist_play_per_bend,
            "reversal_threshold": self.reversal_threshold,
            "roll_play": self.roll_play,
            "twist_play": self.twist_play,
        }
        return HysteresisCompensator(list(self.joints), **{**kwargs, **changes})

    def roll_extra(self, bend: ArrayLike, direction: ArrayLike | None = None) -> Array:
        """Extra half-width of the roll's play (rad) at ``bend`` (rad, any shape) in
        ``direction`` (rad in the knob plane, ``atan2(phi2, phi1)``, broadcast with ``bend``;
        a law of the bend alone ignores it; None: the AP knob's)."""
        if self.roll_play is not None:
            return self.roll_play(bend, direction)
        return self.roll_play_per_bend * np.abs(np.asarray(bend, dtype=np.float64))

    def twist_extra(self, bend: ArrayLike, direction: ArrayLike | None = None) -> Array:
        """Half-width of the distal twist play (rad) at ``bend`` (rad, any shape) in
        ``direction`` (rad, as :meth:`roll_extra`)."""
        if self.twist_play is not None:
            return self.twist_play(bend, direction)
        return self.twist_play_per_bend * np.abs(np.asarray(bend, dtype=np.float64))

    @property
    def direction(self) -> Array:
        """(4,) current direction of motion of each joint (+1, -1, 0 unknown)."""
        return np.array(self._dir)

    def command(self, q_effective: ArrayLike, bend: float | None = None) -> Array:
        """Motor command (4,) that gives the wanted effective joint state (4,); ``bend``
        (rad) is the bend of the section, for the roll's play."""
        z = check_finite(q_effective, "q_effective")
        if z.shape != (4,):
            raise ConfigurationError(f"q_effective must have shape (4,), got {z.shape}")
        out = np.empty(4)
        for j, m in enumerate(self.joints):
            zj = float(z[j])
            if m is None:
                out[j] = zj
                continue
            p = float(m.dead_zone_inverse(zj))
            self._update_direction(j, p)
            self._p[j] = p
            if j == 2:
                b = math.hypot(z[0], z[1]) if bend is None else float(bend)
                extra = float(self.roll_extra(b, math.atan2(z[1], z[0])))
            elif j < 2:
                extra = self.knob_play_per_bend * abs(float(z[1 - j]))
            else:
                extra = 0.0
            out[j] = m.play_inverse(p, self._dir[j], extra)
        return out

    def _update_direction(self, j: int, p: float) -> None:
        """Direction of motion of joint j's play output, with the reversal threshold: the
        furthest point reached in the current direction is kept, and the direction flips
        only when ``p`` comes back from it by more than ``reversal_threshold``."""
        d = self._dir[j]
        delta = self.reversal_threshold
        if d == 0.0:
            dp = p - self._p[j]
            if dp > 1e-12:
                self._dir[j] = 1.0
            elif dp < -1e-12:
                self._dir[j] = -1.0
            self._ext[j] = p
        elif d * (p - self._ext[j]) > 0.0:
            self._ext[j] = p  # further along the current direction
        elif d * (self._ext[j] - p) > max(delta, 1e-12):
            self._dir[j] = -d
            self._ext[j] = p

    def preshape_model(self, q_model_path: ArrayLike) -> Array:
        """Pre-shape a *model* joint path (n, 4) against the distal twist play.

        The twist play lets the image frame lag the roll about its own axis by up to
        ``h_t = twist_play_per_bend * bend`` while the roll moves. Turning the image frame
        about its own axis by ``delta`` without moving the tip is, in the constant-curvature
        model, ``phi3 += delta`` with the bending plane turned by ``-delta``::

            R_z(phi3 + delta) R_z(theta - delta) R_y(alpha) R_z(-(theta - delta))
                = R_z(phi3) R_z(theta) R_y(alpha) R_z(-theta) R_z(delta)

        so the path is shifted by ``delta = s * h_t`` ahead in the direction ``s`` of the roll
        motion (a play inverse whose state is that direction). Apply before F.
        """
        path = check_finite(q_model_path, "q_model_path")
        if path.ndim != 2 or path.shape[1] != 4:
            raise ConfigurationError(f"q_model_path must have shape (n, 4), got {path.shape}")
        out = path.copy()
        if self.twist_play is None and self.twist_play_per_bend == 0.0:
            return out
        direction = 0.0
        for i in range(path.shape[0]):
            if i > 0:
                d3 = path[i, 2] - path[i - 1, 2]
                if d3 > 1e-12:
                    direction = 1.0
                elif d3 < -1e-12:
                    direction = -1.0
            a, b = float(path[i, 0]), float(path[i, 1])
            delta = direction * float(self.twist_extra(math.hypot(a, b), math.atan2(b, a)))
            c, s_ = math.cos(delta), math.sin(delta)
            out[i, 0] = c * a + s_ * b  # bending plane turned by -delta
            out[i, 1] = -s_ * a + c * b
            out[i, 2] = path[i, 2] + delta
        return out

    def command_path(self, q_effective_path: ArrayLike, bends: ArrayLike | None = None) -> Array:
        """Motor commands (n, 4) for a path of wanted effective joint states (n, 4);
        ``bends`` (n,) rad as in :meth:`command`."""
        path = check_finite(q_effective_path, "q_effective_path")
        if path.ndim != 2 or path.shape[1] != 4:
            raise ConfigurationError(f"q_effective_path must have shape (n, 4), got {path.shape}")
        if bends is None:
            return np.array([self.command(row) for row in path])
        b = check_finite(bends, "bends", "rad").ravel()
        if b.size != path.shape[0]:
            raise ConfigurationError(f"bends must have {path.shape[0]} values, got {b.size}")
        return np.array([self.command(row, float(bi)) for row, bi in zip(path, b, strict=True)])

    def effective_path(self, q_motor_path: ArrayLike, q_start: ArrayLike | None = None) -> Array:
        """The model's effective joint states (n, 4) for motor commands (n, 4), from a
        relaxed state at ``q_start`` (motor, default the first command)."""
        path = check_finite(q_motor_path, "q_motor_path")
        if path.ndim != 2 or path.shape[1] != 4:
            raise ConfigurationError(f"q_motor_path must have shape (n, 4), got {path.shape}")
        start = path[0] if q_start is None else check_finite(q_start, "q_start")
        out = path.copy()
        for j, m in enumerate(self.joints):
            if m is not None and j < 2:
                extra = self.knob_play_per_bend * np.abs(path[:, 1 - j])
                out[:, j] = m.simulate(path[:, j], p0=float(start[j]), extra_width=extra)
            elif m is not None and j == 3:
                out[:, j] = m.simulate(path[:, j], p0=float(start[j]))
        m = self.joints[2]
        if m is not None:
            extra = self.roll_extra(
                np.hypot(out[:, 0], out[:, 1]), np.arctan2(out[:, 1], out[:, 0])
            )
            out[:, 2] = m.simulate(path[:, 2], p0=float(start[2]), extra_width=extra)
        return out


# --- identification ----------------------------------------------------------------------
