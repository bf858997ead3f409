"""A lab bench without hardware: emulated CiA 402 drives on python-can's virtual bus behind a
robot TOML (examples/robot.toml with the bus made virtual), and an NDI Aurora (the mocked
ndicapy of tests/support/ndi.py) whose sensor follows the drives through the kinematics."""

from __future__ import annotations

import contextlib
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from icenav.devices.canopen.config import load_robot_config
from icenav.devices.canopen.emulated_drive import EmulatedDriveSet
from icenav.geometry.kinematics import forward
from icenav.geometry.se3 import rigid_inverse
from tests.support.ndi import FakeAurora, Pose

EXAMPLE_ROBOT = Path(__file__).resolve().parents[2] / "examples" / "robot.toml"

# the lab's truth: where the field generator stands and where the sensor sits at the tip
TRUE_TRACKER2BASE = np.array(
    [
        [0.0, -1.0, 0.0, 40.0],
        [0.0, 0.0, -1.0, -25.0],
        [1.0, 0.0, 0.0, 300.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
TRUE_SENSOR2TIP = np.array(
    [[1.0, 0.0, 0.0, -1.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, -4.0], [0.0, 0.0, 0.0, 1.0]]
)


def robot_toml(folder: Path, channel: str) -> Path:
    """examples/robot.toml with its bus on the virtual channel ``channel``, a heartbeat
    consumer time of 2 s and a set-point handshake timeout of 1 s (the emulated drives
    answer from Python threads of the test process on a shared machine, not from drive
    firmware: 0.15 s and 0.1 s, and even 0.5 s, are missed at a load average of 12 on 2
    cores). The supervision itself is tested in tests/devices/canopen."""
    text = EXAMPLE_ROBOT.read_text(encoding="utf-8")
    for old, new in (
        ('interface = "socketcan"', 'interface = "virtual"'),
        ('channel = "can0"', f'channel = "{channel}"'),
        ("consumer_s = 0.15", "consumer_s = 2.0"),
        ("handshake_timeout_s = 0.1", "handshake_timeout_s = 1.0"),
    ):
        assert old in text, f"examples/robot.toml no longer has {old!r}"
        text = text.replace(old, new, 1)
    path = folder / "robot.toml"
    path.write_text(text, encoding="utf-8")
    return path


@contextlib.contextmanager
def emulated_bench(folder: Path, speed: float = 50.0) -> Iterator[tuple[Path, EmulatedDriveSet]]:
    """Five emulated drives ticking ``speed`` times faster than the wall clock (the
    registration's 36 states take seconds, not half a minute) and their robot TOML."""
    channel = f"test-bench-{uuid.uuid4().hex[:8]}"
    drives = EmulatedDriveSet(channel)
    stop = threading.Event()

    def tick() -> None:
        last = time.monotonic()
        while not stop.wait(0.002):
            now = time.monotonic()
            drives.tick(speed * (now - last))
            last = now

    thread = threading.Thread(target=tick, name="test-drives", daemon=True)
    thread.start()
    try:
        yield robot_toml(folder, channel), drives
    finally:
        stop.set()
        thread.join(timeout=5.0)
        drives.close()


class TrackingAurora(FakeAurora):
    """The mocked Aurora whose first tool is a sensor on the catheter tip: its pose is the
    kinematics of the drives' encoder positions seen from :data:`TRUE_TRACKER2BASE`."""

    def __init__(self, robot_config: Path, drives: EmulatedDriveSet) -> None:
        super().__init__()
        self._config = load_robot_config(robot_config)
        self._drives = drives

    def q(self) -> np.ndarray:
        q = np.zeros(4)
        for joint_index, joint in enumerate(("phi1", "phi2", "phi3", "d4")):
            motor = self._config.motors_of(joint)[0]
            q[joint_index] = motor.from_counts(self._drives[motor.node_id].position)
        return q

    def ndiCommand(self, device: str, command: str) -> None:  # noqa: N802
        if command == "INIT:":  # a new connection: the Aurora starts from scratch
            self.initialised.clear()
            self.enabled.clear()
        super().ndiCommand(device, command)

    def ndiGetBXTransform(self, device: str, handle: bytes) -> Pose | str:  # noqa: N802
        if handle[0] != self.handles[0]:
            return "MISSING"
        s2t = rigid_inverse(TRUE_TRACKER2BASE) @ forward(self.q()) @ TRUE_SENSOR2TIP
        x, y, z, w = Rotation.from_matrix(s2t[:3, :3]).as_quat()
        p = s2t[:3, 3]
        return (w, x, y, z, float(p[0]), float(p[1]), float(p[2]), 0.1)


def tracker_toml(folder: Path, *, sensor2tip: np.ndarray | None = TRUE_SENSOR2TIP) -> Path:
    """A tracker TOML for the mocked Aurora (no settling wait: the emulated drives stop dead)."""
    lines = ["[ndi]", 'serial_port = "/dev/ttyNDI0"', "tool_index = 0", ""]
    if sensor2tip is not None:
        rows = ", ".join("[" + ", ".join(f"{v:.6f}" for v in row) + "]" for row in sensor2tip)
        lines += ["[mount]", f"sensor2tip = [{rows}]", ""]
    lines += ["[registration]", "n_average = 2", "settle_s = 0.0", "max_residual_mm = 1.0"]
    path = folder / "tracker.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
