"""Configuration of a CANopen robot, loaded from a TOML file (see ``examples/robot.toml``).

Five CiA 402 drives move the four joints ``q = (phi1, phi2, phi3, d4)``: one drive per knob,
one for the translation, and two for the roll axis ``phi3`` (the *front* motor holds the
catheter shaft, the *back* motor the handle; they are commanded in step and their difference
is supervised).

The conversion between joint units (rad or mm) and encoder counts lives here and only here:
:meth:`MotorConfig.to_counts` and :meth:`MotorConfig.from_counts`.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icenav._validation import JOINT_NAMES, JOINT_UNITS, check_positive, read_toml
from icenav.errors import ConfigurationError

__all__ = [
    "BusConfig",
    "ControlMode",
    "HeartbeatConfig",
    "HomingConfig",
    "JointConfig",
    "MotorConfig",
    "RobotConfig",
    "bundled_eds_path",
    "load_robot_config",
]

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1


def bundled_eds_path() -> Path:
    """Path of the EDS shipped with icenav (the emulated drive's object dictionary)."""
    return Path(str(resources.files("icenav.devices.canopen") / "data" / "emulated_drive.eds"))


class ControlMode(enum.Enum):
    """How set-points reach the drives."""

    PROFILE_POSITION = "profile_position"
    """CiA 402 profile position (mode 1): each command is a new set-point with the
    new-set-point / set-point-acknowledge handshake; the drive plans the motion."""
    CYCLIC_SYNCHRONOUS_POSITION = "cyclic_synchronous_position"
    """CiA 402 cyclic synchronous position (mode 8): the controller streams targets and a
    SYNC after each cycle's targets; all drives apply them on the same SYNC."""


@dataclass(frozen=True)
class BusConfig:
    """The CAN bus (python-can interface)."""

    interface: str = "socketcan"
    """python-can interface name ("socketcan", "pcan", "kvaser", "virtual", ...)."""
    channel: str = "can0"
    """Interface channel ("can0", "PCAN_USBBUS1", a virtual bus name, ...)."""
    bitrate: int = 1_000_000
    """Bit rate (bit/s)."""


@dataclass(frozen=True)
class HeartbeatConfig:
    """Heartbeat production (drives) and consumption (icenav)."""

    producer_ms: int = 50
    """Heartbeat period written to every drive's object 0x1017 (ms)."""
    consumer_s: float = 0.2
    """A drive whose last heartbeat is older than this is lost: FAULT (s)."""


@dataclass(frozen=True)
class HomingConfig:
    """The CiA 402 homing procedure (mode 6)."""

    method: int = 37
    """Homing method (object 0x6098): 37 (or the older 35) = the current position is home,
    i.e. the operator sets the catheter to neutral by hand before homing."""
    timeout_s: float = 30.0
    """Homing must finish within this time (s)."""


@dataclass(frozen=True)
class JointConfig:
    """Limits of one joint, in the joint's unit (rad for phi1..phi3, mm for d4)."""

    name: str
    """Joint name: phi1, phi2, phi3 or d4."""
    low: float
    """Lower position limit (rad or mm); -inf for none (roll)."""
    high: float
    """Upper position limit (rad or mm); inf for none (roll)."""
    max_velocity: float
    """Profile velocity of the joint (rad/s or mm/s)."""
    following_error_window: float
    """Largest allowed difference between demanded and actual position before the drive
    faults (rad or mm); written to object 0x6065."""

    @property
    def unit(self) -> str:
        """Unit of the joint's positions ("rad" or "mm")."""
        return JOINT_UNITS[JOINT_NAMES.index(self.name)]


@dataclass(frozen=True)
class MotorConfig:
    """One CiA 402 drive and its motor."""

    name: str
    """Axis name used in messages ("ap_knob", "roll_front", ...)."""
    joint: str
    """The joint it moves: phi1, phi2, phi3 or d4."""
    node_id: int
    """CANopen node id (1..127)."""
    counts_per_rev: int
    """Encoder counts per motor revolution (after quadrature)."""
    gear_ratio: float
    """Motor revolutions per output revolution (knob, roll ring or lead screw)."""
    mm_per_rev: float = 0.0
    """Translation per output revolution (mm), for the d4 motor only (lead screw pitch)."""
    direction: int = 1
    """+1 if positive counts move the joint positively, -1 otherwise."""
    role: str = ""
    """For the two phi3 motors: "front" (holds the shaft) or "back" (holds the handle)."""
    eds: Path | None = None
    """The drive's EDS file; None = the EDS bundled with icenav (emulated drive)."""

    @property
    def counts_per_unit(self) -> float:
        """Encoder counts per rad (phi1..phi3) or per mm (d4)."""
        per_output_rev = self.counts_per_rev * self.gear_ratio
        if self.joint == "d4":
            return per_output_rev / self.mm_per_rev
        return per_output_rev / (2.0 * math.pi)

    def to_counts(self, value: float) -> int:
        """Joint position (rad or mm) -> drive position (counts, int32).

        Raises ConfigurationError when the result does not fit the drive's 32-bit range.
        """
        counts = round(self.direction * float(value) * self.counts_per_unit)
        if not INT32_MIN <= counts <= INT32_MAX:
            unit = "mm" if self.joint == "d4" else "rad"
            raise ConfigurationError(
                f"axis {self.name}: {self.joint} = {value:.6g} {unit} is {counts} counts, "
                f"outside the drive's int32 range [{INT32_MIN}, {INT32_MAX}]"
            )
        return counts

    def from_counts(self, counts: int) -> float:
        """Drive position (counts) -> joint position (rad or mm)."""
        return self.direction * float(counts) / self.counts_per_unit

    def magnitude_to_counts(self, value: float) -> int:
        """A speed (rad/s or mm/s) or a window (rad or mm) -> counts/s or counts (>= 1)."""
        return max(1, round(abs(float(value)) * self.counts_per_unit))


@dataclass(frozen=True)
class RobotConfig:
    """Everything :class:`~icenav.devices.canopen.robot.CANopenRobot` needs."""

    joints: tuple[JointConfig, ...]
    """The four joints, in the order phi1, phi2, phi3, d4."""
    motors: tuple[MotorConfig, ...]
    """The five drives: one each for phi1, phi2, d4 and two (front, back) for phi3."""
    bus: BusConfig = BusConfig()
    """The CAN bus."""
    mode: ControlMode = ControlMode.PROFILE_POSITION
    """Profile position or cyclic synchronous position."""
    sync_period_s: float = 0.01
    """Controller cycle / SYNC period (s); written to 0x1006 in cyclic synchronous mode."""
    heartbeat: HeartbeatConfig = HeartbeatConfig()
    """Heartbeat production and supervision."""
    homing: HomingConfig = HomingConfig()
    """Homing procedure."""
    roll_difference_limit: float = 0.05
    """Largest allowed |front - back| roll motor difference (rad) before FAULT."""
    sdo_timeout_s: float = 0.5
    """Timeout of one SDO transfer (s)."""
    handshake_timeout_s: float = 0.1
    """Time allowed for the drives' set-point acknowledge / state change (s)."""
    supervision_period_s: float = 0.005
    """Period of the background supervision (heartbeat, EMCY, roll difference) (s)."""

    def __post_init__(self) -> None:
        _validate(self)

    @property
    def limits(self) -> NDArray[np.float64]:
        """(4, 2) joint limits (rad, rad, rad, mm), as icenav._validation expects."""
        return np.array([[j.low, j.high] for j in self.joints], dtype=np.float64)

    def motors_of(self, joint: str) -> tuple[MotorConfig, ...]:
        """The motors that move ``joint`` (two for phi3: front, back)."""
        found = [m for m in self.motors if m.joint == joint]
        return tuple(sorted(found, key=lambda m: m.role != "front"))

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], base_dir: Path | None = None) -> RobotConfig:
        """Build from the parsed TOML (relative EDS paths resolve against ``base_dir``)."""
        known = {
            "bus",
            "control",
            "heartbeat",
            "homing",
            "joints",
            "motors",
            "supervision",
        }
        _no_unknown(data, known, "robot configuration")
        control = dict(data.get("control", {}))
        _no_unknown(control, {"mode", "sync_period_s"}, "[control]")
        try:
            mode = ControlMode(control.pop("mode", ControlMode.PROFILE_POSITION.value))
        except ValueError as exc:
            allowed = ", ".join(m.value for m in ControlMode)
            raise ConfigurationError(
                f"[control] mode must be one of {allowed}, got {data['control']['mode']!r}"
            ) from exc
        sup = dict(data.get("supervision", {}))
        _no_unknown(
            sup,
            {
                "roll_difference_limit",
                "sdo_timeout_s",
                "handshake_timeout_s",
                "supervision_period_s",
            },
            "[supervision]",
        )
        joints_tbl = data.get("joints", {})
        _no_unknown(joints_tbl, set(JOINT_NAMES), "[joints]")
        joints = []
        for name in JOINT_NAMES:
            if name not in joints_tbl:
                raise ConfigurationError(f"[joints.{name}] is missing")
            jt = dict(joints_tbl[name])
            _no_unknown(
                jt, {"low", "high", "max_velocity", "following_error_window"}, f"[joints.{name}]"
            )
            joints.append(
                JointConfig(
                    name=name,
                    low=float(jt.get("low", -math.inf)),
                    high=float(jt.get("high", math.inf)),
                    max_velocity=_req(jt, "max_velocity", f"[joints.{name}]"),
                    following_error_window=_req(jt, "following_error_window", f"[joints.{name}]"),
                )
            )
        motors = []
        for i, mt in enumerate(data.get("motors", [])):
            mt = dict(mt)
            where = f"[[motors]] #{i + 1}"
            _no_unknown(
                mt,
                {
                    "name",
                    "joint",
                    "node_id",
                    "counts_per_rev",
                    "gear_ratio",
                    "mm_per_rev",
                    "direction",
                    "role",
                    "eds",
                },
                where,
            )
            eds_text = str(mt.get("eds", ""))
            eds: Path | None = None
            if eds_text:
                eds = Path(eds_text)
                if not eds.is_absolute() and base_dir is not None:
                    eds = base_dir / eds
            motors.append(
                MotorConfig(
                    name=str(mt.get("name", f"motor{i + 1}")),
                    joint=str(mt.get("joint", "")),
                    node_id=int(_req(mt, "node_id", where)),
                    counts_per_rev=int(_req(mt, "counts_per_rev", where)),
                    gear_ratio=_req(mt, "gear_ratio", where),
                    mm_per_rev=float(mt.get("mm_per_rev", 0.0)),
                    direction=int(mt.get("direction", 1)),
                    role=str(mt.get("role", "")),
                    eds=eds,
                )
            )
        bus_tbl = dict(data.get("bus", {}))
        _no_unknown(bus_tbl, {"interface", "channel", "bitrate"}, "[bus]")
        hb = dict(data.get("heartbeat", {}))
        _no_unknown(hb, {"producer_ms", "consumer_s"}, "[heartbeat]")
        hm = dict(data.get("homing", {}))
        _no_unknown(hm, {"method", "timeout_s"}, "[homing]")
        return cls(
            joints=tuple(joints),
            motors=tuple(motors),
            bus=BusConfig(**bus_tbl),
            mode=mode,
            sync_period_s=float(control.get("sync_period_s", 0.01)),
            heartbeat=HeartbeatConfig(**hb),
            homing=HomingConfig(**hm),
            **{k: float(v) for k, v in sup.items()},
        )


