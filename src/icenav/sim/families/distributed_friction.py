"""Family ``distributed-friction``: Prandtl-Ishlinskii (Maxwell-slip) friction in every joint.

Friction along a tendon is not one contact but many: the handle exit, the shaft's lumen, the
seals, each contact of the tendon in the bending section's lumens, each with its own
breakaway threshold and stiffness. The generalised Maxwell-slip model (Lampaert,
Al-Bender, Swevers 2003; Al-Bender, Lampaert, Swevers 2005) puts such contacts in parallel:
element j is a spring in series with a Coulomb slider that slips when its spring stretches
by ``r_j``; in displacement it is a play operator of half-width ``r_j``, and the sum of the
elements is a Prandtl-Ishlinskii (PI) operator (Brokate & Sprekels 1996; Kuhnen 2003)::

    F_r[x](k) = clip(F_r[x](k-1), x_k - r, x_k + r)                           (F1) play
    d_i = sum_{j=1..N} w_j F_{rho_j R_i}[p_i],   sum_j w_j = 1                 (F2) tendon i
    rho_j = (j - 1/2) / N,  w_j = 1 / N                                        (F3) graded widths
    R_i = R_pair (1 + g_v Theta_vessel)                                        (F4) vessel

With a uniform density of thresholds (F3) the branch after a reversal is a parabola: the
output's slope grows as more elements slip, until after a travel of ``2 R`` all slide. So
the loops have rounded corners, and a reversal inside the loop starts a minor loop that
closes where it started and lies inside the major loop (the PI operator's wiping-out and
congruency properties). The total lag after a long monotone motion is ``R / 2``.

The roll and the distal twist go through PI operators too, their widths scaled with the
section's total tendon tension (the tendons' pull presses the section's parts together,
and Coulomb friction grows with the normal force)::

    roll  = sum_j w_j F_{rho_j H_r}[phi3],     H_r = h_r0 + c_r sum_i T_i         (F5)
    tip   = sum_j w_j F_{rho_j H_t}[roll],     H_t = c_t sum_i T_i                 (F6)

How it differs from the default twin and from our compensation's models: the default (and
``compensation/transmission.py``) has one sharp play per tendon whose band is the capstan
form ``c T g+-(x) + w0``; here there are N plays per joint of graded widths, no capstan
factor, and tendon widths that do not grow with tension; the default's roll and twist plays
(and ``compensation/hysteresis.py``) are one sharp play ``h0 + h1 * bend``; here they are
rounded and scale with the tendon tension, not with the bend.

Magnitudes (assumptions, not tuned to any method): the tendon width ``R`` = 0.25 mm gives a
major loop as wide as the default twin's (about 6 deg of knob at a +-60 deg sweep); the roll
and twist widths equal twice the default twin's plays at a 50 deg bend (10-15 N of total
tension), so the mean lag there is the same.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry
from icenav.sim.families.base import Pulls, SectionPlant, draw, family_rng, sample_params
from icenav.sim.params import PlantParams, Vessel

__all__ = ["DistributedFrictionParams", "DistributedFrictionPlant", "PlayBank"]

TAG = 0xD15
"""Random-stream tag of the family (catheter seed s of this family is its own draw)."""


@dataclass(frozen=True)
class DistributedFrictionParams:
    """Friction parameters of one catheter of the family (lengths mm, angles rad, forces N)."""

    n_elements: int = 10
    """N: play elements per joint (F3)."""
    tendon_width_ap_mm: float = 0.25
    """R of the AP tendons (mm of pull, F2): the widest element's half-width."""
    tendon_width_rl_mm: float = 0.25
    """R of the RL tendons (mm)."""
    vessel_gain_per_rad: float = 0.25
    """g_v (F4): growth of the tendon widths per rad of vessel curvature (the shaft's lumen
    friction, spread over the vessel's arcs)."""
    roll_width_rad: float = 0.03
    """h_r0 (F5): roll width of the relaxed section (rad)."""
    roll_width_per_n: float = 0.012
    """c_r (F5): growth of the roll width per N of total tendon tension (rad/N)."""
    twist_width_per_n: float = 0.02
    """c_t (F6): twist width per N of total tendon tension (rad/N)."""

    def __post_init__(self) -> None:
        if isinstance(self.n_elements, bool) or not 1 <= int(self.n_elements) <= 100:
            raise ConfigurationError(f"n_elements must be in [1, 100], got {self.n_elements!r}")
        for name, hi in (
            ("tendon_width_ap_mm", 2.0),
            ("tendon_width_rl_mm", 2.0),
            ("vessel_gain_per_rad", 5.0),
            ("roll_width_rad", 1.0),
            ("roll_width_per_n", 0.1),
            ("twist_width_per_n", 0.1),
        ):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and 0.0 <= v <= hi):
                raise ConfigurationError(f"{name} must be in [0, {hi}], got {v}")

    @classmethod
    def sample(cls, rng: np.random.Generator) -> DistributedFrictionParams:
        """A catheter's draw: every width +-20 % (uniform), as the default's plays."""
        n = cls()
        return cls(
            n_elements=n.n_elements,
            tendon_width_ap_mm=draw(rng, n.tendon_width_ap_mm, 0.2),
            tendon_width_rl_mm=draw(rng, n.tendon_width_rl_mm, 0.2),
            vessel_gain_per_rad=draw(rng, n.vessel_gain_per_rad, 0.2),
            roll_width_rad=draw(rng, n.roll_width_rad, 0.2),
            roll_width_per_n=draw(rng, n.roll_width_per_n, 0.2),
            twist_width_per_n=draw(rng, n.twist_width_per_n, 0.2),
        )


