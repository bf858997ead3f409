"""The public API: every name in __all__ exists, __all__ is sorted, nothing public is missing."""

from __future__ import annotations

import importlib

import pytest

import icenav

MODULES = [
    "icenav",
    "icenav.apps.calibrate",
    "icenav.apps.calibration_csv",
    "icenav.apps.export_view",
    "icenav.apps.hardware",
    "icenav.apps.options",
    "icenav.apps.run",
    "icenav.apps.serve",
    "icenav.apps.wiring",
    "icenav.calibration.plans",
    "icenav.calibration.catheter",
    "icenav.compensation.elasticity",
    "icenav.console",
    "icenav.control.authorization",
    "icenav.control.calibration_runner",
    "icenav.control.commands",
    "icenav.control.config",
    "icenav.control.controller",
    "icenav.control.guard",
    "icenav.control.handlers",
    "icenav.control.modes",
    "icenav.control.publish",
    "icenav.control.runtime",
    "icenav.control.tasks",
    "icenav.control.teleop",
    "icenav.persistence.recorder",
    "icenav.persistence.dicom",
    "icenav.errors",
    "icenav.eval.metrics",
    "icenav.eval.recovery",
    "icenav.eval.recovery_bench",
    "icenav.eval.recovery_plots",
    "icenav.eval.recovery_report",
    "icenav.eval.spin",
    "icenav.eval.spin_cli",
    "icenav.eval.spin_cost",
    "icenav.eval.spin_report",
    "icenav.control.servo",
    "icenav.refinement.gating",
    "icenav.devices",
    "icenav.devices.robot",
    "icenav.devices.canopen.robot",
    "icenav.devices.sim_robot",
    "icenav.compensation.bend_play",
    "icenav.compensation.hysteresis",
    "icenav.io.igtl",
    "icenav.io.igtl_stream",
    "icenav.io.igtl_server",
    "icenav.io.igtl_wire",
    "icenav.persistence.lock",
    "icenav.devices.gamepad",
    "icenav.geometry.kinematics",
    "icenav.refinement.pose_stage",
    "icenav.refinement.image_search",
    "icenav.recovery.roadmap",
    "icenav.sim",
    "icenav.sim.anatomy",
    "icenav.sim.conditions",
    "icenav.sim.contact",
    "icenav.sim.disturbed",
    "icenav.sim.introducer",
    "icenav.sim.patient",
    "icenav.sim.physiology",
    "icenav.sim.families",
    "icenav.sim.families.base",
    "icenav.sim.families.distributed_friction",
    "icenav.sim.families.field_distortion",
    "icenav.sim.families.nonlinear_play",
    "icenav.sim.families.out_of_tolerance",
    "icenav.sim.families.rate_dependent",
    "icenav.sim.operator",
    "icenav.sim.plugins",
    "icenav.sim.ultrasound",
    "icenav.control.spin",
    "icenav.control.state",
    "icenav.persistence.store",
    "icenav.compensation.tendon_map",
    "icenav.devices.tracker",
    "icenav.compensation.tracker_bias",
    "icenav.geometry.trajectories",
    "icenav.compensation.transmission",
    "icenav._validation",
    "icenav.refinement.task",
    "icenav.recovery.views",
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
    from icenav.geometry import kinematics

    for name in kinematics.__all__:
        assert name in icenav.__all__, (
            f"icenav.geometry.kinematics.{name} not re-exported by icenav"
        )
