"""Real-interface benchmarks: CANopen command round trip and OpenIGTLink frame rates.

* CANopen (five emulated CiA 402 drives on python-can's virtual bus): one command round trip
  = ``command_position`` (RPDOs, and in profile position the set-point handshake), drive
  ticks that reach the target, and ``read_state`` until it reports the new target (TPDO1).
  Baseline measured in the same run: one bare SDO upload (position actual value, node 1).
* OpenIGTLink (our server, over loopback): ICE images (uint8 480 x 640) and transforms
  received per second by a client. Baseline: packing the image message alone (the CPU
  bound of the sender).
* OpenIGTLink with hostile peers (``hostile_run``; ``ICENAV_BENCH_HOSTILE_S`` seconds,
  default 60): the distinct poses and images per second a good client receives while
  other peers idle, half-close, never read, trickle bytes and flood 64 KB messages,
  against the same client alone (baseline); the server process's RSS over the flood; then
  200 connections at once.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import struct
import subprocess
import sys
import threading
import time
import uuid

import numpy as np
import pyigtl
from pyigtl.messages import MessageBase

from benchmarks.common import Result, time_per_call
from icenav.devices.canopen.config import ControlMode
from icenav.devices.canopen.emulated_drive import EmulatedDriveSet, emulated_robot_config
from icenav.devices.canopen.robot import CANopenRobot
from icenav.io.igtl import IgtlBridge, IgtlConfig, ServerLimits, wait_for_client

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
    """(images/s received, transforms/s received, image messages packed/s): the bridge
    sends as fast as it can, the client counts what arrives."""
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, size=IMAGE_SHAPE, dtype=np.uint8)
    ijk2base = np.diag([0.25, 0.25, 1.0, 1.0])
    with IgtlBridge(IgtlConfig(port=0)) as bridge:
        client = _Counter(bridge.port)
        try:
            if not wait_for_client(bridge, 10.0):
                raise RuntimeError("OpenIGTLink client did not connect")

            def stream(send: object, n: int, device: str) -> float:
                t0 = time.perf_counter()
                for i in range(n):
                    send(i)  # type: ignore[operator]
                    if i % 20 == 19:  # let the client keep up (latest-wins would skip)
                        client.wait_for_stamp(device, float(i), 30.0)
                client.wait_for_stamp(device, float(n - 1), 30.0)
                return client.count(device) / (time.perf_counter() - t0)

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
        finally:
            client.close()
    message = pyigtl.ImageMessage(image[np.newaxis], ijk_to_world_matrix=ijk2base)
    pack_s = time_per_call(message.pack, min_time=0.2, repeat=3)
    return images_per_s, transforms_per_s, 1.0 / pack_s


class _Counter:
    """A raw-socket client counting the distinct time stamps it receives per device."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=1.0)
        self.stamps: dict[str, set[float]] = {}
        self.cond = threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        size = MessageBase.IGTL_HEADER_SIZE
        buf = bytearray()
        while not self._stop:
            try:
                chunk = self.sock.recv(1 << 20)
            except TimeoutError:
                continue
            except OSError:
                return
            if not chunk:
                return
            buf += chunk
            while len(buf) >= size:
                fields = MessageBase.parse_header(bytes(buf[:size]))
                end = size + fields["body_size"]
                if len(buf) < end:
                    break
                del buf[:end]
                with self.cond:
                    self.stamps.setdefault(fields["device_name"], set()).add(fields["timestamp"])
                    self.cond.notify_all()

    def count(self, device: str) -> int:
        with self.cond:
            return len(self.stamps.get(device, ()))

    def wait_for_stamp(self, device: str, stamp: float, timeout: float) -> None:
        with self.cond:
            ok = self.cond.wait_for(
                lambda: any(abs(s - stamp) < 1e-3 for s in self.stamps.get(device, ())),
                timeout=timeout,
            )
        if not ok:
            raise RuntimeError(f"{device} {stamp} never arrived")

    def close(self) -> None:
        self._stop = True
        self.sock.close()
        self._thread.join(timeout=5.0)


# ------------------------------------------------------------------ hostile peers, 60 s

