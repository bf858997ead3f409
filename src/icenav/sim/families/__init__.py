"""Plant families: catheters (and trackers) whose laws our compensation does not share.

Each family is a factory ``factory(seed, vessel, *, clock=None) -> (plant, tracker)`` with
the plug-in protocol of :mod:`icenav.sim.plugins` (docs/digital-twin.md, "Plant plug-ins"
and "Plant families"); ``FAMILIES`` maps each name to its factory::

    default                the twin of sim/plant.py and sim/tracker.py, unchanged
    distributed-friction   Prandtl-Ishlinskii (Maxwell-slip) friction in every joint
    rate-dependent         Dahl-Stribeck-viscous friction, friction relaxation, tendon creep
    nonlinear-play         roll and twist plays growing with bend x tension; Bouc-Wen tendons
    out-of-tolerance       the default laws, every parameter 2-3x outside today's tolerance
    field-distortion       the default plant, an EM tracker with a short-wavelength,
                           orientation-dependent distortion and metal turning with the roll

A plant family and a tracker family combine with ``+``: ``family("rate-dependent+
field-distortion")``. Catheter ``seed`` of a family is drawn from the family's own random
stream (it is not the default twin's catheter ``seed``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from icenav.errors import ConfigurationError
from icenav.sim.families.distributed_friction import DistributedFrictionPlant
from icenav.sim.families.field_distortion import DistortionConfig, FieldDistortionTracker
from icenav.sim.families.nonlinear_play import NonlinearPlayPlant
from icenav.sim.families.out_of_tolerance import out_of_tolerance_plant
from icenav.sim.families.rate_dependent import RateDependentPlant
from icenav.sim.plant import CatheterPlant
from icenav.sim.tracker import EMTracker

__all__ = [
    "DistortionConfig",
    "DistributedFrictionPlant",
    "FAMILIES",
    "FamilyFactory",
    "FieldDistortionTracker",
    "NonlinearPlayPlant",
    "PLANT_FAMILIES",
    "RateDependentPlant",
    "TRACKER_FAMILIES",
    "family",
]

Clock = Callable[[], float] | None


def _default_plant(seed: int, vessel: str, clock: Clock) -> Any:
    return CatheterPlant(seed=seed, vessel=vessel)


def _distributed(seed: int, vessel: str, clock: Clock) -> Any:
    return DistributedFrictionPlant(seed=seed, vessel=vessel)


def _rate(seed: int, vessel: str, clock: Clock) -> Any:
    return RateDependentPlant(seed=seed, vessel=vessel, clock=clock)


def _nonlinear(seed: int, vessel: str, clock: Clock) -> Any:
    return NonlinearPlayPlant(seed=seed, vessel=vessel)


def _out_of_tolerance(seed: int, vessel: str, clock: Clock) -> Any:
    return out_of_tolerance_plant(seed, vessel)


def _em(plant: Any, seed: int, clock: Clock) -> Any:
    return EMTracker(plant, seed=seed, clock=clock)


def _field(plant: Any, seed: int, clock: Clock) -> Any:
    return FieldDistortionTracker(plant, seed=seed, clock=clock)


PLANT_FAMILIES: dict[str, Callable[[int, str, Clock], Any]] = {
    "default": _default_plant,
    "distributed-friction": _distributed,
    "rate-dependent": _rate,
    "nonlinear-play": _nonlinear,
    "out-of-tolerance": _out_of_tolerance,
}
"""Plant family name -> ``make(seed, vessel, clock) -> plant``."""

TRACKER_FAMILIES: dict[str, Callable[[Any, int, Clock], Any]] = {
    "em": _em,
    "field-distortion": _field,
}
"""Tracker family name -> ``make(plant, seed, clock) -> tracker`` (``em``: the default)."""


@dataclass(frozen=True)
class FamilyFactory:
    """The factory of one plant family with one tracker family (picklable, so worker
    processes can be handed it)."""

    plant: str = "default"
    """Plant family (a key of :data:`PLANT_FAMILIES`)."""
    tracker: str = "em"
    """Tracker family (a key of :data:`TRACKER_FAMILIES`)."""

    def __post_init__(self) -> None:
        if self.plant not in PLANT_FAMILIES:
            raise ConfigurationError(
                f"unknown plant family {self.plant!r}; choose from {sorted(PLANT_FAMILIES)}"
            )
        if self.tracker not in TRACKER_FAMILIES:
            raise ConfigurationError(
                f"unknown tracker family {self.tracker!r}; choose from {sorted(TRACKER_FAMILIES)}"
            )

    @property
    def name(self) -> str:
        """The registry name: ``plant``, ``field-distortion`` or ``plant+tracker``."""
        if self.tracker == "em":
            return self.plant
        if self.plant == "default":
            return self.tracker
        return f"{self.plant}+{self.tracker}"

    def __call__(
        self, seed: int, vessel: str = "straight", *, clock: Clock = None
    ) -> tuple[Any, Any]:
        """Catheter ``seed`` of the family in ``vessel`` and its tracker (seeded alike);
        ``clock`` (s), if given, drives the tracker's sampling and any plant with time."""
        plant = PLANT_FAMILIES[self.plant](seed, vessel, clock)
        return plant, TRACKER_FAMILIES[self.tracker](plant, seed, clock)


FAMILIES: dict[str, FamilyFactory] = {
    f.name: f
    for f in (
        FamilyFactory("default"),
        FamilyFactory("distributed-friction"),
        FamilyFactory("rate-dependent"),
        FamilyFactory("nonlinear-play"),
        FamilyFactory("out-of-tolerance"),
        FamilyFactory("default", "field-distortion"),
    )
}
"""Family name -> factory ``(seed, vessel, *, clock=None) -> (plant, tracker)``."""


def family(name: str) -> FamilyFactory:
    """The factory of a family by name: a key of :data:`FAMILIES`, or ``PLANT+TRACKER``
    (a plant family and a tracker family, e.g. ``rate-dependent+field-distortion``)."""
    if not isinstance(name, str):
        raise ConfigurationError(f"family name must be a string, got {name!r}")
    if name in FAMILIES:
        return FAMILIES[name]
    plant, sep, tracker = name.partition("+")
    if sep and plant in PLANT_FAMILIES and tracker in TRACKER_FAMILIES:
        return FamilyFactory(plant, tracker)
    raise ConfigurationError(
        f"unknown plant family {name!r}; choose from {sorted(FAMILIES)} or PLANT+TRACKER with "
        f"PLANT in {sorted(PLANT_FAMILIES)} and TRACKER in {sorted(TRACKER_FAMILIES)}"
    )
