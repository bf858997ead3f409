"""icenav: open software for robotic intracardiac echocardiography (ICE) catheters.

The core (kinematics, compensation, hysteresis, trajectories, roadmap) is pure computation;
the digital twin lives in :mod:`icenav.sim`.
"""

from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.control.controller import Controller, ControllerConfig
from icenav.errors import (
    ConfigurationError,
    FileFormatError,
    IcenavError,
    InvalidValueError,
    JointLimitError,
    NonFiniteError,
    ShapeError,
    TransformError,
    UnreachablePoseError,
)
from icenav.geometry.kinematics import (
    Backbone,
    CatheterGeometry,
    InverseSolution,
    backbone,
    bend_to_knobs,
    forward,
    inverse,
    inverse_with_residual,
    jacobian,
    knobs_to_bend,
    tip_jog,
)
from icenav.persistence.store import SessionStore
from icenav.recovery.roadmap import Roadmap, RoadmapConfig
from icenav.recovery.views import View, ViewLibrary

__version__ = "0.1.0"

__all__ = [
    "Backbone",
    "CalibrationSet",
    "CatheterGeometry",
    "ConfigurationError",
    "Controller",
    "ControllerConfig",
    "ElasticityMap",
    "FileFormatError",
    "IcenavError",
    "InvalidValueError",
    "InverseSolution",
    "JointLimitError",
    "NonFiniteError",
    "Roadmap",
    "RoadmapConfig",
    "SessionStore",
    "ShapeError",
    "TransformError",
    "UnreachablePoseError",
    "View",
    "ViewLibrary",
    "__version__",
    "backbone",
    "bend_to_knobs",
    "forward",
    "inverse",
    "inverse_with_residual",
    "jacobian",
    "knobs_to_bend",
    "tip_jog",
]
