"""Family ``nonlinear-play``: roll and twist plays that grow with bend times tendon tension.

A tendon of tension ``T`` that follows a curve of curvature ``kappa`` presses on its lumen
with a force ``T kappa`` per unit length (the tendon's distributed load on the backbone,
Rucker & Webster 2011). Over a section bent by ``alpha = kappa L`` the tendons press with
``N = alpha sum_i T_i``; the section's jacket turning against these taut, pressed tendons
meets a Coulomb friction torque ``mu r N``, which a torsional stiffness turns into a play.
Since the tensions themselves grow with the bend (and faster at large bends: strain
stiffening), the play grows about as the bend squared::

    h_r = h_r0 + c_r alpha sum_i T_i                                          (N1) roll
    roll <- clip(roll, phi3 - h_r, phi3 + h_r)
    h_t = c_t alpha sum_i T_i                                                  (N2) twist
    tip <- clip(tip, roll - h_t, roll + h_t)

The tendons' sheath friction is a Bouc-Wen hysteresis (Bouc 1967; Wen 1976; the survey of
Ismail, Ikhouane & Rodellar 2009), a smooth loop used for tendon-sheath drives: the
normalised friction state ``y`` in [-1, 1] of tendon i follows its proximal pull ``p``::

    dy/dp = (1 - (beta sgn(dp y) + gamma) |y|) / delta,   beta + gamma = 1          (N3)
    d_i = p_i - W_i y_i,   W_i = W_pair (1 + g_v Theta_vessel)                        (N4)

with ``beta`` = 0.75, ``gamma`` = 0.25 and ``delta`` = 1.5 W: at a reversal from saturation
the output stands still, then picks up smoothly (no sharp corner), and after a long motion
it lags by ``W``. Minor loops of a Bouc-Wen operator do not close (unlike a
Prandtl-Ishlinskii operator's): repeated small cycles drift. (N3) is integrated exactly
(it is linear in y between sign changes).

How it differs from the default twin and our compensation: the default's (and
``compensation/hysteresis.py``'s) roll and twist plays are ``h0 + h1 * bend``, linear in the
bend; here they grow with the product of bend and tension (about the bend squared), so a
line fitted at two bends is wrong at a third. The tendons have no capstan band
(``g+-``, ``transmission.py``): a Bouc-Wen loop whose width does not grow with tension.

Magnitudes (assumptions, not tuned to any method): ``c_r``, ``c_t`` make the plays equal to
the default twin's at a 50 deg bend (about 11 N of total tension); below it they are
smaller, above it larger. ``W`` = 0.12 mm makes the tendon loop about as wide as the
default's (6 deg of knob).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry
from icenav.sim.families.base import Pulls, SectionPlant, draw, family_rng, sample_params
from icenav.sim.params import PlantParams, Vessel

__all__ = ["BoucWen", "NonlinearPlayParams", "NonlinearPlayPlant"]

TAG = 0x9A7
"""Random-stream tag of the family."""

BETA = 0.75
"""Bouc-Wen beta of (N3) (with gamma = 1 - beta)."""
DELTA_PER_WIDTH = 1.5
"""delta / W of (N3): 1 + beta - gamma, so the output stands still at a reversal."""


@dataclass(frozen=True)
class NonlinearPlayParams:
    """Play parameters of one catheter of the family (lengths mm, angles rad, forces N)."""

    tendon_width_ap_mm: float = 0.12
    """W of the AP tendons (N4): lag after a long motion (mm of pull)."""
    tendon_width_rl_mm: float = 0.12
    """W of the RL tendons (mm)."""
    vessel_gain_per_rad: float = 0.25
    """g_v (N4): growth of W per rad of vessel curvature."""
    roll_play_rad: float = 0.014
    """h_r0 (N1): roll play of the relaxed section (rad)."""
    roll_play_per_n_rad: float = 0.0081
    """c_r (N1): roll play per N of total tension and rad of bend (rad / (N rad))."""
    twist_play_per_n_rad: float = 0.0135
    """c_t (N2): twist play per N of total tension and rad of bend (rad / (N rad))."""

    def __post_init__(self) -> None:
        for name, hi in (
            ("tendon_width_ap_mm", 2.0),
            ("tendon_width_rl_mm", 2.0),
            ("vessel_gain_per_rad", 5.0),
            ("roll_play_rad", 0.5),
            ("roll_play_per_n_rad", 0.1),
            ("twist_play_per_n_rad", 0.1),
        ):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and 0.0 <= v <= hi):
                raise ConfigurationError(f"{name} must be in [0, {hi}], got {v}")

    @classmethod
    def sample(cls, rng: np.random.Generator) -> NonlinearPlayParams:
        """A catheter's draw: every value +-20 % (uniform), as the default's plays."""
        n = cls()
        return cls(**{k: draw(rng, float(getattr(n, k)), 0.2) for k in n.__dataclass_fields__})


class BoucWen:
    """The Bouc-Wen lost motion of one tendon (N3)-(N4), n = 1, integrated exactly."""

    __slots__ = ("p", "y")

    def __init__(self) -> None:
        self.p = 0.0
        self.y = 0.0

    def reset(self, p: float) -> None:
        """Relaxed at pull p (no friction stored)."""
        self.p = p
        self.y = 0.0

    def __call__(self, p: float, width: float) -> float:
        """Distal pull (mm) after the proximal pull moved to p (mm); W = ``width`` (mm)."""
        dp = p - self.p
        self.p = p
        if width <= 0.0:
            self.y = 0.0
            return p
        if dp != 0.0:
            delta = DELTA_PER_WIDTH * width
            s = 1.0 if dp > 0 else -1.0
            y = s * self.y  # work in the direction of motion: dy'/d|p| with y' = s y
            travel = abs(dp)
            if y < 0.0:
                # against the stored friction: dy'/dx = (1 - a y') / delta, a = beta - gamma,
                # so y'(x) = 1/a + (y' - 1/a) e^(-a x / delta), which reaches 0 at x0
                a = 2.0 * BETA - 1.0
                x0 = delta * math.log(1.0 - a * y) / a
                if travel < x0:
                    y = 1.0 / a + (y - 1.0 / a) * math.exp(-a * travel / delta)
                    travel = 0.0
                else:
                    y = 0.0
                    travel -= x0
            if travel > 0.0:
                # with it: dy'/dx = (1 - y') / delta
                y = 1.0 - (1.0 - y) * math.exp(-travel / delta)
            self.y = s * y
        return p - width * self.y


class NonlinearPlayPlant(SectionPlant):
    """A catheter whose roll and twist plays grow with bend times tension and whose tendons
    have Bouc-Wen friction; see the module docstring.

    Parameters
    ----------
    seed : int
        Catheter identity (elastic parameters within today's tolerances, plays +-20 %,
        from the family's stream of this seed unless given).
    vessel : "straight" | "moderate" | "steep" | Vessel
        Path of the shaft.
    params, plays : optional
        Explicit parameters (override the seed's draw).
    """

    family = "nonlinear-play"

    def __init__(
        self,
        seed: int = 0,
        vessel: str | Vessel = "straight",
        params: PlantParams | None = None,
        plays: NonlinearPlayParams | None = None,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    ) -> None:
        rng = family_rng(seed, TAG)
        drawn = sample_params(rng)
        drawn_plays = NonlinearPlayParams.sample(rng)
        super().__init__(seed, vessel, drawn if params is None else params, geometry)
        self.plays = drawn_plays if plays is None else plays
        pl = self.plays
        gain = 1.0 + pl.vessel_gain_per_rad * self.vessel.total_curvature_rad
        self._widths = (
            pl.tendon_width_ap_mm * gain,
            pl.tendon_width_ap_mm * gain,
            pl.tendon_width_rl_mm * gain,
            pl.tendon_width_rl_mm * gain,
        )
        self._tendons = [BoucWen() for _ in range(4)]
        self.reset()

    def roll_play(self) -> float:
        """h_r of (N1) now (rad)."""
        return self.plays.roll_play_rad + self.plays.roll_play_per_n_rad * self._load()

    def twist_play(self) -> float:
        """h_t of (N2) now (rad)."""
        return self.plays.twist_play_per_n_rad * self._load()

    def _load(self) -> float:
        """alpha sum_i T_i (N rad): the tendons' normal load on the bent section."""
        return self.bend * self.tension_sum_n

    def _reset_transmission(self, pulls: Pulls) -> Pulls:
        for tendon, p in zip(self._tendons, pulls, strict=True):
            tendon.reset(p)
        return pulls

    def _transmit(self, pulls: Pulls, dt: float) -> Pulls:
        return tuple(  # type: ignore[return-value]
            t(p, w) for t, p, w in zip(self._tendons, pulls, self._widths, strict=True)
        )  # (N3)-(N4)

    def _reset_turn(self, phi3: float) -> None:
        pass  # the base sets roll = phi3, twist = 0

    def _turn(self, phi3: float, dt: float) -> tuple[float, float]:
        h = self.roll_play()
        tip = self._roll + self._twist
        roll = min(max(self._roll, phi3 - h), phi3 + h)  # (N1)
        h = self.twist_play()
        tip = min(max(tip, roll - h), roll + h)  # (N2)
        return roll, tip - roll
