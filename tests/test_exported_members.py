"""The public API: every name in __all__ exists, __all__ is sorted, nothing public is missing."""

from __future__ import annotations

import importlib

import pytest

import icenav

MODULES = [
    "icenav",
    "icenav.app",
    "icenav.calibration",
    "icenav.catheter_calibration",
    "icenav.compensation",
    "icenav.console",
    "icenav.controller",
    "icenav.dicom",
    "icenav.errors",
    "icenav.eval.metrics",
    "icenav.eval.spin",
    "icenav.eval.spin_report",
    "icenav.feedback",
    "icenav.gating",
    "icenav.hw",
    "icenav.hw.base",
    "icenav.hw.canopen_robot",
    "icenav.hw.sim",
    "icenav.hysteresis",
    "icenav.io.igtl",
    "icenav.io.igtl_stream",
    "icenav.io.joystick",
    "icenav.kinematics",
    "icenav.motion",
    "icenav.pose_stage",
    "icenav.refinement",
    "icenav.roadmap",
    "icenav.sim",
    "icenav.sim.anatomy",
    "icenav.sim.operator",
    "icenav.sim.ultrasound",
    "icenav.spin_task",
    "icenav.state",
    "icenav.store",
    "icenav.tendon_map",
    "icenav.tracking",
    "icenav.tracker_bias",
    "icenav.trajectories",
    "icenav.transmission",
    "icenav.validation",
    "icenav.view_refinement",
    "icenav.views",
]


@pytest.mark.parametrize("name", MODULES)
def test_all_is_sorted_and_resolves(name: str) -> None:
    module = importlib.import_module(name)
    exported = list(module.__all__)
    assert exported == sorted(exported), f"{name}.__all__ is not sorted"
    for member in exported:
        assert hasattr(module, member), f"{name}.{member} is in __all__ but missing"


def test_package_exports_every_public_error() -> None:
    from icenav import errors

    for name in errors.__all__:
        assert getattr(errors, name).__module__ == "icenav.errors"


def test_kinematics_public_names_are_exported_from_the_package() -> None:
    from icenav import kinematics

    for name in kinematics.__all__:
        assert name in icenav.__all__, f"icenav.kinematics.{name} not re-exported by icenav"
