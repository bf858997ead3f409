"""The OpenIGTLink server against hostile peers, on real loopback sockets (port 0).

A pyigtl client receives a 50 Hz ``TipToBase`` stream while another peer is idle, sends one
byte at a time, half-closes, floods 64 KB messages, never reads, or opens 200 connections;
every malformed message class leaves the server up. Checks count stamps (the client must
receive >= 95 % of the poses sent while the hostile peer acts) and wait on conditions with
timeouts; nothing waits on a sleep.
"""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest

from icenav.io.igtl import (
    DEVICE_COMMAND_ACK,
    DEVICE_IMAGE,
    DEVICE_STATUS,
    DEVICE_TIP_TO_BASE,
    IgtlBridge,
    IgtlCommand,
    IgtlConfig,
    IgtlOutcome,
    IgtlReply,
    ServerLimits,
)
from icenav.io.igtl_server import ServerStats
from tests.support.igtl import (
    TIMEOUT_S,
    PoseStream,
    RawReader,
    RecordingClient,
    command_message,
    connected_client,
    distinct_stamps,
    raw_connection,
    raw_message,
    read_until,
    string_body,
)

LIMITS = ServerLimits(max_clients=32, read_timeout_s=1.0, send_stall_timeout_s=2.0)
WINDOW = 60
"""Poses (at 50 Hz: 1.2 s) over which a good client's reception is counted."""


@pytest.fixture
def bridge() -> Iterator[IgtlBridge]:
    with IgtlBridge(IgtlConfig(port=0, limits=LIMITS)) as b:
        yield b


def _wait_stats(bridge: IgtlBridge, predicate: Callable[[ServerStats], bool]) -> ServerStats:
    assert bridge.server.wait_until(predicate, TIMEOUT_S), bridge.stats()
    return bridge.stats()


def _received_while(stream: PoseStream, client: RecordingClient) -> tuple[int, int]:
    """(received, sent) distinct poses among the next WINDOW poses streamed."""
    first = stream.sent
    last = first + WINDOW - 1
    assert client.wait_until(lambda: any(s >= last for s in distinct_stamps(client)))
    got = {s for s in distinct_stamps(client) if first <= s <= last}
    return len(got), WINDOW


class Hostile:
    """A peer doing one bad thing on a thread of its own until stopped."""

    def __init__(self, port: int, act: Callable[[socket.socket, threading.Event], None]):
        self.sock = raw_connection(port)
        self.stop = threading.Event()
        self.bytes_sent = 0
        self._thread = threading.Thread(target=self._run, args=(act,), daemon=True)

    def _run(self, act: Callable[[socket.socket, threading.Event], None]) -> None:
        with contextlib.suppress(OSError):
            act(self.sock, self.stop)

    def __enter__(self) -> Hostile:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self._thread.join(timeout=TIMEOUT_S)
        self.sock.close()


def _idle(sock: socket.socket, stop: threading.Event) -> None:
    stop.wait()


def _one_byte_at_a_time(sock: socket.socket, stop: threading.Event) -> None:
    message = command_message("stop")
    for b in message:  # one byte every 0.3 s: the message never completes in time
        sock.sendall(bytes([b]))
        if stop.wait(0.3):
            return


def _half_close_mid_message(sock: socket.socket, stop: threading.Event) -> None:
    sock.sendall(command_message("stop")[:30])
    sock.shutdown(socket.SHUT_WR)
    stop.wait()


def _flood_64k(sock: socket.socket, stop: threading.Event) -> None:
    big = command_message("save_view " + "x" * (64 * 1024 - 20))
    sock.settimeout(0.2)
    while not stop.is_set():
        with contextlib.suppress(TimeoutError):
            sock.sendall(big)


