"""The OpenIGTLink bridge to 3D Slicer: what icenav streams, and the commands it takes.

It streams, on one TCP port (18944 by default, bound to 127.0.0.1 unless told otherwise),
to every connected client at once (:class:`~icenav.io.igtl_server.IgtlServer`):

* ``TipToBase`` (TRANSFORM): the model's tip pose ``tip2base`` (mm);
* ``SensorToTracker`` (TRANSFORM): the tracked EM sensor pose;
* ``Image`` (IMAGE): the live ICE image, uint8 (H, W), with its ``ijk2base`` matrix so that
  Slicer shows it in place (i = column, j = row, k = the image normal; mm per pixel in the
  columns of the matrix);
* ``IcenavStatus`` (STRING): a status text, or a JSON object.

Each message is packed once (pyigtl) and queued to every client; a client that reads
slowly gets the newest frame of each device and skips older ones.

Commands (STRING messages on ``IcenavCommand``, one command per line: ``stop``,
``save_view <name>``, ``go_to_view <name>``, ``refine_view <name>``) are read only when
enabled in :class:`IgtlConfig`. Every command gets exactly one reply on ``IcenavCommandAck``,
``<outcome>: <command>[: <reason>]`` with the outcome ``accepted``, ``refused``, ``done``
or ``failed``, from the ``on_command`` callback (which decides: the controller's answer)
or from the bridge (not enabled, unknown, wrong token, unreadable message). Several lines
in one message get one reply each, in order. Commands refused by the bridge become
counters and a bounded ring (:attr:`IgtlBridge.command_log`), never a growing list.
"""

from __future__ import annotations

import collections
import enum
import hmac
import json
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyigtl
from numpy.typing import ArrayLike, NDArray

from icenav._validation import check_finite, check_transform
from icenav.errors import IgtlError, InvalidValueError, ShapeError
from icenav.io.igtl_server import IgtlServer, Incoming, ServerLimits, ServerStats

__all__ = [
    "CommandRecord",
    "DEFAULT_PORT",
    "DEVICE_COMMAND",
    "DEVICE_COMMAND_ACK",
    "DEVICE_IMAGE",
    "DEVICE_SENSOR_TO_TRACKER",
    "DEVICE_STATUS",
    "DEVICE_TIP_TO_BASE",
    "IgtlBridge",
    "IgtlCommand",
    "IgtlConfig",
    "IgtlError",
    "IgtlOutcome",
    "IgtlReply",
    "IgtlRequest",
    "MAX_DEVICE_NAME_LENGTH",
    "ServerLimits",
    "check_device_name",
    "parse_command",
    "wait_for_client",
]

logger = logging.getLogger(__name__)

DEFAULT_PORT = 18944
"""The OpenIGTLink port 3D Slicer connects to by default."""
MAX_DEVICE_NAME_LENGTH = 20
"""OpenIGTLink's device name field is 20 bytes."""

# The one place where icenav's frame names meet OpenIGTLink device names (PLUS naming).
DEVICE_TIP_TO_BASE = "TipToBase"
DEVICE_SENSOR_TO_TRACKER = "SensorToTracker"
DEVICE_IMAGE = "Image"
DEVICE_STATUS = "IcenavStatus"
DEVICE_COMMAND = "IcenavCommand"
DEVICE_COMMAND_ACK = "IcenavCommandAck"

_ECHO_CHARS = 100  # a reply repeats at most this much of the command
_TOKEN_GUESSES = 5  # wrong tokens per host ...
_TOKEN_WINDOW_S = 60.0  # ... within this window before the host is refused unchecked
_TOKEN_HOSTS = 1024  # hosts remembered for the guess limit (oldest forgotten)


class IgtlCommand(enum.Enum):
    """Commands a client (3D Slicer) may send, when enabled."""

    STOP = "stop"
    """Stop the current motion."""
    SAVE_VIEW = "save_view"
    """Save the current view under a name."""
    GO_TO_VIEW = "go_to_view"
    """Go to a saved view by name."""
    REFINE_VIEW = "refine_view"
    """Refine the view returned to (the EM pose stage towards its saved tracked pose)."""


class IgtlOutcome(enum.Enum):
    """The outcome a reply reports (the names of the controller's command outcomes)."""

    ACCEPTED = "accepted"
    """Taken: the controller will act on it (or has started)."""
    REFUSED = "refused"
    """Not taken, and why (not enabled, not in control, in ESTOP, unknown view, ...)."""
    DONE = "done"
    """Taken and finished."""
    FAILED = "failed"
    """Taken, and it failed (why in the reason)."""


