"""icenav: open software for robotic intracardiac echocardiography (ICE) catheters.

The core (kinematics, compensation, hysteresis, trajectories, roadmap) is pure computation;
the digital twin lives in :mod:`icenav.sim`.
"""

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
from icenav.kinematics import (
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

__version__ = "0.1.0"

__all__ = [
    "Backbone",
    "CatheterGeometry",
    "ConfigurationError",
    "FileFormatError",
    "IcenavError",
    "InvalidValueError",
    "InverseSolution",
    "JointLimitError",
    "NonFiniteError",
    "ShapeError",
    "TransformError",
    "UnreachablePoseError",
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
