"""Physical parameters of the simulated ICE catheter and the vessel it lies in.

Every value of :class:`PlantParams` has a nominal value (:meth:`PlantParams.nominal`), a
manufacturing tolerance (:data:`TOLERANCES`, drawn by :meth:`PlantParams.sample`) and a source
in ``docs/digital-twin.md``. Values marked *tuned* there were adjusted (on catheter seeds
0-9 only) so that the paper's image-spinning test reproduces its Table I.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Literal

import numpy as np

from icenav.errors import ConfigurationError

__all__ = [
    "PlantParams",
    "TOLERANCES",
    "Vessel",
    "VesselName",
]

VesselName = Literal["straight", "moderate", "steep"]


@dataclass(frozen=True)
class Vessel:
    """The path of the catheter shaft between the robot's front and back units."""

    name: str
    """Name of the condition (the paper's ``straight``, ``moderate``, ``steep`` or custom)."""
    arcs_rad: tuple[float, ...] = ()
    """Turning angle of each arc of the vessel (rad, >= 0); the paper's phantom has two."""

    def __post_init__(self) -> None:
        arcs = tuple(float(a) for a in self.arcs_rad)
        for a in arcs:
            if not math.isfinite(a) or a < 0.0 or a > 2.0 * math.pi:
                raise ConfigurationError(
                    f"vessel arc must be in [0, 2 pi] rad ([0, 360] deg), got {a} rad"
                )
        object.__setattr__(self, "arcs_rad", arcs)

    @property
    def total_curvature_rad(self) -> float:
        """Sum of the arcs' turning angles (rad): the capstan wrap the vessel adds."""
        return float(sum(self.arcs_rad))

    @classmethod
    def named(cls, name: str) -> Vessel:
        """The paper's phantom conditions: straight (0, 0), moderate (30, 30), steep (40, 45) deg
        arcs."""
        table = {"straight": (0.0, 0.0), "moderate": (30.0, 30.0), "steep": (40.0, 45.0)}
        if name not in table:
            raise ConfigurationError(
                f"vessel must be one of {sorted(table)} or a Vessel, got {name!r}"
            )
        return cls(name, tuple(math.radians(a) for a in table[name]))