@dataclass(frozen=True)
class IgtlReply:
    """What ``on_command`` answers for one command."""

    outcome: IgtlOutcome
    """Accepted, refused, done or failed."""
    reason: str = ""
    """Why (required for refused and failed)."""


@dataclass(frozen=True)
class IgtlRequest:
    """One command that passed the bridge's checks, for ``on_command``."""

    command: IgtlCommand
    """What to do."""
    argument: str
    """The view name for SAVE_VIEW / GO_TO_VIEW / REFINE_VIEW ("" for STOP)."""
    timestamp: float
    """Time stamp of the OpenIGTLink message (s since 1970)."""
    peer: str = ""
    """``host:port`` of the client that sent it (the command's source)."""


@dataclass(frozen=True)
class CommandRecord:
    """One entry of the bridge's command log (a bounded ring)."""

    t: float
    """Wall-clock time (s since 1970)."""
    peer: str
    """``host:port`` of the client."""
    command: str
    """The command as received (at most 100 characters; a token is never kept)."""
    outcome: IgtlOutcome
    """The outcome replied."""
    reason: str
    """Why, for refused / failed."""


@dataclass(frozen=True)
class IgtlConfig:
    """Settings of the OpenIGTLink bridge."""

    port: int = DEFAULT_PORT
    """TCP port; 0 lets the operating system choose a free one (see IgtlBridge.port)."""
    local_only: bool = True
    """Bind to 127.0.0.1 (True) or to ``bind_address`` (False)."""
    bind_address: str = "0.0.0.0"
    """Address the server binds to when not local_only ("0.0.0.0": every interface)."""
    accepted_commands: frozenset[IgtlCommand] = frozenset()
    """Commands accepted from clients; the empty default accepts none."""
    token: str = ""
    """When set, a command is accepted only as ``<token> <command> [argument]`` (required
    when the bridge is exposed beyond loopback)."""
    limits: ServerLimits = field(default_factory=ServerLimits)
    """What one client may cost the server (connections, sizes, timeouts, backlogs)."""

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise InvalidValueError(f"port must be in [0, 65535], got {self.port}")
        if not self.local_only and self.accepted_commands and len(self.token) < 16:
            raise InvalidValueError(
                "commands on an exposed OpenIGTLink bridge need a token of >= 16 characters"
            )
        if any(c.isspace() for c in self.token):
            raise InvalidValueError("the OpenIGTLink command token must not contain spaces")


def check_device_name(name: str) -> str:
    """Return ``name`` if it is a valid OpenIGTLink device name (1-20 ASCII characters)."""
    if not isinstance(name, str) or not name:
        raise InvalidValueError(f"device name must be a non-empty string, got {name!r}")
    if not name.isascii() or not name.isprintable():
        raise InvalidValueError(f"device name must be printable ASCII, got {name!r}")
    if len(name) > MAX_DEVICE_NAME_LENGTH:
        raise InvalidValueError(
            f"device name {name!r} has {len(name)} characters; OpenIGTLink allows at most "
            f"{MAX_DEVICE_NAME_LENGTH} (pyigtl would cut it silently)"
        )
    return name


