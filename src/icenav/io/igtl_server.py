"""An OpenIGTLink TCP server that keeps serving good clients whatever other peers do.

The socket layer is ours (standard library ``selectors``, one I/O thread, non-blocking
sockets); message contents are packed and unpacked by pyigtl (:mod:`icenav.io.igtl_wire`
checks a peer's bytes before pyigtl reads them). pyigtl's own server serves one client at
a time with blocking reads, so one idle connection stopped the stream to every other one.

What a peer can make the server keep, and the bound on each (per client):

* bytes of the message being received: at most ``max_body_bytes`` + the header, plus one
  ``recv_chunk_bytes`` read; a message must be complete within ``read_timeout_s`` of its
  first byte (a peer sending one byte every few seconds is closed then);
* outgoing stream frames: per device, the frames not yet sent while they are at most
  ``max_frames_per_device`` and ``max_device_backlog_bytes`` (poses: 32 frames, 0.64 s at
  50 Hz; 480 x 640 images: 3 frames, 0.2 s at 15 Hz); a client further behind skips the
  oldest frames and always gets the newest (counted in ``frames_dropped``; the frame
  bytes are shared by every client, packed once);
* commands waiting for the command thread: ``max_pending_commands``, and replies not yet
  sent: ``max_queued_replies``. Beyond either, the server stops *reading* from that peer
  (TCP pushes back on it), so a flood costs it, not the server;
* counters, and a ring of the last ``event_ring`` events (connections refused, peers
  closed, malformed messages): a flood becomes numbers, not a growing list or a log line
  per message (the first event of each kind per peer is logged, the rest counted).

Connections beyond ``max_clients`` are told so in a STRING on ``IcenavStatus`` and closed at
once. Pending output that makes no progress for ``send_stall_timeout_s`` (a peer that
stopped reading) closes the connection; an idle peer that reads is served forever (3D
Slicer sends nothing). A disconnect is a counted event, never a traceback.

A peer that sent commands is reported to ``on_close(peer)`` when its connection ends, on
the command thread after its last command was handled (so the controller can stop the
motion that peer started: a client that is gone holds no control).
"""

from __future__ import annotations

import collections
import contextlib
import errno
import logging
import queue
import selectors
import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import pyigtl

from icenav.errors import IgtlError, IgtlProtocolError, InvalidValueError
from icenav.io.igtl_wire import HEADER_SIZE, Header, decode_body, parse_header

__all__ = ["IgtlServer", "Incoming", "ServerEvent", "ServerLimits", "ServerStats"]

logger = logging.getLogger(__name__)

_LISTENER = "listener"
_WAKE = "wake"


@dataclass(frozen=True)
class ServerLimits:
    """What one peer may cost the server."""

    max_clients: int = 16
    """Connections served at once; more are refused (told, then closed)."""
    max_body_bytes: int = 128 * 1024
    """Largest incoming body (bytes); a header announcing more closes the connection."""
    read_timeout_s: float = 5.0
    """A message must arrive in full within this time of its first byte (s)."""
    send_stall_timeout_s: float = 30.0
    """Output pending without any byte sent for this long closes the connection (s)."""
    max_pending_commands: int = 4
    """Command messages of one peer waiting for the command thread; reading pauses beyond."""
    max_queued_replies: int = 64
    """Replies to one peer not yet sent; reading pauses beyond."""
    max_frames_per_device: int = 32
    """Unsent stream frames kept per client and device (the newest always)."""
    max_device_backlog_bytes: int = 1024 * 1024
    """... while they hold at most this many bytes (bytes; one larger frame is kept alone):
    3 frames of a 480 x 640 image, 0.2 s at 15 Hz."""
    max_commands_per_message: int = 16
    """Commands (lines) read from one STRING; the rest are refused in one reply."""
    recv_chunk_bytes: int = 64 * 1024
    """Bytes read per ``recv`` (bytes)."""
    max_in_bytes_per_s: float = 2_000_000.0
    """Bytes per second read from one peer (a token bucket of one second); a flood beyond
    waits in the peer's socket, so it cannot take the I/O thread's (and the GIL's) time."""
    event_ring: int = 256
    """Events kept in :attr:`IgtlServer.events`."""

    def __post_init__(self) -> None:
        for name in ("max_clients", "max_body_bytes", "max_pending_commands", "recv_chunk_bytes"):
            if getattr(self, name) < 1:
                raise InvalidValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("read_timeout_s", "send_stall_timeout_s"):
            if not getattr(self, name) > 0:
                raise InvalidValueError(f"{name} must be > 0 s, got {getattr(self, name)} s")