@dataclass(frozen=True)
class PlantParams:
    """Parameters of one catheter (lengths mm, forces N, angles rad).

    The AP tendon pair is pulled by knob 1 (tendon A at +x, B at -x of the base frame), the RL
    pair by knob 2 (tendon C at +y, D at -y).
    """

    handle_radius_ap_mm: float = 2.4
    """Radius of the AP knob's handle pulley that turns knob rotation into tendon pull (mm)."""
    handle_radius_rl_mm: float = 2.2
    """Radius of the RL knob's handle pulley (mm); the handle's two knobs differ (sized so the
    stiffer RL plane reaches a full deflection comparable to AP's, as a real handle is)."""
    tendon_offset_ap_mm: float = 1.27
    """Distance of the AP tendons from the catheter axis in the bending section (mm)."""
    tendon_offset_rl_mm: float = 1.15
    """Distance of the RL tendons from the catheter axis (mm); the array forces the lumens
    to different radii."""
    neutral_axis_x_mm: float = 0.05
    """Offset of the bending neutral axis from the tendon circle's centre along x (mm):
    the off-centre imaging array and its cable shift it."""
    neutral_axis_y_mm: float = 0.15
    """Offset of the neutral axis along y (mm)."""
    routing_error_ap_rad: float = 0.17
    """Angular misplacement of the AP tendon pair around the axis (rad): pulls off-plane."""
    routing_error_rl_rad: float = -0.26
    """Angular misplacement of the RL tendon pair around the axis (rad)."""
    slack_ap_mm: float = 0.05
    """Slack of each AP tendon at the knob's centre (mm): dead-zone half-width in pull."""
    slack_rl_mm: float = 0.06
    """Slack of each RL tendon (mm)."""
    tendon_compliance_mm_per_n: float = 0.04
    """Compliance of one tendon over its whole length (handle to tip), mm per N."""
    ei_ap_nmm2: float = 340.0
    """Bending stiffness for bending in the AP plane (x-z), N mm^2, at zero curvature."""
    ei_rl_nmm2: float = 700.0
    """Bending stiffness for bending in the RL plane (y-z), N mm^2 (the array stiffens it)."""
    ei_coupling_nmm2: float = 140.0
    """Product-of-inertia coupling between the planes, N mm^2 (non-symmetric cross-section)."""
    stiffening: float = 0.08
    """Strain stiffening beta: EI grows by (1 + beta * bend_angle^2), dimensionless."""
    friction_coefficient: float = 0.6
    """Effective tendon Coulomb friction coefficient mu of the handle exit and the bending
    section (dimensionless): applies to ``shaft_curvature_rad`` and the section's own bend;
    lumps lumen and section contact (tuned)."""
    shaft_curvature_rad: float = 0.6
    """Intrinsic total curvature of the tendon path with a straight vessel (handle, shaft
    lie on the bench), rad, at the coefficient ``friction_coefficient``."""
    seal_play_mm: float = 0.03
    """Tension-independent half-width of the tendon play (seal and lumen friction), mm."""
    roll_play_rad: float = 0.014
    """Half-width of the torsional play between handle and tip with a straight vessel (rad)."""
    roll_play_per_bend: float = 0.09
    """Growth of the torsional play half-width with the bend angle (rad per rad of bend): a
    bent section needs more torque to turn (its tendons are taut and it presses on the
    sheath)."""
    twist_play_per_bend: float = 0.15
    """Half-width of the torsional play of the bent distal section itself, per rad of bend
    (rad/rad): the image plane lags about its own axis when the catheter is rolled."""
    translation_play_mm: float = 0.3
    """Half-width of the axial lost motion with a straight vessel (mm)."""
    bending_length_scale: float = 1.0
    """True bending length / nominal bending length (dimensionless)."""
    lumen_friction_coefficient: float = 0.2
    """Coulomb friction coefficient of a tendon in the shaft's lined lumen (dimensionless):
    applies to the vessel's curvature (PTFE on steel, 0.1-0.3, Do et al. 2014). Last field,
    so that adding it left the other parameters of every seed as they were."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            try:
                v = float(value)
            except (TypeError, ValueError) as exc:
                raise ConfigurationError(f"{f.name} must be a number, got {value!r}") from exc
            low, high = _RANGES[f.name]
            if not (math.isfinite(v) and low <= v <= high):
                unit = _unit(f.name)
                raise ConfigurationError(
                    f"{f.name} = {v} {unit} is outside the allowed range [{low}, {high}] {unit}"
                )
            object.__setattr__(self, f.name, v)

    def elastic_only(self) -> PlantParams:
        """The same catheter without slack, friction or play: only its elastic statics
        (the part the paper's compensation F can remove)."""
        return replace(
            self,
            slack_ap_mm=0.0,
            slack_rl_mm=0.0,
            friction_coefficient=0.0,
            lumen_friction_coefficient=0.0,
            seal_play_mm=0.0,
            roll_play_rad=0.0,
            roll_play_per_bend=0.0,
            twist_play_per_bend=0.0,
            translation_play_mm=0.0,
        )

    @classmethod
    def nominal(cls) -> PlantParams:
        """The documented defaults (see docs/digital-twin.md)."""
        return cls()

    @classmethod
    def sample(cls, seed: int) -> PlantParams:
        """A catheter drawn within manufacturing tolerance of :meth:`nominal`.

        Each parameter is drawn uniformly from nominal +- tolerance (relative or absolute, see
        :data:`TOLERANCES`), with ``numpy.random.default_rng(seed)``; the same seed gives the
        same catheter.
        """
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
            raise ConfigurationError(f"seed must be an integer >= 0, got {seed!r}")
        rng = np.random.default_rng([int(seed), 0x1CE])
        nom = cls()
        values: dict[str, float] = {}
        for f in fields(cls):
            base = float(getattr(nom, f.name))
            kind, tol = TOLERANCES[f.name]
            x = float(rng.uniform(-1.0, 1.0))
            values[f.name] = base * (1.0 + tol * x) if kind == "rel" else base + tol * x
        return replace(nom, **values)


def _unit(name: str) -> str:
    for suffix, unit in (
        ("_mm_per_n", "mm/N"),
        ("_nmm2", "N mm^2"),
        ("_mm", "mm"),
        ("_rad", "rad"),
    ):
        if name.endswith(suffix):
            return unit
    return "(dimensionless)"


_RANGES: dict[str, tuple[float, float]] = {
    "handle_radius_ap_mm": (0.5, 10.0),
    "handle_radius_rl_mm": (0.5, 10.0),
    "tendon_offset_ap_mm": (0.3, 3.0),
    "tendon_offset_rl_mm": (0.3, 3.0),
    "neutral_axis_x_mm": (-0.5, 0.5),
    "neutral_axis_y_mm": (-0.5, 0.5),
    "routing_error_ap_rad": (-0.5, 0.5),
    "routing_error_rl_rad": (-0.5, 0.5),
    "slack_ap_mm": (0.0, 2.0),
    "slack_rl_mm": (0.0, 2.0),
    "tendon_compliance_mm_per_n": (1e-4, 1.0),
    "ei_ap_nmm2": (10.0, 1e5),
    "ei_rl_nmm2": (10.0, 1e5),
    "ei_coupling_nmm2": (-1e4, 1e4),
    "stiffening": (0.0, 5.0),
    "friction_coefficient": (0.0, 1.0),
    "shaft_curvature_rad": (0.0, 4.0 * math.pi),
    "seal_play_mm": (0.0, 1.0),
    "roll_play_rad": (0.0, 0.5),
    "roll_play_per_bend": (0.0, 1.0),
    "twist_play_per_bend": (0.0, 1.0),
    "translation_play_mm": (0.0, 5.0),
    "bending_length_scale": (0.8, 1.2),
    "lumen_friction_coefficient": (0.0, 1.0),
}
"""Physically sensible range of each parameter (outside it a ConfigurationError)."""

TOLERANCES: dict[str, tuple[Literal["rel", "abs"], float]] = {
    "handle_radius_ap_mm": ("rel", 0.02),
    "handle_radius_rl_mm": ("rel", 0.02),
    "tendon_offset_ap_mm": ("rel", 0.03),
    "tendon_offset_rl_mm": ("rel", 0.03),
    "neutral_axis_x_mm": ("abs", 0.05),
    "neutral_axis_y_mm": ("abs", 0.05),
    "routing_error_ap_rad": ("abs", 0.03),
    "routing_error_rl_rad": ("abs", 0.03),
    "slack_ap_mm": ("rel", 0.25),
    "slack_rl_mm": ("rel", 0.25),
    "tendon_compliance_mm_per_n": ("rel", 0.10),
    "ei_ap_nmm2": ("rel", 0.10),
    "ei_rl_nmm2": ("rel", 0.10),
    "ei_coupling_nmm2": ("rel", 0.30),
    "stiffening": ("rel", 0.20),
    "friction_coefficient": ("rel", 0.20),
    "shaft_curvature_rad": ("rel", 0.20),
    "seal_play_mm": ("rel", 0.20),
    "roll_play_rad": ("rel", 0.20),
    "roll_play_per_bend": ("rel", 0.20),
    "twist_play_per_bend": ("rel", 0.20),
    "translation_play_mm": ("rel", 0.20),
    "bending_length_scale": ("rel", 0.015),
    "lumen_friction_coefficient": ("rel", 0.20),
}
"""Manufacturing tolerance of each parameter: ("rel", fraction) or ("abs", amount in its unit)."""
