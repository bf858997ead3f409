"""Robot backends behind one protocol: the simulated robot and real drives."""

from icenav.hw.base import JointState, RobotBackend, RobotStatus

__all__ = ["JointState", "RobotBackend", "RobotStatus"]