HOSTILE = {
    "idle": (_idle, None),
    "one_byte_at_a_time": (_one_byte_at_a_time, "read_timeout"),
    "half_close_mid_message": (_half_close_mid_message, "closed_mid_message"),
    "flood_64k_commands": (_flood_64k, None),
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_a_good_client_keeps_its_stream_beside_a_hostile_peer(
    bridge: IgtlBridge, name: str
) -> None:
    act, closed_reason = HOSTILE[name]
    with connected_client(bridge) as client, PoseStream(bridge) as stream:
        client.wait_for(DEVICE_TIP_TO_BASE)
        with Hostile(bridge.port, act):
            _wait_stats(bridge, lambda s: s.accepted >= 2)  # it may be closed already
            got, sent = _received_while(stream, client)
            if closed_reason is not None:
                _wait_stats(bridge, lambda s: s.closed.get(closed_reason, 0) == 1)
                got2, sent2 = _received_while(stream, client)
                got, sent = got + got2, sent + sent2
    assert got >= 0.95 * sent, (name, got, sent)
    stats = bridge.stats()
    # what the server kept for the two peers stayed within the stated bound
    assert stats.peak_buffered_bytes <= _memory_bound(LIMITS, clients=2), stats


def _memory_bound(limits: ServerLimits, clients: int, frame_bytes: int = 4096) -> int:
    """The stated bound of what the server keeps (docs/safety.md): per client, one message
    being received plus one read, the commands waiting, the replies not sent and a frame
    in flight; plus the frames queued, shared by all clients (per device at most
    max_device_backlog_bytes or one larger frame; four devices)."""
    per_client = (
        58
        + limits.max_body_bytes
        + limits.recv_chunk_bytes
        + limits.max_pending_commands * (58 + limits.max_body_bytes)
        + (limits.max_queued_replies + limits.max_commands_per_message) * 256
        + frame_bytes
    )
    return clients * per_client + 4 * max(limits.max_device_backlog_bytes, frame_bytes)


def test_a_flood_is_paid_by_the_flooder_and_memory_stays_bounded(bridge: IgtlBridge) -> None:
    """Four peers flood 64 KB command messages and never read their replies: the server
    stops reading from them (TCP pushes back), keeps one bounded backlog each, and the
    refused commands become counters and a bounded ring."""
    with connected_client(bridge) as client, PoseStream(bridge) as stream:
        client.wait_for(DEVICE_TIP_TO_BASE)
        floods = [Hostile(bridge.port, _flood_64k) for _ in range(4)]
        with contextlib.ExitStack() as stack:
            for f in floods:
                stack.enter_context(f)
            got, sent = 0, 0
            for _ in range(3):  # 3.6 s of flood
                g, s = _received_while(stream, client)
                got, sent = got + g, sent + s
    stats = bridge.stats()
    assert got >= 0.95 * sent, (got, sent)
    assert stats.bytes_in > 4 * LIMITS.max_queued_replies * 64 * 1024  # they did flood
    assert stats.peak_buffered_bytes <= _memory_bound(LIMITS, clients=5), stats
    assert bridge.command_counts["refused"] >= 4 * LIMITS.max_queued_replies
    # the server paused them; its own pause is not counted against their read deadline
    assert stats.closed.get("read_timeout", 0) == 0, stats
    assert len(bridge.command_log) == bridge.command_log.maxlen  # a ring, not a list


def test_a_client_that_never_reads_skips_frames_then_is_closed(bridge: IgtlBridge) -> None:
    image = np.random.default_rng(0).integers(0, 256, (480, 640), dtype=np.uint8)
    with connected_client(bridge) as client, PoseStream(bridge) as stream:
        client.wait_for(DEVICE_TIP_TO_BASE)
        deaf = raw_connection(bridge.port)  # connects and never reads
        try:
            assert bridge.server.wait_for_clients(2, TIMEOUT_S)
            stop = threading.Event()

            def images() -> None:
                k = 0
                while not stop.wait(1 / 30):
                    bridge.send_image(DEVICE_IMAGE, image, np.eye(4), timestamp=float(k))
                    k += 1

            t = threading.Thread(target=images, daemon=True)
            t.start()
            try:
                got, sent = _received_while(stream, client)
                stats = _wait_stats(bridge, lambda s: s.closed.get("send_stalled", 0) == 1)
                got2, sent2 = _received_while(stream, client)
            finally:
                stop.set()
                t.join()
        finally:
            deaf.close()
    assert got + got2 >= 0.95 * (sent + sent2)
    assert stats.frames_dropped > 0
    assert len(client.messages(DEVICE_IMAGE)) > 0


def test_200_connections_at_once(bridge: IgtlBridge) -> None:
    with connected_client(bridge) as client, PoseStream(bridge) as stream:
        client.wait_for(DEVICE_TIP_TO_BASE)
        socks = [socket.create_connection(("127.0.0.1", bridge.port)) for _ in range(200)]
        try:
            stats = _wait_stats(bridge, lambda s: s.accepted + s.refused >= 201)
            assert stats.clients == LIMITS.max_clients and stats.refused == 201 - 32
            got, sent = _received_while(stream, client)
            assert got >= 0.95 * sent
            # a refused peer is told why before it is closed
            refused = socks[-1]
            msg = read_until(refused, DEVICE_STATUS)
            assert msg is not None and "at most 32" in msg.string
        finally:
            for s in socks:
                s.close()
        _wait_stats(bridge, lambda s: s.clients == 1)
        with connected_client(bridge, n_before=1) as late:  # room again once they left
            late.wait_for(DEVICE_TIP_TO_BASE, lambda m: m.timestamp > stream.sent - 5)


def _transform_body(values: list[float]) -> bytes:
    return struct.pack(">12f", *values)


_EYE = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0, 0, 0, 0]
_MAX = LIMITS.max_body_bytes