def _check_affine(m: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = check_finite(m, name)
    if arr.shape != (4, 4):
        raise ShapeError(f"{name} must have shape (4, 4), got {arr.shape}")
    if not np.allclose(arr[3], [0.0, 0.0, 0.0, 1.0]):
        raise InvalidValueError(f"{name} must have the last row (0, 0, 0, 1), got {arr[3]}")
    if abs(np.linalg.det(arr[:3, :3])) < 1e-12:
        raise InvalidValueError(f"{name} is singular (zero pixel spacing?)")
    return arr


def parse_command(
    line: str, config: IgtlConfig, timestamp: float = 0.0, peer: str = ""
) -> IgtlRequest | IgtlReply:
    """One command line (token already removed) as a request, or the refusal and why."""
    word, _, argument = line.strip().partition(" ")
    try:
        command = IgtlCommand(word.lower())
    except ValueError:
        return IgtlReply(IgtlOutcome.REFUSED, f"unknown command {word[:40]!r}")
    if command not in config.accepted_commands:
        return IgtlReply(IgtlOutcome.REFUSED, f"command {command.value} is not enabled")
    argument = argument.strip()
    if command is not IgtlCommand.STOP and not argument:
        return IgtlReply(IgtlOutcome.REFUSED, f"command {command.value} needs a view name")
    return IgtlRequest(command, argument, timestamp, peer)


def _pack_ack(text: str) -> bytes:
    return bytes(pyigtl.StringMessage(text, device_name=DEVICE_COMMAND_ACK).pack())


class IgtlBridge:
    """An OpenIGTLink server that streams poses, images and status to 3D Slicer.

    May be created on any thread; sending (``send_*``) is thread-safe and never waits for a
    socket (the server's I/O thread sends).

    Parameters
    ----------
    config : IgtlConfig
        Port, binding, accepted commands and limits.
    on_command : callable, optional
        ``on_command(request) -> IgtlReply``, called on the server's command thread for each
        enabled command; its reply is sent to the client. Without it, enabled commands are
        refused ("no controller").
    on_disconnect : callable, optional
        ``on_disconnect(peer)`` when a client that sent commands is gone (on the command
        thread, after its commands): the controller stops what that client started.

    Raises
    ------
    IgtlError
        The port cannot be bound (the message names it).
    """

    def __init__(
        self,
        config: IgtlConfig | None = None,
        on_command: Callable[[IgtlRequest], IgtlReply] | None = None,
        on_disconnect: Callable[[str], None] | None = None,
    ):
        self.config = config or IgtlConfig()
        self._on_command = on_command
        self.command_counts: collections.Counter[str] = collections.Counter()
        """Replies sent, by outcome value ("accepted", "refused", ...)."""
        self.command_log: collections.deque[CommandRecord] = collections.deque(maxlen=128)
        """The last 128 commands and their outcomes (a bounded ring)."""
        self._guesses: collections.OrderedDict[str, collections.deque[float]] = (
            collections.OrderedDict()
        )
        self._closed = False
        host = "127.0.0.1" if self.config.local_only else self.config.bind_address
        self.server = IgtlServer(
            host=host,
            port=self.config.port,
            limits=self.config.limits,
            command_device=DEVICE_COMMAND,
            on_command=self._handle,
            on_close=on_disconnect,
        )

    # ------------------------------------------------------------------ properties
    @property
    def port(self) -> int:
        """The TCP port the server listens on (the chosen one when config.port is 0)."""
        return int(self.server.port)

    @property
    def host(self) -> str:
        """The address the server is bound to."""
        return str(self.server.host)

    @property
    def connected(self) -> bool:
        """Whether at least one client is connected."""
        return self.server.n_clients > 0

    def stats(self) -> ServerStats:
        """The server's counters (connections, faults, bytes, buffered bytes)."""
        return self.server.stats()

    # ------------------------------------------------------------------ sending
    def send_pose(self, name: str, a2b: ArrayLike, timestamp: float | None = None) -> None:
        """Send a rigid transform (4, 4), mm, e.g. ``send_pose("TipToBase", tip2base)``."""
        check_device_name(name)
        matrix = check_transform(a2b, name, tol=1e-5)
        if matrix.shape != (4, 4):
            raise ShapeError(f"{name} must have shape (4, 4), got {matrix.shape}")
        self._send(name, pyigtl.TransformMessage(matrix, timestamp=timestamp, device_name=name))

    def send_image(
        self,
        name: str,
        image: ArrayLike,
        ijk2base: ArrayLike,
        timestamp: float | None = None,
    ) -> None:
        """Send a 2D uint8 image placed in 3D by ``ijk2base``.

        Parameters
        ----------
        image : array-like, shape (H, W), uint8
            The image; row j, column i.
        ijk2base : array-like, shape (4, 4)
            Maps a pixel index (i = column, j = row, k = 0, 1) to the base frame (mm); its
            columns are the column step, the row step (mm per pixel) and the image normal.
        """
        check_device_name(name)
        img = np.asarray(image)
        if img.ndim != 2:
            raise ShapeError(f"image must have shape (H, W), got {img.shape}")
        if img.dtype != np.uint8:
            raise InvalidValueError(f"image must be uint8, got {img.dtype}")
        matrix = _check_affine(ijk2base, "ijk2base")
        # pyigtl's voxel axes are (k, j, i): one slice of H rows and W columns.
        voxels = np.ascontiguousarray(img[np.newaxis, :, :])
        message = pyigtl.ImageMessage(
            voxels,
            ijk_to_world_matrix=matrix,
            world_coordinate_system="ras",
            timestamp=timestamp,
            device_name=name,
        )
        self._send(name, message)

    def send_status(self, status: str | Mapping[str, Any], timestamp: float | None = None) -> None:
        """Send a status text, or a mapping as a JSON object, on ``IcenavStatus``."""
        text = status if isinstance(status, str) else json.dumps(dict(status), sort_keys=True)
        self._send(
            DEVICE_STATUS,
            pyigtl.StringMessage(text, timestamp=timestamp, device_name=DEVICE_STATUS),
        )

    def _send(self, device: str, message: Any) -> None:
        if self._closed:
            raise IgtlError("the OpenIGTLink bridge is closed")
        self.server.broadcast(device, bytes(message.pack()))  # packed once, on this thread

    # ------------------------------------------------------------------ commands
    def _handle(self, incoming: Incoming) -> Sequence[bytes]:
        """The server's command handler: one reply per command line."""
        if incoming.error is not None or incoming.text is None:
            why = str(incoming.error) if incoming.error is not None else "no text"
            return [self._reply(incoming.peer, "<unreadable>", IgtlReply(IgtlOutcome.REFUSED, why))]
        lines = [ln for ln in incoming.text.splitlines() if ln.strip()]
        if not lines:
            return [self._reply(incoming.peer, "", IgtlReply(IgtlOutcome.REFUSED, "empty command"))]
        cap = self.config.limits.max_commands_per_message
        replies = [self.handle_line(ln, incoming.timestamp_s, incoming.peer) for ln in lines[:cap]]
        if len(lines) > cap:
            more = IgtlReply(
                IgtlOutcome.REFUSED,
                f"{len(lines) - cap} more commands in one message (at most {cap} are read)",
            )
            replies.append(self._reply(incoming.peer, "...", more))
        return replies

    def handle_line(self, line: str, timestamp: float, peer: str) -> bytes:
        """Check, authenticate and run one command line; its packed reply."""
        text = line.strip()
        if self.config.token:  # the token is never echoed or logged
            given, _, text = text.partition(" ")
            text = text.strip()
            host = peer.rsplit(":", 1)[0]
            if self._too_many_guesses(host):
                why = f"too many wrong tokens from {host}; wait {_TOKEN_WINDOW_S:g} s"
                return self._reply(peer, "<redacted>", IgtlReply(IgtlOutcome.REFUSED, why))
            if not hmac.compare_digest(given.encode(), self.config.token.encode()):
                self._note_guess(host)
                why = "missing or wrong token"
                return self._reply(peer, "<redacted>", IgtlReply(IgtlOutcome.REFUSED, why))
        parsed = parse_command(text, self.config, timestamp, peer)
        if isinstance(parsed, IgtlReply):
            return self._reply(peer, text, parsed)
        if self._on_command is None:
            reply = IgtlReply(IgtlOutcome.REFUSED, "no controller is attached")
        else:
            try:
                reply = self._on_command(parsed)
            except Exception as exc:  # noqa: BLE001 - reported to the client, not raised
                logger.exception("OpenIGTLink command %r failed", text)
                reply = IgtlReply(IgtlOutcome.FAILED, f"{type(exc).__name__}: {exc}")
            if not isinstance(reply, IgtlReply):
                reply = IgtlReply(IgtlOutcome.FAILED, "the command handler gave no outcome")
        return self._reply(peer, text, reply)

    def _too_many_guesses(self, host: str) -> bool:
        times = self._guesses.get(host)
        if times is None or len(times) < _TOKEN_GUESSES:
            return False
        return time.monotonic() - times[0] < _TOKEN_WINDOW_S

    def _note_guess(self, host: str) -> None:
        times = self._guesses.setdefault(host, collections.deque(maxlen=_TOKEN_GUESSES))
        self._guesses.move_to_end(host)
        times.append(time.monotonic())
        if len(times) == _TOKEN_GUESSES and times[-1] - times[0] < _TOKEN_WINDOW_S:
            logger.warning(
                "OpenIGTLink: %d wrong command tokens from %s within %g s; its commands are "
                "refused unchecked until the window passes",
                _TOKEN_GUESSES,
                host,
                _TOKEN_WINDOW_S,
            )
        while len(self._guesses) > _TOKEN_HOSTS:
            self._guesses.popitem(last=False)

    def _reply(self, peer: str, command: str, reply: IgtlReply) -> bytes:
        echo = command[:_ECHO_CHARS]
        self.command_counts[reply.outcome.value] += 1
        self.command_log.append(CommandRecord(time.time(), peer, echo, reply.outcome, reply.reason))
        if reply.outcome is not IgtlOutcome.ACCEPTED and reply.outcome is not IgtlOutcome.DONE:
            logger.debug(
                "OpenIGTLink command %r from %s %s: %s",
                echo,
                peer,
                reply.outcome.value,
                reply.reason,
            )
        text = f"{reply.outcome.value}: {echo}" + (f": {reply.reason}" if reply.reason else "")
        return _pack_ack(text)

    # ------------------------------------------------------------------ life cycle
    def close(self) -> None:
        """Close every connection and stop the server."""
        if self._closed:
            return
        self._closed = True
        self.server.close()

    def __enter__(self) -> IgtlBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def wait_for_client(bridge: IgtlBridge, timeout: float, n: int = 1) -> bool:
    """Wait up to ``timeout`` seconds (on a condition) for ``n`` clients; True if they came."""
    return bridge.server.wait_for_clients(n, timeout)
