"""Robot backends behind one protocol: the simulated robot and real drives.

``CANopenRobot`` lives in :mod:`icenav.hw.canopen_robot` (imported on use, so the simulated
robot does not load the CAN stack).
"""

from icenav.hw.base import TRANSITIONS, JointState, RobotBackend, RobotStatus
from icenav.hw.sim import CommandStepError, IdealPlant, SimulatedRobot

__all__ = [
    "CommandStepError",
    "IdealPlant",
    "JointState",
    "RobotBackend",
    "RobotStatus",
    "SimulatedRobot",
    "TRANSITIONS",
]
