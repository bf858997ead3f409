"""The digital twin: catheter plant and EM tracker (registration is in
:mod:`icenav.devices.registration`).

Other parts of the twin (operator, anatomy, ultrasound) are added by their own modules.
"""

from icenav.sim.params import TOLERANCES, PlantParams, Vessel
from icenav.sim.plant import (
    CatheterPlant,
    PlantState,
    elastic_tip2base,
    elastic_tip2base_from_tensions,
)
from icenav.sim.tracker import EMTracker, ToolStatus, TrackerConfig, TrackerFrame

__all__ = [
    "CatheterPlant",
    "EMTracker",
    "PlantParams",
    "PlantState",
    "TOLERANCES",
    "ToolStatus",
    "TrackerConfig",
    "TrackerFrame",
    "Vessel",
    "elastic_tip2base",
    "elastic_tip2base_from_tensions",
]