@dataclass(frozen=True)
class ServerEvent:
    """One entry of the server's event ring."""

    t: float
    """Wall-clock time (s since 1970)."""
    peer: str
    """``host:port`` of the peer."""
    kind: str
    """"refused" (connection cap), "closed" (and why in detail), or a protocol fault kind
    ("bad_crc", "unknown_type", "malformed", "non_finite", "bad_device", ...)."""
    detail: str
    """What happened (at most 200 characters)."""


@dataclass(frozen=True)
class Incoming:
    """A message for the command device, as the command handler receives it."""

    client_id: int
    """Connection number (unique for the server's life)."""
    peer: str
    """``host:port`` of the peer."""
    text: str | None
    """The STRING's text; None when the message failed its checks (see ``error``)."""
    error: IgtlProtocolError | None
    """Why the message could not be read (bad CRC, not a STRING, ...), or None."""
    timestamp_s: float
    """Time stamp of the message (s since 1970)."""


@dataclass(frozen=True)
class ServerStats:
    """Counters since the server started."""

    clients: int
    """Connections open now."""
    accepted: int
    """Connections accepted."""
    refused: int
    """Connections refused at the cap."""
    closed: dict[str, int]
    """Connections closed, by reason ("peer_closed", "read_timeout", "oversize", ...)."""
    faults: dict[str, int]
    """Incoming messages refused, by kind ("bad_crc", "unknown_type", ...; "ignored": valid
    messages to a device other than the command device)."""
    messages_in: int
    """Complete messages received."""
    bytes_in: int
    """Bytes received (bytes)."""
    bytes_out: int
    """Bytes sent (bytes)."""
    frames_dropped: int
    """Stream frames dropped (the oldest of a device) for clients too far behind."""
    buffered_bytes: int
    """Bytes held for clients now (receive buffers, frames, replies, commands)."""
    peak_buffered_bytes: int
    """The largest ``buffered_bytes`` seen (bytes)."""


@dataclass(eq=False)
class _Client:
    id: int
    sock: socket.socket
    peer: str
    rbuf: bytearray = field(default_factory=bytearray)
    header: Header | None = None
    msg_started: float | None = None
    frames: dict[str, collections.deque[bytes]] = field(default_factory=dict)
    replies: collections.deque[bytes] = field(default_factory=collections.deque)
    inflight: memoryview | None = None
    last_progress: float = 0.0
    pending: int = 0
    pending_bytes: int = 0
    tokens: float = 0.0
    refilled: float = 0.0
    mask: int = 0
    logged: set[str] = field(default_factory=set)
    commanded: bool = False

    def has_output(self) -> bool:
        return self.inflight is not None or bool(self.replies) or bool(self.frames)


@dataclass(frozen=True)
class _Gone:
    """A peer that sent commands has gone (queued behind its commands)."""

    peer: str


def _status_bytes(text: str) -> bytes:
    return bytes(pyigtl.StringMessage(text, device_name="IcenavStatus").pack())


