"""The one error tree of icenav.

Every error icenav raises derives from :class:`IcenavError`, so a caller can catch all of
them at once. Errors caused by a bad value also derive from :class:`ValueError`, so code
that already catches ``ValueError`` keeps working. Leaves carry context: the value, its
unit and the allowed range (as canopen's ``SdoAbortedError`` carries the abort code).

::

    IcenavError
    ├── InvalidValueError (ValueError)        a value is malformed or out of range
    │   ├── NonFiniteError                    NaN or inf where a finite number is needed
    │   ├── ShapeError                        an array has the wrong shape
    │   ├── JointLimitError                   a joint state beyond its limit
    │   ├── TransformError                    a matrix that is not a rigid transform
    │   ├── UnreachablePoseError              no joint state reaches a pose
    │   ├── ConfigurationError                a bad setting (geometry, plant, tracker, ...)
    │   │   └── PluginError                   a plant plug-in fails to load or breaks the protocol
    │   ├── CommandStepError                  a position command jumps farther than allowed
    │   ├── ViewExistsError                   a view of that name exists already
    │   └── UnsafeExportPathError             an export would land outside its directory
    ├── FileFormatError (ValueError)          a file that icenav cannot read
    │   └── UnsupportedVersionError           written by a newer icenav, or unknown version
    ├── ViewNotFoundError (KeyError)          no view of that name
    ├── PlanningError                         no path can be planned
    │   ├── GoalUnreachableError              the goal is not connected to the start
    │   ├── RoadmapFullError                  the roadmap's vertex budget is used up
    │   └── NeighbourhoodError                a refinement would leave the view's neighbourhood
    ├── StoreError                            the session store failed (disk full, read-only, ...)
    │   └── SessionLockedError                another process writes the session file
    ├── ExportError                           writing an export failed (disk full, permission)
    ├── MotionAborted                         an automatic motion was aborted or stopped
    ├── CommandTimeoutError (TimeoutError)    a command's outcome did not come in time
    ├── CommandRefusedError                   a command was refused (authorization, mode, ...)
    ├── HardwareError                         a robot backend reports a problem
    │   ├── DriveFaultError                   a motor drive is in FAULT (code and text)
    │   ├── HeartbeatLostError                a drive stopped sending heartbeats
    │   └── EmergencyStopError                the robot is e-stopped; reset required
    ├── TrackerError                          the tracker is not running or misconfigured
    │   └── RegistrationError                 no registration, or one whose residual is too large
    ├── JobError                              a job of a population run failed (item, traceback)
    └── IgtlError                             the OpenIGTLink server cannot start or is misused
        └── IgtlProtocolError                 a peer sent bytes that break the protocol
"""

from __future__ import annotations

__all__ = [
    "CommandRefusedError",
    "CommandStepError",
    "CommandTimeoutError",
    "ConfigurationError",
    "DriveFaultError",
    "EmergencyStopError",
    "ExportError",
    "FileFormatError",
    "GoalUnreachableError",
    "HardwareError",
    "HeartbeatLostError",
    "IcenavError",
    "IgtlError",
    "IgtlProtocolError",
    "InvalidValueError",
    "JobError",
    "JointLimitError",
    "MotionAborted",
    "NeighbourhoodError",
    "NonFiniteError",
    "PlanningError",
    "PluginError",
    "RegistrationError",
    "RoadmapFullError",
    "SessionLockedError",
    "ShapeError",
    "StoreError",
    "TrackerError",
    "TransformError",
    "UnreachablePoseError",
    "UnsafeExportPathError",
    "UnsupportedVersionError",
    "ViewExistsError",
    "ViewNotFoundError",
]


class IcenavError(Exception):
    """Root of every error raised by icenav."""


class InvalidValueError(IcenavError, ValueError):
    """A value is malformed or outside its allowed range."""


class NonFiniteError(InvalidValueError):
    """NaN or inf where a finite number is required."""


class ShapeError(InvalidValueError):
    """An array argument has the wrong shape."""


class JointLimitError(InvalidValueError):
    """A joint state lies beyond its limit.

    Attributes
    ----------
    joint : str
        Joint name (``phi1``, ``phi2``, ``phi3`` or ``d4``).
    value : float
        The offending value, in the joint's unit (rad or mm).
    low, high : float
        The allowed range, in the same unit.
    """

    def __init__(self, message: str, *, joint: str, value: float, low: float, high: float):
        super().__init__(message)
        self.joint = joint
        self.value = value
        self.low = low
        self.high = high


class TransformError(InvalidValueError):
    """A 4x4 matrix is not a rigid (proper, orthonormal) homogeneous transform."""


