"""The OpenIGTLink bridge to 3D Slicer (pyigtl's server).

It streams, on one TCP port (18944 by default, bound to 127.0.0.1 unless told otherwise):

* ``TipToBase`` (TRANSFORM): the model's tip pose ``tip2base`` (mm);
* ``SensorToTracker`` (TRANSFORM): the tracked EM sensor pose;
* ``Image`` (IMAGE): the live ICE image, uint8 (H, W), with its ``ijk2base`` matrix so that
  Slicer shows it in place (i = column, j = row, k = the image normal; mm per pixel in the
  columns of the matrix);
* ``IcenavStatus`` (STRING): a status text, or a JSON object.

It accepts a small set of commands (STRING messages on the device ``IcenavCommand``:
``stop``, ``save_view <name>``, ``go_to_view <name>``) only when they are enabled in
:class:`IgtlConfig`; each accepted command goes to the ``on_command`` callback and is
acknowledged on ``IcenavCommandAck`` (``accepted: ...`` / ``rejected: ...``).

pyigtl's behaviour that shapes this design:

* its server installs SIGINT / SIGTERM handlers, and Python allows that only on the main
  thread: :class:`IgtlBridge` must be created on the main thread (it checks, and raises
  IgtlError otherwise); the bridge restores the previous handlers in :meth:`close`. Sending
  is thread-safe (a locked queue), so the controller thread may send;
* it cuts device names past 20 characters silently: names are checked here instead;
* both ends keep only the *latest* incoming message per device: a client that polls sees the
  newest pose, not every pose; two commands sent between two polls of the bridge keep only
  the second, so a client should wait for the acknowledgement before sending the next one;
* its outgoing queue keeps at most 100 messages: while no client is connected, older ones
  are dropped.
"""

from __future__ import annotations

import enum
import hmac
import json
import logging
import signal
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyigtl
from numpy.typing import ArrayLike, NDArray

from icenav._validation import check_finite, check_transform
from icenav.errors import IgtlError, InvalidValueError, ShapeError

