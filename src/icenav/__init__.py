"""icenav: open software for robotic intracardiac echocardiography (ICE) catheters.

The core (kinematics, compensation, hysteresis, trajectories, roadmap) is pure computation;
the digital twin lives in :mod:`icenav.sim`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_LAZY: dict[str, str] = {
    "CalibrationSet": "icenav.compensation.elasticity",
    "ElasticityMap": "icenav.compensation.elasticity",
    "Controller": "icenav.control.controller",
    "ControllerConfig": "icenav.control.controller",
    "ConfigurationError": "icenav.errors",
    "FileFormatError": "icenav.errors",
    "IcenavError": "icenav.errors",
    "InvalidValueError": "icenav.errors",
    "JointLimitError": "icenav.errors",
    "NonFiniteError": "icenav.errors",
    "ShapeError": "icenav.errors",
    "TransformError": "icenav.errors",
    "UnreachablePoseError": "icenav.errors",
    "Backbone": "icenav.geometry.kinematics",
    "CatheterGeometry": "icenav.geometry.kinematics",
    "InverseSolution": "icenav.geometry.kinematics",
    "backbone": "icenav.geometry.kinematics",
    "bend_to_knobs": "icenav.geometry.kinematics",
    "forward": "icenav.geometry.kinematics",
    "inverse": "icenav.geometry.kinematics",
    "inverse_with_residual": "icenav.geometry.kinematics",
    "jacobian": "icenav.geometry.jacobian",
    "knobs_to_bend": "icenav.geometry.kinematics",
    "tip_jog": "icenav.geometry.jacobian",
    "SessionStore": "icenav.persistence.store",
    "Roadmap": "icenav.recovery.roadmap",
    "RoadmapConfig": "icenav.recovery.roadmap",
    "View": "icenav.recovery.views",
    "ViewLibrary": "icenav.recovery.views",
}
"""Public name -> the module that defines it; imported on first use, so ``import icenav``
loads neither numpy's heavy neighbours nor the controller (a command-line tool or a
subpackage import stays fast)."""


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'icenav' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # the next access is a plain lookup
    return value


def __dir__() -> list[str]:
    return sorted(__all__)


if TYPE_CHECKING:  # for type checkers and IDEs: the same names, eagerly
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
    from icenav.geometry.jacobian import jacobian, tip_jog
    from icenav.geometry.kinematics import (
        Backbone,
        CatheterGeometry,
        InverseSolution,
        backbone,
        bend_to_knobs,
        forward,
        inverse,
        inverse_with_residual,
        knobs_to_bend,
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