_SERVER = """
import json, sys, threading, time
import numpy as np
from icenav.io.igtl import IgtlBridge, IgtlConfig

bridge = IgtlBridge(IgtlConfig(port=0))
image = np.random.default_rng(0).integers(0, 256, (480, 640), dtype=np.uint8)
stop = threading.Event()

def stream():  # TipToBase at 50 Hz, Image at 15 Hz, time stamps 0, 1, 2, ...
    k = 0
    nxt = time.perf_counter()
    pose = np.eye(4)
    while not stop.is_set():
        bridge.send_pose("TipToBase", pose, timestamp=float(k))
        if k % 10 in (0, 3, 7):
            bridge.send_image("Image", image, np.eye(4), timestamp=float(k))
        k += 1
        nxt += 0.02
        stop.wait(max(0.0, nxt - time.perf_counter()))

threading.Thread(target=stream, daemon=True).start()
print(bridge.port, flush=True)
for line in sys.stdin:
    rss = [int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmRSS")][0]
    s = bridge.stats()
    print(json.dumps({"rss_kb": rss, "peak_buffered": s.peak_buffered_bytes,
                      "refused": s.refused, "closed": s.closed, "faults": s.faults,
                      "bytes_in": s.bytes_in, "dropped": s.frames_dropped,
                      "refused_commands": bridge.command_counts["refused"]}), flush=True)
stop.set()
bridge.close()
"""


def _flood(port: int, device: str, stop: threading.Event, sent: list[int]) -> None:
    """Send 64 KB STRING messages as fast as the server takes them, never reading; when
    the server closes the connection (it stopped reading and nothing we owe was taken for
    30 s), connect again."""
    body = struct.pack(">HH", 3, 64 * 1024 - 4) + b"x" * (64 * 1024 - 4)
    header = struct.pack(">H12s20sIIQQ", 1, b"STRING", device.encode(), 0, 0, len(body), 0)
    from pyigtl.messages import CRC64

    message = header[:-8] + struct.pack(">Q", CRC64(body)) + body
    while not stop.is_set():
        try:
            with socket.create_connection(("127.0.0.1", port)) as sock:
                sock.settimeout(0.5)
                while not stop.is_set():
                    try:
                        sock.sendall(message)
                        sent[0] += len(message)
                    except TimeoutError:
                        continue
        except OSError:
            stop.wait(0.1)


def _slow(port: int, stop: threading.Event) -> None:
    with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port)) as sock:
        for _ in range(1000):  # one byte every 2 s, then again on a new connection
            sock.sendall(b"\x00")
            if stop.wait(2.0):
                return