def _v2_string(text: str, bad_sizes: bool) -> bytes:
    content = string_body(text)
    ext = struct.pack(">HHII", 12, 500 if bad_sizes else 0, 0, 0)
    return raw_message("STRING", "IcenavCommand", ext + content, version=2)


# (bytes a peer sends, then "closed:<reason>" or "fault:<kind>")
MALFORMED: dict[str, tuple[bytes, str]] = {
    "size_2**64-1": (raw_message("STRING", "X", b"", size=2**64 - 1), "closed:oversize"),
    "size_max+1": (raw_message("STRING", "X", b"", size=_MAX + 1), "closed:oversize"),
    "header_version_7": (raw_message("STRING", "X", b"", version=7), "closed:bad_header"),
    "binary_type": (raw_message("\x01\xff", "X", b""), "closed:bad_header"),
    "truncated_stream": (raw_message("STRING", "X", b"", size=100) + b"x" * 10, "closed:*"),
    "bad_crc": (raw_message("TRANSFORM", "T", _transform_body(_EYE), crc=1), "fault:bad_crc"),
    "bad_crc_command": (
        raw_message("STRING", "IcenavCommand", string_body("stop"), crc=7),
        "fault:bad_crc",
    ),
    "unknown_type": (raw_message("FOOBAR", "X", b"z" * 100), "fault:unknown_type"),
    "truncated_body": (raw_message("TRANSFORM", "T", b"\0" * 10), "fault:malformed"),
    "nan_matrix": (
        raw_message("TRANSFORM", "T", _transform_body([float("nan")] * 12)),
        "fault:non_finite",
    ),
    "inf_matrix": (
        raw_message("TRANSFORM", "T", _transform_body([*_EYE[:9], float("inf"), 0, 0])),
        "fault:non_finite",
    ),
    "string_length_too_long": (
        raw_message("STRING", "IcenavCommand", string_body("stop", length=999)),
        "fault:malformed",
    ),
    "string_unknown_encoding": (
        raw_message("STRING", "IcenavCommand", string_body("stop", encoding=999)),
        "fault:malformed",
    ),
    "string_bad_utf8": (
        raw_message("STRING", "IcenavCommand", struct.pack(">HH", 106, 2) + b"\xff\xfe"),
        "fault:malformed",
    ),
    "v2_extended_sizes_beyond_body": (_v2_string("stop", bad_sizes=True), "fault:malformed"),
    "empty_device": (raw_message("STRING", "", string_body("stop")), "fault:bad_device"),
    "image_as_command": (raw_message("IMAGE", "IcenavCommand", b"\0" * 80), "fault:unknown_type"),
}


@pytest.mark.parametrize("name", sorted(MALFORMED))
def test_every_malformed_message_class_leaves_the_server_up(bridge: IgtlBridge, name: str) -> None:
    data, expect = MALFORMED[name]
    what, _, kind = expect.partition(":")
    with connected_client(bridge) as client:
        peer = raw_connection(bridge.port)
        try:
            assert bridge.server.wait_for_clients(2, TIMEOUT_S)
            peer.sendall(data)
            if name == "truncated_stream":
                peer.shutdown(socket.SHUT_WR)
            if what == "closed":
                stats = _wait_stats(bridge, lambda s: s.clients == 1)
                if kind != "*":
                    assert stats.closed == {kind: 1}
                    assert stats.faults == {kind: 1}
            else:
                stats = _wait_stats(bridge, lambda s: s.faults.get(kind, 0) == 1)
                # the connection survives a bad message: the next command is answered
                peer.sendall(command_message("stop"))
                reader = RawReader(peer)
                ack = reader.next(DEVICE_COMMAND_ACK)
                if "IcenavCommand" in repr(data[:60]):  # the bad command got its own reply
                    assert ack.string.startswith("refused: <unreadable>"), ack.string
                    ack = reader.next(DEVICE_COMMAND_ACK)
                assert ack.string == "refused: stop: command stop is not enabled"
                assert bridge.stats().clients == 2
        finally:
            peer.close()
        bridge.send_status(f"after {name}")
        client.wait_for(DEVICE_STATUS, lambda m: m.string == f"after {name}")
    assert any(e.kind in (kind, "closed") for e in bridge.server.events)


