"""The beating heart phantom of the ICE twin (see :mod:`icenav.sim.anatomy.phantom`)."""

from icenav.sim.anatomy.phantom import (
    BASE2ANATOMY,
    BASE_BELOW_JUNCTION_MM,
    BLOOD_LABELS,
    ECHOGENICITY,
    EXAMPLE_VIEWS,
    ROI_LABELS,
    BloodVessel,
    CardiacMotion,
    Chamber,
    HeartPhantom,
    Tissue,
    Valve,
    default_phantom,
    tip2anatomy,
)

__all__ = [
    "BASE2ANATOMY",
    "BASE_BELOW_JUNCTION_MM",
    "BLOOD_LABELS",
    "BloodVessel",
    "CardiacMotion",
    "Chamber",
    "ECHOGENICITY",
    "EXAMPLE_VIEWS",
    "HeartPhantom",
    "ROI_LABELS",
    "Tissue",
    "Valve",
    "default_phantom",
    "tip2anatomy",
]