def hostile_run(duration_s: float = 60.0) -> dict[str, float]:
    """The server in a process of its own (its RSS is then its own), streaming 50 Hz poses and
    15 Hz 480 x 640 images; a good client counts what it receives, alone (baseline) and
    while peers are idle, half-closed, deaf (never read), send one byte every 2 s, flood
    64 KB commands (4 peers) and 64 KB messages to another device (1 peer), for
    ``duration_s``; then 200 connections at once."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _SERVER],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stdin is not None

    def probe() -> dict[str, object]:
        proc.stdin.write("stats\n")  # type: ignore[union-attr]
        proc.stdin.flush()  # type: ignore[union-attr]
        return json.loads(proc.stdout.readline())  # type: ignore[union-attr, no-any-return]

    port = int(proc.stdout.readline())
    out: dict[str, float] = {}
    try:
        good = _Counter(port)
        t0, n0, i0 = time.perf_counter(), good.count("TipToBase"), good.count("Image")
        time.sleep(10.0)  # the measurement window (the stream is paced by the server)
        dt = time.perf_counter() - t0
        out["alone_poses_s"] = (good.count("TipToBase") - n0) / dt
        out["alone_images_s"] = (good.count("Image") - i0) / dt
        rss0 = probe()["rss_kb"]
        stop = threading.Event()
        sent = [0]
        idle = socket.create_connection(("127.0.0.1", port))
        half = socket.create_connection(("127.0.0.1", port))
        half.shutdown(socket.SHUT_WR)
        deaf = socket.create_connection(("127.0.0.1", port))
        deaf.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        threads = [threading.Thread(target=_slow, args=(port, stop), daemon=True)]
        for device in ("IcenavCommand",) * 4 + ("Flood",):
            threads.append(
                threading.Thread(target=_flood, args=(port, device, stop, sent), daemon=True)
            )
        for t in threads:
            t.start()
        t0, n0, i0 = time.perf_counter(), good.count("TipToBase"), good.count("Image")
        rss_max = float(rss0)  # type: ignore[arg-type]
        while time.perf_counter() - t0 < duration_s:
            time.sleep(5.0)
            rss_max = max(rss_max, float(probe()["rss_kb"]))  # type: ignore[arg-type]
        dt = time.perf_counter() - t0
        out["hostile_poses_s"] = (good.count("TipToBase") - n0) / dt
        out["hostile_images_s"] = (good.count("Image") - i0) / dt
        stop.set()
        for t in threads:
            t.join(timeout=10.0)
        for s in (idle, half, deaf):
            s.close()
        end = probe()
        out["flood_mb"] = sent[0] / 1e6
        out["rss_start_mb"] = float(rss0) / 1024  # type: ignore[arg-type]
        out["rss_max_mb"] = rss_max / 1024
        out["peak_buffered_mb"] = float(end["peak_buffered"]) / 1e6  # type: ignore[arg-type]
        out["refused_commands"] = float(end["refused_commands"])  # type: ignore[arg-type]
        out["frames_dropped"] = float(end["dropped"])  # type: ignore[arg-type]
        # 200 connections at once
        t0, n0 = time.perf_counter(), good.count("TipToBase")
        socks = [socket.create_connection(("127.0.0.1", port)) for _ in range(200)]
        time.sleep(5.0)
        out["burst_poses_s"] = (good.count("TipToBase") - n0) / (time.perf_counter() - t0)
        out["burst_refused"] = float(probe()["refused"]) - float(end["refused"])  # type: ignore[arg-type]
        for s in socks:
            s.close()
        good.close()
    finally:
        proc.stdin.close()
        proc.wait(timeout=30)
    return out


def _bound_mb(clients: int) -> float:
    """The stated bound of what the server keeps (docs/safety.md), default limits, with
    480 x 640 images: per client one incoming message and one read, the commands waiting,
    the replies unsent and a frame in flight; the frames queued, shared (per device at most
    max_device_backlog_bytes or one image)."""
    lim = ServerLimits()
    image = 58 + 12 + 48 + 12 + IMAGE_SHAPE[0] * IMAGE_SHAPE[1]
    per_client = (
        58
        + lim.max_body_bytes
        + lim.recv_chunk_bytes
        + lim.max_pending_commands * (58 + lim.max_body_bytes)
        + (lim.max_queued_replies + lim.max_commands_per_message) * 256
        + image
    )
    return (clients * per_client + 4 * max(lim.max_device_backlog_bytes, image)) / 1e6


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
    h = hostile_run(float(os.environ.get("ICENAV_BENCH_HOSTILE_S", "60")))
    results += [
        Result(
            name="OpenIGTLink TipToBase to a good client beside hostile peers (50 Hz stream)",
            value=h["hostile_poses_s"],
            unit="poses/s",
            baseline=h["alone_poses_s"],
            baseline_name="the same client alone",
            target=">= 30 distinct poses/s",
            met=h["hostile_poses_s"] >= 30.0,
        ),
        Result(
            name="OpenIGTLink Image to a good client beside hostile peers (15 Hz stream)",
            value=h["hostile_images_s"],
            unit="images/s",
            baseline=h["alone_images_s"],
            baseline_name="the same client alone",
            target=">= 15 images/s (stream rate 15)",
            met=h["hostile_images_s"] >= 14.5,
        ),
        Result(
            name=f"OpenIGTLink server RSS, max over a {h['flood_mb']:.0f} MB flood",
            value=h["rss_max_mb"],
            unit="MB",
            baseline=h["rss_start_mb"],
            baseline_name="RSS before the flood",
            target="within 20 MB of the start",
            met=h["rss_max_mb"] - h["rss_start_mb"] <= 20.0,
        ),
        Result(
            name="OpenIGTLink server: bytes kept for clients, peak",
            value=h["peak_buffered_mb"],
            unit="MB",
            target=f"<= {_bound_mb(9):.1f} MB (the stated bound for 9 peers, docs/safety.md)",
            met=h["peak_buffered_mb"] <= _bound_mb(9),
        ),
        Result(
            name="OpenIGTLink TipToBase during 200 connections at once",
            value=h["burst_poses_s"],
            unit="poses/s",
            baseline=h["alone_poses_s"],
            baseline_name="the same client alone",
            target=f">= 30 poses/s ({h['burst_refused']:.0f} connections refused at the cap)",
            met=h["burst_poses_s"] >= 30.0,
        ),
    ]
    print(f"  (hostile run: {h})")
    return results


if __name__ == "__main__":
    from benchmarks.common import print_results

    print_results(main())