class UnreachablePoseError(InvalidValueError):
    """No joint state reaches the requested pose within tolerance.

    Attributes
    ----------
    position_residual_mm, rotation_residual_rad : float
        Distance from the requested pose to the nearest reachable one.
    """

    def __init__(self, message: str, *, position_residual_mm: float, rotation_residual_rad: float):
        super().__init__(message)
        self.position_residual_mm = position_residual_mm
        self.rotation_residual_rad = rotation_residual_rad


class ConfigurationError(InvalidValueError):
    """A configuration value (geometry, plant, tracker, controller, ...) is invalid."""


class PluginError(ConfigurationError):
    """A plant plug-in (``--plant MODULE:FACTORY``) cannot be loaded, or the plant or tracker
    it makes lacks part of the protocol (the message names the spec and what is missing)."""


class FileFormatError(IcenavError, ValueError):
    """A file is corrupt, truncated or not an icenav file of the expected kind."""


class UnsupportedVersionError(FileFormatError):
    """A file's format version is newer than (or unknown to) this icenav."""


class PlanningError(IcenavError):
    """No path can be planned."""


class GoalUnreachableError(PlanningError):
    """The goal is not connected to the start in the roadmap."""


class StoreError(IcenavError):
    """The session store could not read or write (disk full, read-only, locked, ...)."""


class SessionLockedError(StoreError):
    """Another process holds the session file open for writing; ``holder`` says who
    ("pid 1234 on host lab-pc"); the file may still be opened read-only."""

    def __init__(self, message: str, holder: str = "") -> None:
        super().__init__(message)
        self.holder = holder


class MotionAborted(IcenavError):
    """An automatic motion was aborted (operator input, stop or e-stop)."""


class CommandTimeoutError(IcenavError, TimeoutError):
    """Waiting for a command's outcome (``Ticket.result`` / ``Ticket.final``) timed out."""


class CommandRefusedError(IcenavError):
    """A command was refused: not authorized, in FAULT / ESTOP, no such view, ... (the text
    says why; the controller reports it through the command's ticket)."""


class HardwareError(IcenavError):
    """A robot backend reports a problem."""


class DriveFaultError(HardwareError):
    """A motor drive is in FAULT.

    Attributes
    ----------
    axis : str
        The axis whose drive faulted.
    code : int
        The drive's error code (CiA 402 error code / EMCY code), 0 if unknown.
    """

    def __init__(self, message: str, *, axis: str = "", code: int = 0):
        super().__init__(message)
        self.axis = axis
        self.code = code


class HeartbeatLostError(HardwareError):
    """A drive stopped sending heartbeats within its supervision time."""


class EmergencyStopError(HardwareError):
    """The robot is emergency-stopped; motion needs an explicit reset."""


class TrackerError(IcenavError):
    """The tracker is not running, or is misconfigured."""


class RegistrationError(TrackerError):
    """The tracker's registration to the robot base is missing, failed, or its residual
    exceeds the allowed limit (mm)."""


class ExportError(IcenavError):
    """Writing an export failed (the disk is full, no permission, ...)."""


class UnsafeExportPathError(InvalidValueError):
    """An export would be written outside its export directory (a symlink, a directory
    replaced after it was configured)."""


class CommandStepError(InvalidValueError):
    """A position command jumps farther than the backend's per-command maximum step."""


class IgtlError(IcenavError):
    """The OpenIGTLink server cannot start (the port is taken) or is used wrongly."""


class IgtlProtocolError(IgtlError):
    """A peer's bytes break the OpenIGTLink protocol (header, size, CRC, body).

    ``kind`` names the class of fault for the server's counters: "bad_header",
    "oversize", "bad_crc", "unknown_type", "bad_device", "malformed", "non_finite".
    """

    def __init__(self, message: str, kind: str = "malformed") -> None:
        super().__init__(message)
        self.kind = kind


class RoadmapFullError(PlanningError):
    """The vertex budget (``RoadmapConfig.max_vertices``) is used up: a view whose state is
    not already a vertex cannot be recorded exactly."""


class ViewExistsError(InvalidValueError):
    """A view with that name already exists in the library."""


class ViewNotFoundError(IcenavError, KeyError):
    """No view with that name in the library."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class NeighbourhoodError(PlanningError):
    """A refinement set-point would leave the neighbourhood of the saved view."""


class JobError(IcenavError):
    """A job of a population run (:func:`icenav.eval.engine.run_jobs`) failed.

    Attributes
    ----------
    item : object
        The item whose job failed (e.g. the catheter seed).
    index : int
        Its position in the items.
    remote_traceback : str
        The traceback text from the worker that ran it ("" when it ran in this process;
        the exception is then chained as ``__cause__``).
    """

    def __init__(self, message: str, *, item: object, index: int, remote_traceback: str = ""):
        super().__init__(message)
        self.item = item
        self.index = index
        self.remote_traceback = remote_traceback
