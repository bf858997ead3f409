"""The digital twin: catheter plant, EM tracker and registration (issue 3).

Other parts of the twin (operator, anatomy, ultrasound) are added by their own modules.
"""

from icenav.sim.params import TOLERANCES, PlantParams, Vessel
from icenav.sim.plant import (
    CatheterPlant,
    PlantState,
    elastic_tip2base,
    elastic_tip2base_from_tensions,
)
from icenav.sim.registration import (
    Registration,
    kabsch_umeyama,
    register_tracker,
    registration_joint_states,
)
from icenav.sim.tracker import EMTracker, ToolStatus, TrackerConfig, TrackerFrame

__all__ = [
    "CatheterPlant",
    "EMTracker",
    "PlantParams",
    "PlantState",
    "Registration",
    "TOLERANCES",
    "ToolStatus",
    "TrackerConfig",
    "TrackerFrame",
    "Vessel",
    "elastic_tip2base",
    "elastic_tip2base_from_tensions",
    "kabsch_umeyama",
    "register_tracker",
    "registration_joint_states",
]
