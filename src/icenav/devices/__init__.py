"""Robot backends behind one protocol: the simulated robot and real drives.

``CANopenRobot`` lives in :mod:`icenav.devices.canopen.robot` (imported on use, so the simulated
robot does not load the CAN stack).
"""

from icenav.devices.robot import TRANSITIONS, JointState, RobotBackend, RobotStatus
from icenav.devices.sim_robot import CommandStepError, IdealPlant, SimulatedRobot

__all__ = [
    "CommandStepError",
    "IdealPlant",
    "JointState",
    "RobotBackend",
    "RobotStatus",
    "SimulatedRobot",
    "TRANSITIONS",
]