__all__ = [
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
    "IgtlRequest",
    "MAX_DEVICE_NAME_LENGTH",
    "check_device_name",
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


class IgtlCommand(enum.Enum):
    """Commands a client (3D Slicer) may send, when enabled."""

    STOP = "stop"
    """Stop the current motion."""
    SAVE_VIEW = "save_view"
    """Save the current view under a name."""
    GO_TO_VIEW = "go_to_view"
    """Go to a saved view by name."""


@dataclass(frozen=True)
class IgtlRequest:
    """One accepted command."""

    command: IgtlCommand
    """What to do."""
    argument: str
    """The view name for SAVE_VIEW / GO_TO_VIEW ("" for STOP)."""
    timestamp: float
    """Time stamp of the OpenIGTLink message (s since 1970)."""


@dataclass(frozen=True)
class IgtlConfig:
    """Settings of the OpenIGTLink bridge."""

    port: int = DEFAULT_PORT
    """TCP port; 0 lets the operating system choose a free one (see IgtlBridge.port)."""
    local_only: bool = True
    """Bind to 127.0.0.1 (True) or to the address of ``iface`` (False)."""
    iface: str = "eth0"
    """Network interface whose address the server binds to when not local_only."""
    accepted_commands: frozenset[IgtlCommand] = frozenset()
    """Commands accepted from clients; the empty default accepts none."""
    poll_period_s: float = 0.01
    """How often incoming commands are polled (s)."""
    token: str = ""
    """When set, a command is accepted only as ``<token> <command> [argument]`` (required
    when the bridge is exposed beyond loopback)."""

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise InvalidValueError(f"port must be in [0, 65535], got {self.port}")
        if not self.poll_period_s > 0:
            raise InvalidValueError(f"poll_period_s must be > 0 s, got {self.poll_period_s} s")
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


class IgtlBridge:
    """An OpenIGTLink server that streams poses, images and status to 3D Slicer.

    Parameters
    ----------
    config : IgtlConfig
        Port, binding and accepted commands.
    on_command : callable, optional
        Called (on the bridge's polling thread) with each accepted :class:`IgtlRequest`.

    Raises
    ------
    IgtlError
        Not on the main thread, or the port cannot be bound.
    """

    def __init__(
        self,
        config: IgtlConfig | None = None,
        on_command: Callable[[IgtlRequest], None] | None = None,
    ):
        if threading.current_thread() is not threading.main_thread():
            raise IgtlError(
                "IgtlBridge must be created on the main thread: pyigtl's server installs "
                "SIGINT / SIGTERM handlers, which Python allows only there"
            )
        self.config = config or IgtlConfig()
        self._on_command = on_command
        self._previous_handlers = {
            sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)
        }
        try:
            self._server = pyigtl.OpenIGTLinkServer(
                port=self.config.port,
                local_server=self.config.local_only,
                iface=self.config.iface,
                start_now=True,
            )
        except OSError as exc:
            self._restore_signal_handlers()
            raise IgtlError(
                f"cannot open the OpenIGTLink server on port {self.config.port}: {exc}"
            ) from exc
        self.rejected: list[str] = []
        """Texts of the commands refused because they are not enabled (for diagnostics)."""
        self._stop = threading.Event()
        self._closed = False
        self._poller = threading.Thread(target=self._poll, name="igtl-commands", daemon=True)
        self._poller.start()

    # ------------------------------------------------------------------ properties
    @property
    def port(self) -> int:
        """The TCP port the server listens on (the chosen one when config.port is 0)."""
        return int(self._server.server_address[1])

    @property
    def host(self) -> str:
        """The address the server is bound to."""
        return str(self._server.server_address[0])

    @property
    def connected(self) -> bool:
        """Whether a client is connected."""
        return bool(self._server.is_connected())

    # ------------------------------------------------------------------ sending
    def send_pose(self, name: str, a2b: ArrayLike, timestamp: float | None = None) -> None:
        """Send a rigid transform (4, 4), mm, e.g. ``send_pose("TipToBase", tip2base)``."""
        check_device_name(name)
        matrix = check_transform(a2b, name, tol=1e-5)
        if matrix.shape != (4, 4):
            raise ShapeError(f"{name} must have shape (4, 4), got {matrix.shape}")
        self._send(pyigtl.TransformMessage(matrix, timestamp=timestamp, device_name=name))

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
        self._send(message)

    def send_status(self, status: str | Mapping[str, Any], timestamp: float | None = None) -> None:
        """Send a status text, or a mapping as a JSON object, on ``IcenavStatus``."""
        text = status if isinstance(status, str) else json.dumps(dict(status), sort_keys=True)
        self._send(pyigtl.StringMessage(text, timestamp=timestamp, device_name=DEVICE_STATUS))

    def _send(self, message: Any) -> None:
        if self._closed:
            raise IgtlError("the OpenIGTLink bridge is closed")
        # wait=False: with no client connected, waiting for the queue to drain would block.
        self._server.send_message(message, wait=False)

    # ------------------------------------------------------------------ commands
    def _poll(self) -> None:
        while not self._stop.wait(self.config.poll_period_s):
            try:
                for message in self._server.get_latest_messages():
                    if message.device_name == DEVICE_COMMAND and hasattr(message, "string"):
                        self._handle_command(str(message.string), float(message.timestamp))
            except Exception:  # pragma: no cover - keep polling whatever a client sends
                logger.exception("OpenIGTLink command handling failed")

    def _handle_command(self, text: str, timestamp: float) -> None:
        if self.config.token:  # reliability: part 4 (security); the token is never echoed
            given, _, rest = text.strip().partition(" ")
            if not hmac.compare_digest(given.encode(), self.config.token.encode()):
                self._reject("<redacted>", "missing or wrong token")
                return
            text = rest
        word, _, argument = text.strip().partition(" ")
        try:
            command = IgtlCommand(word.lower())
        except ValueError:
            self._reject(text, f"unknown command {word!r}")
            return
        if command not in self.config.accepted_commands:
            self._reject(text, f"command {command.value} is not enabled")
            return
        argument = argument.strip()
        if command is not IgtlCommand.STOP and not argument:
            self._reject(text, f"command {command.value} needs a view name")
            return
        self._ack(f"accepted: {text.strip()}")
        if self._on_command is not None:
            self._on_command(IgtlRequest(command, argument, timestamp))

    def _reject(self, text: str, reason: str) -> None:
        self.rejected.append(text)
        logger.warning("OpenIGTLink command %r rejected: %s", text, reason)
        self._ack(f"rejected: {text.strip()}: {reason}")

    def _ack(self, text: str) -> None:
        if not self._closed:
            self._server.send_message(
                pyigtl.StringMessage(text, device_name=DEVICE_COMMAND_ACK), wait=False
            )

    # ------------------------------------------------------------------ life cycle
    def close(self) -> None:
        """Stop the server and restore the signal handlers pyigtl replaced."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._poller.join(timeout=5.0)
        self._server.stop()
        self._restore_signal_handlers()

    def _restore_signal_handlers(self) -> None:
        if threading.current_thread() is threading.main_thread():
            for sig, handler in self._previous_handlers.items():
                signal.signal(sig, handler)

    def __enter__(self) -> IgtlBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def wait_for_client(bridge: IgtlBridge, timeout: float) -> bool:
    """Wait up to ``timeout`` seconds for a client to connect; True if one did."""
    deadline = time.monotonic() + timeout
    while not bridge.connected:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True