def load_robot_config(path: str | Path) -> RobotConfig:
    """Read a robot configuration TOML file (see ``examples/robot.toml``).

    Raises FileFormatError for a file that is not TOML, ConfigurationError for bad values.
    """
    p = Path(path)
    data = read_toml(p, "robot configuration")
    return RobotConfig.from_mapping(data, base_dir=p.parent)


def _req(table: Mapping[str, Any], key: str, where: str) -> float:
    if key not in table:
        raise ConfigurationError(f"{where}: {key} is missing")
    try:
        return float(table[key])
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f"{where}: {key} must be a number, got {table[key]!r}") from exc


def _no_unknown(table: Mapping[str, Any], known: set[str], where: str) -> None:
    unknown = sorted(set(table) - known)
    if unknown:
        raise ConfigurationError(
            f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(known))}"
        )


def _validate(cfg: RobotConfig) -> None:
    names = tuple(j.name for j in cfg.joints)
    if names != JOINT_NAMES:
        raise ConfigurationError(f"joints must be {JOINT_NAMES} in this order, got {names}")
    for j in cfg.joints:
        if not j.low < j.high:
            raise ConfigurationError(
                f"joint {j.name}: low ({j.low} {j.unit}) must be < high ({j.high} {j.unit})"
            )
        check_positive(j.max_velocity, f"joint {j.name} max_velocity", f"{j.unit}/s")
        check_positive(j.following_error_window, f"joint {j.name} following_error_window", j.unit)
    counts = {name: len([m for m in cfg.motors if m.joint == name]) for name in JOINT_NAMES}
    expected = {"phi1": 1, "phi2": 1, "phi3": 2, "d4": 1}
    if counts != expected or len(cfg.motors) != 5:
        raise ConfigurationError(
            "the robot needs five motors: one each for phi1, phi2, d4 and two (front, back) "
            f"for phi3; got motors per joint {counts}"
        )
    roll_roles = sorted(m.role for m in cfg.motors if m.joint == "phi3")
    if roll_roles != ["back", "front"]:
        raise ConfigurationError(
            f'the two phi3 motors need role = "front" and role = "back", got {roll_roles}'
        )
    ids = [m.node_id for m in cfg.motors]
    if len(set(ids)) != len(ids):
        raise ConfigurationError(f"node ids must be unique, got {ids}")
    names_m = [m.name for m in cfg.motors]
    if len(set(names_m)) != len(names_m):
        raise ConfigurationError(f"motor names must be unique, got {names_m}")
    for m in cfg.motors:
        if not 1 <= m.node_id <= 127:
            raise ConfigurationError(
                f"motor {m.name}: node_id must be in [1, 127], got {m.node_id}"
            )
        if m.counts_per_rev < 1:
            raise ConfigurationError(
                f"motor {m.name}: counts_per_rev must be >= 1 count/rev, got {m.counts_per_rev}"
            )
        check_positive(m.gear_ratio, f"motor {m.name} gear_ratio", "motor rev / output rev")
        if m.joint == "d4":
            check_positive(m.mm_per_rev, f"motor {m.name} mm_per_rev", "mm/rev")
        if m.direction not in (1, -1):
            raise ConfigurationError(
                f"motor {m.name}: direction must be 1 or -1, got {m.direction}"
            )
        if m.eds is not None and not m.eds.is_file():
            raise ConfigurationError(f"motor {m.name}: EDS file {m.eds} does not exist")
    hb = cfg.heartbeat
    if not 1 <= hb.producer_ms <= 65535:
        raise ConfigurationError(
            f"heartbeat producer_ms must be in [1, 65535] ms, got {hb.producer_ms} ms"
        )
    check_positive(hb.consumer_s, "heartbeat consumer_s", "s")
    if hb.consumer_s * 1000.0 <= hb.producer_ms:
        raise ConfigurationError(
            f"heartbeat consumer_s ({hb.consumer_s} s) must exceed the producer period "
            f"({hb.producer_ms} ms); use about 3 periods"
        )
    check_positive(cfg.homing.timeout_s, "homing timeout_s", "s")
    if not -128 <= cfg.homing.method <= 127:
        raise ConfigurationError(f"homing method must be in [-128, 127], got {cfg.homing.method}")
    check_positive(cfg.sync_period_s, "sync_period_s", "s")
    check_positive(cfg.roll_difference_limit, "roll_difference_limit", "rad")
    check_positive(cfg.sdo_timeout_s, "sdo_timeout_s", "s")
    check_positive(cfg.handshake_timeout_s, "handshake_timeout_s", "s")
    check_positive(cfg.supervision_period_s, "supervision_period_s", "s")
