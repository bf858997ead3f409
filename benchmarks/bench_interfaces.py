"""Real-interface benchmarks: CANopen command round trip and OpenIGTLink frame rates.

* CANopen (five emulated CiA 402 drives on python-can's virtual bus): one command round trip
  = ``command_position`` (RPDOs, and in profile position the set-point handshake), drive
  ticks that reach the target, and ``read_state`` until it reports the new target (TPDO1).
  Baseline measured in the same run: one bare SDO upload (position actual value, node 1).
* OpenIGTLink (pyigtl server and client over loopback): ICE images (uint8 480 x 640) and
  transforms received per second by the client. Baseline: packing the image message alone
  (the CPU bound of the sender).
"""

from __future__ import annotations

import time
import uuid

import numpy as np
import pyigtl

from benchmarks.common import Result, time_per_call
from icenav.devices.canopen.config import ControlMode
from icenav.devices.canopen.emulated_drive import EmulatedDriveSet, emulated_robot_config
from icenav.devices.canopen.robot import CANopenRobot
from icenav.io.igtl import IgtlBridge, IgtlConfig, wait_for_client

IMAGE_SHAPE = (480, 640)


def _canopen_round_trip(mode: ControlMode) -> tuple[float, float]:
    """(seconds per command round trip, seconds per bare SDO upload)."""
    channel = f"bench-{uuid.uuid4().hex[:8]}"
    drives = EmulatedDriveSet(channel)
    robot = CANopenRobot(emulated_robot_config(channel, mode=mode))
    try:
        robot.enable()
        targets = [np.array([0.01, -0.01, 0.01, 0.1]), np.array([0.0, 0.0, 0.0, 0.0])]
        k = [0]

        def round_trip() -> None:
            q = targets[k[0] % 2]
            k[0] += 1
            robot.command_position(q)
            deadline = time.monotonic() + 2.0
            # A tick of 1 s reaches the target; in cyclic synchronous mode the drives take
            # it only at the SYNC, which their receive thread may not have handled yet.
            drives.tick(1.0)
            while np.max(np.abs(robot.read_state().q - q)) > 1e-3:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"target {q} not read back: {robot.read_state()}")
                time.sleep(0)
                drives.tick(1.0)

        node = robot.network[1]

        def sdo_upload() -> None:
            node.sdo.upload(0x6064, 0)

        t_rt = time_per_call(round_trip, min_time=0.3, repeat=3)
        t_sdo = time_per_call(sdo_upload, min_time=0.3, repeat=3)
        return t_rt, t_sdo
    finally:
        robot.close()
        drives.close()


def _igtl_rates(n_images: int = 200, n_transforms: int = 2000) -> tuple[float, float, float]:
    """(images/s received, transforms/s received, image messages packed/s)."""
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, size=IMAGE_SHAPE, dtype=np.uint8)
    ijk2base = np.diag([0.25, 0.25, 1.0, 1.0])
    bridge = IgtlBridge(IgtlConfig(port=0))
    client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=bridge.port)
    server = bridge._server  # the outgoing queue, for back-pressure (pyigtl drops at 100)
    try:
        if not wait_for_client(bridge, 10.0):
            raise RuntimeError("OpenIGTLink client did not connect")

        def stream(send: object, n: int, device: str) -> float:
            t0 = time.perf_counter()
            for i in range(n):
                send(i)  # type: ignore[operator]
                while len(server.outgoing_messages) > 50:
                    time.sleep(0.0005)
            last = float(n - 1)
            deadline = time.monotonic() + 30.0
            while time.monotonic() < deadline:
                msg = client.wait_for_message(device, timeout=0.01)
                if msg is not None and abs(msg.timestamp - last) < 1e-3:
                    return n / (time.perf_counter() - t0)
            raise RuntimeError(f"last {device} message never arrived")

        images_per_s = stream(
            lambda i: bridge.send_image("Image", image, ijk2base, timestamp=float(i)),
            n_images,
            "Image",
        )
        pose = np.eye(4)
        transforms_per_s = stream(
            lambda i: bridge.send_pose("TipToBase", pose, timestamp=float(i)),
            n_transforms,
            "TipToBase",
        )
        message = pyigtl.ImageMessage(image[np.newaxis], ijk_to_world_matrix=ijk2base)
        pack_s = time_per_call(message.pack, min_time=0.2, repeat=3)
        return images_per_s, transforms_per_s, 1.0 / pack_s
    finally:
        bridge.close()
        client.stop()
        if client.socket is not None:
            client.socket.close()


def main() -> list[Result]:
    results = []
    for mode in ControlMode:
        t_rt, t_sdo = _canopen_round_trip(mode)
        results.append(
            Result(
                name=f"CANopen command round trip, 5 drives, {mode.value}",
                value=t_rt * 1e6,
                unit="us/call",
                baseline=t_sdo * 1e6,
                baseline_name="one bare SDO upload",
                target="< 10 ms (one 100 Hz cycle)",
                met=t_rt < 0.010,
            )
        )
    images, transforms, packed = _igtl_rates()
    h, w = IMAGE_SHAPE
    results.append(
        Result(
            name=f"OpenIGTLink images received ({h}x{w} uint8)",
            value=images,
            unit="frames/s",
            baseline=packed,
            baseline_name="image messages packed/s (sender CPU bound)",
            target=">= 15 frames/s (live image rate)",
            met=images >= 15.0,
        )
    )
    results.append(
        Result(
            name="OpenIGTLink transforms received",
            value=transforms,
            unit="messages/s",
            target=">= 100 messages/s (controller rate)",
            met=transforms >= 100.0,
        )
    )
    return results


if __name__ == "__main__":
    from benchmarks.common import print_results

    print_results(main())