def test_random_bytes_never_take_the_server_down(bridge: IgtlBridge) -> None:
    rng = np.random.default_rng(7)
    valid = command_message("stop")
    with connected_client(bridge) as client:
        for k in range(100):
            blob = bytearray(valid * 2)
            for _ in range(int(rng.integers(1, 8))):  # flip, cut or splice
                i = int(rng.integers(0, len(blob)))
                blob[i] = int(rng.integers(0, 256))
            if k % 3 == 0:
                blob = blob[: int(rng.integers(1, len(blob)))]
            with raw_connection(bridge.port) as peer:
                peer.sendall(bytes(blob))
        # (connections that arrive faster than the server reads their end may meet the cap)
        _wait_stats(bridge, lambda s: s.accepted + s.refused == 101 and s.clients == 1)
        bridge.send_status("alive")
        client.wait_for(DEVICE_STATUS, lambda m: m.string == "alive")


def test_a_new_client_gets_the_latest_frame_of_each_device_at_once(bridge: IgtlBridge) -> None:
    bridge.send_status("ready")
    pose = np.eye(4)
    pose[:3, 3] = (1.0, 2.0, 3.0)
    bridge.send_pose(DEVICE_TIP_TO_BASE, pose)
    with connected_client(bridge) as client:
        msg: Any = client.wait_for(DEVICE_TIP_TO_BASE)
        np.testing.assert_allclose(msg.matrix, pose, atol=1e-6)
        client.wait_for(DEVICE_STATUS, lambda m: m.string == "ready")


def test_a_bug_met_serving_one_peer_closes_that_peer_only(
    bridge: IgtlBridge, monkeypatch: pytest.MonkeyPatch
) -> None:
    import icenav.io.igtl_server as server_module

    def broken(header: Any, body: bytes) -> Any:
        raise RuntimeError("a decoder bug")

    with connected_client(bridge) as client:
        monkeypatch.setattr(server_module, "decode_body", broken)
        with raw_connection(bridge.port) as peer:
            peer.sendall(command_message("stop"))
            stats = _wait_stats(bridge, lambda s: s.closed.get("internal", 0) == 1)
        assert stats.faults["internal"] == 1
        bridge.send_status("still serving")
        client.wait_for(DEVICE_STATUS, lambda m: m.string == "still serving")


def test_a_client_leaving_mid_image_is_a_counted_event_not_a_traceback(
    bridge: IgtlBridge, caplog: pytest.LogCaptureFixture, capfd: pytest.CaptureFixture[str]
) -> None:
    image = np.random.default_rng(1).integers(0, 256, (480, 640), dtype=np.uint8)
    with connected_client(bridge):
        leaver = raw_connection(bridge.port)
        leaver.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        _wait_stats(bridge, lambda s: s.accepted >= 2)
        for k in range(20):  # more than the socket buffers hold: the server is mid-send
            bridge.send_image(DEVICE_IMAGE, image, np.eye(4), timestamp=float(k))
        leaver.close()  # SO_LINGER 0: a reset, as a crashed client gives
        stats = _wait_stats(bridge, lambda s: s.clients == 1)
    assert sum(stats.closed.values()) == 1
    assert set(stats.closed) <= {"reset", "peer_closed"}
    assert not [r for r in caplog.records if r.exc_info or r.levelname == "ERROR"]
    assert "Traceback" not in capfd.readouterr().err  # pyigtl's server printed one here


def test_the_close_of_a_peer_that_sent_commands_is_reported_after_its_commands() -> None:
    """``on_disconnect(peer)`` comes once per commanding connection, after its last command
    was handled; a peer that only listened (3D Slicer streaming) is not reported."""
    seen: list[tuple[str, str]] = []
    gone = threading.Event()

    def on_command(request: Any) -> Any:
        seen.append(("command", request.peer))
        return IgtlReply(IgtlOutcome.ACCEPTED)

    def on_disconnect(peer: str) -> None:
        seen.append(("gone", peer))
        gone.set()

    config = IgtlConfig(port=0, limits=LIMITS, accepted_commands=frozenset(IgtlCommand))
    with IgtlBridge(config, on_command=on_command, on_disconnect=on_disconnect) as b:
        listener = raw_connection(b.port)
        commander = raw_connection(b.port)
        _wait_stats(b, lambda s: s.clients == 2)
        commander.sendall(command_message("stop") + command_message("stop"))
        read_until(commander, DEVICE_COMMAND_ACK)
        peer = f"127.0.0.1:{commander.getsockname()[1]}"
        commander.close()
        assert gone.wait(TIMEOUT_S)
        listener.close()
        _wait_stats(b, lambda s: s.clients == 0)
    assert seen == [("command", peer), ("command", peer), ("gone", peer)]
