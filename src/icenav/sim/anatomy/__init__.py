"""The beating heart phantom of the ICE twin.

:mod:`icenav.sim.anatomy.tissue` holds the tissue labels and their acoustic properties,
:mod:`icenav.sim.anatomy.phantom` the shapes, the motion, the default heart and its
registration to the robot base, :mod:`icenav.sim.anatomy.views` the standard ICE views.
"""

from icenav.sim.anatomy.phantom import (
    BASE2ANATOMY,
    BASE_BELOW_JUNCTION_MM,
    EXAMPLE_VIEWS,
    PATIENT_DIRECTIONS,
    BloodVessel,
    CardiacMotion,
    Chamber,
    HeartPhantom,
    Landmark,
    Region,
    Valve,
    default_phantom,
    tip2anatomy,
)
from icenav.sim.anatomy.tissue import (
    ACOUSTICS,
    BLOOD_LABELS,
    ECHOGENICITY,
    ROI_LABELS,
    AcousticProperties,
    Tissue,
)
from icenav.sim.anatomy.views import STANDARD_VIEWS, StandardView

__all__ = [
    "ACOUSTICS",
    "AcousticProperties",
    "BASE2ANATOMY",
    "BASE_BELOW_JUNCTION_MM",
    "BLOOD_LABELS",
    "BloodVessel",
    "CardiacMotion",
    "Chamber",
    "ECHOGENICITY",
    "EXAMPLE_VIEWS",
    "HeartPhantom",
    "Landmark",
    "PATIENT_DIRECTIONS",
    "ROI_LABELS",
    "Region",
    "STANDARD_VIEWS",
    "StandardView",
    "Tissue",
    "Valve",
    "default_phantom",
    "tip2anatomy",
]
