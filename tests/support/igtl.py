"""OpenIGTLink test helpers: a pyigtl client that keeps every message, raw messages as a
hostile peer writes them, and a paced pose stream. Real sockets on loopback only."""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pyigtl
from pyigtl.messages import CRC64

from icenav.io.igtl import DEVICE_TIP_TO_BASE, IgtlBridge, wait_for_client

TIMEOUT_S = 10.0


class RecordingClient(pyigtl.OpenIGTLinkClient):  # type: ignore[misc]
    """pyigtl's client, keeping *every* message received (pyigtl keeps the latest per
    device), with a condition to wait on."""

    def __init__(self, port: int) -> None:
        self.received: list[Any] = []
        self.changed = threading.Condition()
        super().__init__(host="127.0.0.1", port=port)

    def _receive_message_from_socket(self, ssocket: socket.socket) -> bool:
        got = bool(super()._receive_message_from_socket(ssocket))
        if got:
            with self.lock_incoming_messages:
                new = list(self.incoming_messages.values())
                self.incoming_messages = {}
            with self.changed:
                self.received.extend(new)
                self.changed.notify_all()
        return got

    def messages(self, device: str) -> list[Any]:
        with self.changed:
            return [m for m in self.received if m.device_name == device]

    def wait_until(self, predicate: Callable[[], bool], timeout: float = TIMEOUT_S) -> bool:
        with self.changed:
            return self.changed.wait_for(predicate, timeout=timeout)

    def wait_for(self, device: str, accept: Callable[[Any], bool] = lambda m: True) -> Any:
        """The first message of ``device`` that ``accept`` takes (AssertionError after
        TIMEOUT_S)."""
        found: list[Any] = []

        def ready() -> bool:
            found[:] = [m for m in self.received if m.device_name == device and accept(m)]
            return bool(found)

        assert self.wait_until(ready), f"no acceptable {device} message within {TIMEOUT_S} s"
        return found[0]

    def close(self) -> None:
        self.stop()
        if self.socket is not None:
            self.socket.close()


@contextlib.contextmanager
def connected_client(bridge: IgtlBridge, n_before: int = 0) -> Iterator[RecordingClient]:
    """A recording pyigtl client connected to ``bridge`` (``n_before`` clients already)."""
    client = RecordingClient(bridge.port)
    try:
        assert wait_for_client(bridge, TIMEOUT_S, n=n_before + 1)
        yield client
    finally:
        client.close()


def raw_message(
    mtype: str,
    device: str,
    body: bytes,
    *,
    crc: int | None = None,
    size: int | None = None,
    version: int = 1,
) -> bytes:
    """An OpenIGTLink message as bytes, with its CRC and size right unless told."""
    header = struct.pack(
        ">H12s20sIIQQ",
        version,
        mtype.encode("latin-1"),
        device.encode("latin-1"),
        0,
        0,
        len(body) if size is None else size,
        CRC64(body) if crc is None else crc,
    )
    return header + body


def string_body(text: str, encoding: int = 3, length: int | None = None) -> bytes:
    raw = text.encode("utf-8")
    return struct.pack(">HH", encoding, len(raw) if length is None else length) + raw


def command_message(text: str) -> bytes:
    return raw_message("STRING", "IcenavCommand", string_body(text))


def raw_connection(port: int) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=TIMEOUT_S)
    return sock


class PoseStream:
    """Sends ``TipToBase`` with time stamps 0, 1, 2, ... at ``rate_hz`` on a thread, paced
    by deadlines (it makes the stream; no test waits on its timing)."""

    def __init__(self, bridge: IgtlBridge, rate_hz: float = 50.0) -> None:
        self.bridge = bridge
        self.period = 1.0 / rate_hz
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        pose = np.eye(4)
        next_t = time.perf_counter()
        while not self._stop.is_set():
            pose[0, 3] = float(self.sent)
            self.bridge.send_pose(DEVICE_TIP_TO_BASE, pose, timestamp=float(self.sent))
            self.sent += 1
            next_t += self.period
            self._stop.wait(max(0.0, next_t - time.perf_counter()))

    def __enter__(self) -> PoseStream:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def distinct_stamps(client: RecordingClient, device: str = DEVICE_TIP_TO_BASE) -> set[float]:
    return {float(m.timestamp) for m in client.messages(device)}


class RawReader:
    """Reads whole messages from a raw socket (pyigtl unpacks them), keeping what it read
    past the message asked for."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.buf = b""

    def _need(self, n: int) -> bool:
        while len(self.buf) < n:
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                return False
            self.buf += chunk
        return True

    def next(self, device: str, timeout: float = TIMEOUT_S) -> Any:
        """The next message of ``device``; None if the server closed the connection first."""
        from pyigtl.messages import MessageBase

        size = MessageBase.IGTL_HEADER_SIZE
        self.sock.settimeout(timeout)
        while True:
            if not self._need(size):
                return None
            fields = MessageBase.parse_header(self.buf[:size])
            end = size + fields["body_size"]
            if not self._need(end):
                return None
            body, self.buf = self.buf[size:end], self.buf[end:]
            if fields["device_name"] == device:
                message = MessageBase.create_message(fields["message_type"])
                message.unpack(fields, body)
                return message


def read_until(sock: socket.socket, device: str, timeout: float = TIMEOUT_S) -> Any:
    """The next message of ``device`` on a raw socket read once (see RawReader)."""
    return RawReader(sock).next(device, timeout)