class IgtlServer:
    """Serve OpenIGTLink on ``host:port`` from one I/O thread (started at once).

    Parameters
    ----------
    host : str
        Address to bind ("127.0.0.1" for this machine only).
    port : int
        TCP port; 0 lets the operating system choose (see :attr:`port`).
    limits : ServerLimits
        What one peer may cost.
    command_device : str
        Device name whose STRING messages are commands.
    on_command : callable, optional
        ``on_command(incoming) -> replies`` (packed messages) runs on the server's command
        thread for each message to ``command_device``; the replies go to that client only.
    on_close : callable, optional
        ``on_close(peer)`` runs on the command thread when a peer that sent at least one
        command message is gone (after the replies to its commands were decided).

    Raises
    ------
    IgtlError
        The address cannot be bound (the error names the port).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        limits: ServerLimits | None = None,
        command_device: str = "IcenavCommand",
        on_command: Callable[[Incoming], Sequence[bytes]] | None = None,
        on_close: Callable[[str], None] | None = None,
    ) -> None:
        self.limits = limits or ServerLimits()
        self.command_device = command_device
        self._on_command = on_command
        self._on_close = on_close
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        # a restart may bind while old connections linger in TIME_WAIT; on Linux this
        # never lets two servers listen on one port (a port in use stays an error)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._listener.bind((host, port))
            self._listener.listen(min(socket.SOMAXCONN, 512))
        except OSError as exc:
            self._listener.close()
            raise IgtlError(
                f"cannot open the OpenIGTLink server on {host} port {port}: {exc.strerror or exc}"
                + (
                    " (the port is in use; choose another, or 0 for a free one)"
                    if getattr(exc, "errno", None) == errno.EADDRINUSE
                    else ""
                )
            ) from exc
        self._listener.setblocking(False)
        self.host, self.port = self._listener.getsockname()[:2]
        self._lock = threading.RLock()
        self._changed = threading.Condition(self._lock)
        self._clients: dict[int, _Client] = {}
        self._latest: dict[str, bytes] = {}
        self._next_id = 1
        self._closing = False
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._sel = selectors.DefaultSelector()
        self._sel.register(self._listener, selectors.EVENT_READ, _LISTENER)
        self._sel.register(self._wake_r, selectors.EVENT_READ, _WAKE)
        self._events: collections.deque[ServerEvent] = collections.deque(
            maxlen=self.limits.event_ring
        )
        self._accepted = self._refused = self._messages_in = 0
        self._bytes_in = self._bytes_out = self._dropped = 0
        self._buffered = self._peak_buffered = 0
        self._closed_by: collections.Counter[str] = collections.Counter()
        self._faults: collections.Counter[str] = collections.Counter()
        self._full_message = _status_bytes(
            f"refused: this icenav serves at most {self.limits.max_clients} OpenIGTLink clients"
        )
        self._commands: queue.SimpleQueue[tuple[Incoming | _Gone, int] | None] = queue.SimpleQueue()
        self._io = threading.Thread(target=self._run, name="icenav-igtl-io", daemon=True)
        self._worker = threading.Thread(target=self._work, name="icenav-igtl-cmd", daemon=True)
        self._io.start()
        self._worker.start()

    # ------------------------------------------------------------------ public
    @property
    def n_clients(self) -> int:
        """Connections open now."""
        return len(self._clients)

    def broadcast(self, device: str, data: bytes) -> None:
        """Queue a packed stream frame of ``device`` to every client; an unsent older frame
        of the same device is replaced (latest wins). Never blocks on a socket."""
        with self._lock:
            if self._closing:
                raise IgtlError("the OpenIGTLink server is closed")
            self._latest[device] = data
            for c in self._clients.values():
                queue_ = c.frames.setdefault(device, collections.deque())
                queue_.append(data)
                self._dropped += self._trim(queue_)
        self._wake()

    def _trim(self, frames: collections.deque[bytes]) -> int:
        """Drop the oldest frames beyond the per-device backlog; how many were dropped."""
        lim = self.limits
        dropped = 0
        while len(frames) > 1 and (
            len(frames) > lim.max_frames_per_device
            or sum(len(f) for f in frames) > lim.max_device_backlog_bytes
        ):
            frames.popleft()
            dropped += 1
        return dropped

    def wait_for_clients(self, n: int, timeout: float) -> bool:
        """Wait (on a condition, no polling) until at least ``n`` clients are connected."""
        with self._changed:
            return self._changed.wait_for(lambda: len(self._clients) >= n, timeout=timeout)

    @property
    def events(self) -> tuple[ServerEvent, ...]:
        """The last ``limits.event_ring`` events (a bounded ring), oldest first."""
        with self._lock:
            return tuple(self._events)

    def wait_until(self, predicate: Callable[[ServerStats], bool], timeout: float) -> bool:
        """Wait (on a condition notified at every connection, close and fault) until
        ``predicate(stats)`` holds; False after ``timeout`` seconds."""
        with self._changed:
            return self._changed.wait_for(lambda: predicate(self.stats()), timeout=timeout)

    def stats(self) -> ServerStats:
        """A snapshot of the counters."""
        with self._lock:
            return ServerStats(
                clients=len(self._clients),
                accepted=self._accepted,
                refused=self._refused,
                closed=dict(self._closed_by),
                faults=dict(self._faults),
                messages_in=self._messages_in,
                bytes_in=self._bytes_in,
                bytes_out=self._bytes_out,
                frames_dropped=self._dropped,
                buffered_bytes=self._buffered,
                peak_buffered_bytes=self._peak_buffered,
            )

    def close(self) -> None:
        """Close every connection and stop the threads."""
        with self._lock:
            if self._closing:
                return
            self._closing = True
        self._wake()
        self._io.join(timeout=5.0)
        self._commands.put(None)
        self._worker.join(timeout=5.0)

    # ------------------------------------------------------------------ I/O thread
    def _wake(self) -> None:
        with contextlib.suppress(BlockingIOError, OSError):
            self._wake_w.send(b"\0")

    def _run(self) -> None:
        try:
            while not self._closing:
                for key, mask in self._sel.select(timeout=0.1):
                    now = time.monotonic()
                    if key.data is _LISTENER:
                        self._accept(now)
                    elif key.data is _WAKE:
                        with contextlib.suppress(BlockingIOError, OSError):
                            while self._wake_r.recv(4096):
                                pass
                    elif mask & selectors.EVENT_READ:
                        self._guarded(key.data, self._read, now)
                self._sweep(time.monotonic())
        finally:
            with self._lock:
                for c in list(self._clients.values()):
                    self._close_locked(c, "server_closed", "", log=False)
            self._sel.close()
            self._listener.close()
            self._wake_r.close()
            self._wake_w.close()

    def _guarded(self, c: _Client, step: Callable[[_Client, float], None], now: float) -> None:
        """Run one client's step; a bug it hits closes that client, never the server."""
        try:
            step(c, now)
        except Exception as exc:  # noqa: BLE001 - one peer must not end the I/O thread
            logger.exception("OpenIGTLink: unexpected error serving %s", c.peer)
            with self._lock:
                self._faults["internal"] += 1
                self._close_locked(c, "internal", f"{type(exc).__name__}: {exc}")

    def _accept(self, now: float) -> None:
        for _ in range(64):
            try:
                sock, addr = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # out of descriptors: counted, retried on the next event
                self._fault_event("-", "accept_failed", str(exc))
                return
            peer = f"{addr[0]}:{addr[1]}"
            with self._lock:
                if len(self._clients) >= self.limits.max_clients:
                    self._refused += 1
                    self._event(peer, "refused", f"{len(self._clients)} clients (the cap)")
                    with contextlib.suppress(OSError):
                        sock.setblocking(False)
                        sock.send(self._full_message)
                    sock.close()
                    continue
                sock.setblocking(False)
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
                rate = self.limits.max_in_bytes_per_s
                c = _Client(self._next_id, sock, peer, last_progress=now, tokens=rate, refilled=now)
                # a new client gets the latest frame of each device at once
                c.frames = {d: collections.deque([f]) for d, f in self._latest.items()}
                self._next_id += 1
                self._accepted += 1
                self._clients[c.id] = c
                self._set_mask(c)
                self._changed.notify_all()
            logger.info("OpenIGTLink client %s connected", peer)

    def _read(self, c: _Client, now: float) -> None:
        with self._lock:
            if c.id not in self._clients:
                return
            try:
                data = c.sock.recv(self.limits.recv_chunk_bytes)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                self._close_locked(c, "reset", str(exc))
                return
            if not data:
                if c.rbuf:
                    self._close_locked(c, "closed_mid_message", f"{len(c.rbuf)} bytes unread")
                else:
                    self._close_locked(c, "peer_closed", "")
                return
            if not c.rbuf:
                c.msg_started = now
            c.rbuf += data
            c.tokens -= len(data)
            self._bytes_in += len(data)
            self._parse(c, now)

    def _paused(self, c: _Client) -> bool:
        return (
            c.pending >= self.limits.max_pending_commands
            or len(c.replies) >= self.limits.max_queued_replies
        )

    def _refill(self, c: _Client, now: float) -> None:
        rate = self.limits.max_in_bytes_per_s
        c.tokens = min(rate, c.tokens + (now - c.refilled) * rate)
        c.refilled = now

    def _parse(self, c: _Client, now: float) -> None:
        while not self._paused(c):
            if c.header is None:
                if len(c.rbuf) < HEADER_SIZE:
                    return
                try:
                    c.header = parse_header(bytes(c.rbuf[:HEADER_SIZE]), self.limits.max_body_bytes)
                except IgtlProtocolError as exc:
                    self._faults[exc.kind] += 1
                    self._close_locked(c, exc.kind, str(exc))
                    return
            end = HEADER_SIZE + c.header.body_size
            if len(c.rbuf) < end:
                return
            header, body = c.header, bytes(c.rbuf[HEADER_SIZE:end])
            del c.rbuf[:end]
            c.header = None
            c.msg_started = now if c.rbuf else None
            self._messages_in += 1
            self._on_message(c, header, body)

    def _on_message(self, c: _Client, header: Header, body: bytes) -> None:
        error: IgtlProtocolError | None = None
        text: str | None = None
        try:
            message = decode_body(header, body)
            text = getattr(message, "string", None)
        except IgtlProtocolError as exc:
            error = exc
        if header.device == self.command_device and error is None and text is None:
            error = IgtlProtocolError(
                f"commands are STRING messages, got {header.type}", kind="malformed"
            )
        if error is not None:
            self._faults[error.kind] += 1
            self._fault_event(c.peer, error.kind, str(error), c)
        if header.device != self.command_device:
            if error is None:
                self._faults["ignored"] += 1  # a valid message icenav does not read
            return
        c.pending += 1
        c.commanded = True
        c.pending_bytes += len(body)
        self._commands.put((Incoming(c.id, c.peer, text, error, header.timestamp_s), len(body)))

    def _sweep(self, now: float) -> None:
        """Send what can be sent, enforce the deadlines, resume paused readers."""
        with self._lock:
            buffered = 0
            seen: set[int] = set()
            for c in list(self._clients.values()):
                self._refill(c, now)
                self._guarded(c, self._flush, now)
                if c.id not in self._clients:
                    continue
                if self._paused(c) or c.tokens <= 0:
                    # the server is not reading: its own pause does not count against the
                    # peer's read deadline (a peer that never reads its replies is closed by
                    # the send-stall deadline instead)
                    c.msg_started = now if c.rbuf else None
                if c.msg_started is not None and now - c.msg_started > self.limits.read_timeout_s:
                    self._faults["read_timeout"] += 1
                    self._close_locked(
                        c,
                        "read_timeout",
                        f"a message incomplete after {self.limits.read_timeout_s:g} s "
                        f"({len(c.rbuf)} bytes)",
                    )
                    continue
                if c.has_output() and now - c.last_progress > self.limits.send_stall_timeout_s:
                    self._close_locked(
                        c,
                        "send_stalled",
                        f"no byte taken for {self.limits.send_stall_timeout_s:g} s",
                    )
                    continue
                if not self._paused(c) and len(c.rbuf) >= HEADER_SIZE:
                    self._guarded(c, self._parse, now)  # messages left in the buffer by a pause
                self._set_mask(c)
                buffered += len(c.rbuf) + c.pending_bytes + sum(len(r) for r in c.replies)
                if c.inflight is not None:
                    buffered += len(c.inflight)
                for frames in c.frames.values():
                    for f in frames:
                        if id(f) not in seen:
                            seen.add(id(f))
                            buffered += len(f)
            self._buffered = buffered
            self._peak_buffered = max(self._peak_buffered, buffered)

    def _flush(self, c: _Client, now: float) -> None:
        while True:
            if c.inflight is None:
                if c.replies:
                    c.inflight = memoryview(c.replies.popleft())
                elif c.frames:
                    device = next(iter(c.frames))  # the devices take turns
                    frames = c.frames.pop(device)
                    c.inflight = memoryview(frames.popleft())
                    if frames:
                        c.frames[device] = frames
                else:
                    return
            try:
                n = c.sock.send(c.inflight)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # BrokenPipe, reset: the peer left
                self._close_locked(c, "reset", str(exc))
                return
            self._bytes_out += n
            c.last_progress = now
            c.inflight = c.inflight[n:] if n < len(c.inflight) else None

    def _set_mask(self, c: _Client) -> None:
        mask = 0 if self._paused(c) or c.tokens <= 0 else selectors.EVENT_READ
        if c.has_output():
            mask |= selectors.EVENT_WRITE
        else:
            c.last_progress = time.monotonic()  # nothing owed: no stall
        if mask == c.mask:
            return
        if c.mask == 0:
            self._sel.register(c.sock, mask, c)
        elif mask == 0:
            self._sel.unregister(c.sock)
        else:
            self._sel.modify(c.sock, mask, c)
        c.mask = mask

    def _close_locked(self, c: _Client, reason: str, detail: str, log: bool = True) -> None:
        if self._clients.pop(c.id, None) is None:
            return
        if c.mask:
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._sel.unregister(c.sock)
            c.mask = 0
        with contextlib.suppress(OSError):
            c.sock.close()
        self._closed_by[reason] += 1
        if c.commanded:  # after its commands, on the command thread (never under this lock)
            self._commands.put((_Gone(c.peer), 0))
        self._event(c.peer, "closed", f"{reason}: {detail}" if detail else reason)
        self._changed.notify_all()
        if log:
            level = logging.INFO if reason in ("peer_closed", "reset") else logging.WARNING
            logger.log(level, "OpenIGTLink client %s closed: %s %s", c.peer, reason, detail)

    # ------------------------------------------------------------------ events
    def _event(self, peer: str, kind: str, detail: str) -> None:
        with self._changed:
            self._events.append(ServerEvent(time.time(), peer, kind, detail[:200]))
            self._changed.notify_all()

    def _fault_event(self, peer: str, kind: str, detail: str, c: _Client | None = None) -> None:
        self._event(peer, kind, detail)
        if c is None or kind not in c.logged:  # the first of each kind per peer is logged
            if c is not None:
                c.logged.add(kind)
            logger.warning("OpenIGTLink %s from %s: %s (further ones counted)", kind, peer, detail)

    # ------------------------------------------------------------------ command thread
    def _work(self) -> None:
        while True:
            got = self._commands.get()
            if got is None:
                return
            item, size = got
            if isinstance(item, _Gone):
                if self._on_close is not None:
                    try:
                        self._on_close(item.peer)
                    except Exception:  # noqa: BLE001 - the handler's bug must not end the server
                        logger.exception("OpenIGTLink close handler failed for %s", item.peer)
                continue
            replies: Sequence[bytes] = ()
            if self._on_command is not None:
                try:
                    replies = self._on_command(item)
                except Exception:  # noqa: BLE001 - the handler's bug must not end the server
                    logger.exception("OpenIGTLink command handler failed")
            with self._lock:
                c = self._clients.get(item.client_id)
                if c is not None:
                    c.pending -= 1
                    c.pending_bytes -= size
                    c.replies.extend(replies)
            self._wake()