class PlayBank:
    """A Prandtl-Ishlinskii operator (F1)-(F3): N plays of graded widths, equal weights.

    Call with the input x and the widest half-width R (same unit as x); returns the output.
    """

    __slots__ = ("rho", "w", "y")

    def __init__(self, n: int) -> None:
        self.rho = tuple((j + 0.5) / n for j in range(n))
        self.w = 1.0 / n
        self.y = [0.0] * n

    def reset(self, x: float) -> None:
        """Every element relaxed at x (no stored friction)."""
        self.y = [x] * len(self.rho)

    def __call__(self, x: float, width: float) -> float:
        y = self.y
        total = 0.0
        for j, rho in enumerate(self.rho):
            r = rho * width
            v = y[j]
            v = x - r if v < x - r else x + r if v > x + r else v  # (F1)
            y[j] = v
            total += v
        return total * self.w


class DistributedFrictionPlant(SectionPlant):
    """A catheter whose joints have distributed (Prandtl-Ishlinskii) friction; see the module
    docstring for the law.

    Parameters
    ----------
    seed : int
        Catheter identity: the elastic parameters within today's tolerances and the friction
        widths are drawn from the family's stream of this seed (unless given).
    vessel : "straight" | "moderate" | "steep" | Vessel
        Path of the shaft.
    params, friction : optional
        Explicit parameters (override the seed's draw).
    """

    family = "distributed-friction"

    def __init__(
        self,
        seed: int = 0,
        vessel: str | Vessel = "straight",
        params: PlantParams | None = None,
        friction: DistributedFrictionParams | None = None,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    ) -> None:
        rng = family_rng(seed, TAG)
        drawn = sample_params(rng)
        drawn_friction = DistributedFrictionParams.sample(rng)
        super().__init__(seed, vessel, drawn if params is None else params, geometry)
        self.friction = drawn_friction if friction is None else friction
        f = self.friction
        gain = 1.0 + f.vessel_gain_per_rad * self.vessel.total_curvature_rad  # (F4)
        self._widths = (
            f.tendon_width_ap_mm * gain,
            f.tendon_width_ap_mm * gain,
            f.tendon_width_rl_mm * gain,
            f.tendon_width_rl_mm * gain,
        )
        n = int(f.n_elements)
        self._tendons = [PlayBank(n) for _ in range(4)]
        self._roll_bank = PlayBank(n)
        self._twist_bank = PlayBank(n)
        self.reset()

    def _reset_transmission(self, pulls: Pulls) -> Pulls:
        for bank, p in zip(self._tendons, pulls, strict=True):
            bank.reset(p)
        return pulls

    def _transmit(self, pulls: Pulls, dt: float) -> Pulls:
        return tuple(  # type: ignore[return-value]
            bank(p, w) for bank, p, w in zip(self._tendons, pulls, self._widths, strict=True)
        )  # (F2)

    def _reset_turn(self, phi3: float) -> None:
        self._roll_bank.reset(phi3)
        self._twist_bank.reset(phi3)

    def _turn(self, phi3: float, dt: float) -> tuple[float, float]:
        f = self.friction
        tension = self.tension_sum_n
        roll = self._roll_bank(phi3, f.roll_width_rad + f.roll_width_per_n * tension)  # (F5)
        tip = self._twist_bank(roll, f.twist_width_per_n * tension)  # (F6)
        return roll, tip - roll
