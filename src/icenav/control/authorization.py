"""Who may do what: the one place where a command's source is checked.

Rules (``docs/safety.md``, "Authorization"):

- **State-changing commands** (jog, mode, go to view, spin, calibrate, compensation on/off,
  save / rename / delete view, reset, export) only from the client that holds control. When
  nobody holds control, such a command takes control for its client first (as Take control
  would), so whatever moves the robot always has a holder, and the holder's disconnect stops
  it.
- **E-STOP and Stop** from anyone who sees the robot, view-only clients included.
- A **view-only client** (a browser that has not entered the control token) is refused
  everything but Stop and E-STOP, and told why.
- **Take control** is refused while another client holds it; the gamepad always wins (its
  dead-man button is at the bedside).
- A client that **released** control (or disconnected) is refused the commands it asked for
  before it released: a jog still in the queue cannot take control back.

:class:`TokenGate` is the console's control-token check: constant-time comparison,
wrong guesses rate-limited per client and overall, with a logged alarm.
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

from icenav.control.commands import Command, Source
from icenav.errors import ConfigurationError

__all__ = ["Authorizer", "TokenGate", "TokenVerdict"]

logger = logging.getLogger("icenav.security")

_MAX_CLIENTS = 4096
"""Clients remembered (view-only flags, releases); the oldest are forgotten beyond it."""


def _remember(table: OrderedDict[str, int], client: str, value: int) -> None:
    table[client] = value
    table.move_to_end(client)
    while len(table) > _MAX_CLIENTS:
        table.popitem(last=False)


class Authorizer:
    """Control ownership and the authorization of every command (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._holder: str | None = None
        self._view_only: OrderedDict[str, int] = OrderedDict()
        self._released: OrderedDict[str, int] = OrderedDict()

    @property
    def holder(self) -> str | None:
        """The client that holds control (None: free)."""
        return self._holder

    def set_view_only(self, client: str, view_only: bool) -> None:
        """Mark ``client`` view only (it may Stop and E-STOP, nothing else), or lift it (the
        console does, once the browser entered the control token)."""
        with self._lock:
            if view_only:
                _remember(self._view_only, client, 1)
                if self._holder == client:
                    self._holder = None
            else:
                self._view_only.pop(client, None)

    def is_view_only(self, client: str) -> bool:
        """Whether ``client`` is marked view only."""
        return client in self._view_only

    def take(self, source: Source) -> str | None:
        """Give control to ``source``'s client; None when it holds it now, else why not."""
        client = source.client
        with self._lock:
            if client in self._view_only:
                return f"{client} is view only: enter the control token to take control"
            if self._holder in (None, client) or source.kind == "gamepad":
                self._holder = client
                return None
            return f"{self._holder} holds control"

    def release(self, source: Source, seq: int) -> str | None:
        """``source``'s client gives control back; None when released, else why not."""
        client = source.client
        with self._lock:
            _remember(self._released, client, seq)
            if self._holder != client:
                return f"{client} does not hold control ({self._holder or 'nobody'} does)"
            self._holder = None
            return None

    def disconnect(self, source: Source, seq: int) -> bool:
        """``source``'s client is gone: release its control; returns whether it held it."""
        client = source.client
        with self._lock:
            _remember(self._released, client, seq)
            held = self._holder == client
            if held:
                self._holder = None
            return held

    def authorize(self, command: Command, seq: int) -> str | None:
        """None when ``command`` (submitted as number ``seq``) may run, else why not. A
        state-changing command while control is free takes control for its client."""
        if not command.changes_state:
            return None
        client = command.source.client
        what = command.name
        with self._lock:
            if client in self._view_only:
                return f"{client} is view only: enter the control token and take control to {what}"
            released = self._released.get(client)
            if released is not None and seq < released:
                return f"{client} released control after asking to {what}"
            if self._holder is None:
                self._holder = client
                return None
            if self._holder == client:
                return None
            return f"{client} asked to {what} but {self._holder} holds control (view only)"


@dataclass(frozen=True)
class TokenVerdict:
    """The answer to one control-token entry."""

    ok: bool
    """The token was right (and the client was not waiting out a penalty)."""
    reason: str = ""
    """Why not, for the browser."""


class TokenGate:
    """Checks control tokens: constant time, rate-limited, with an alarm.

    A wrong token costs its client a wait that doubles from ``base_delay_s`` after
    ``free_attempts`` wrong entries in a row (up to ``max_delay_s``); while it waits, its
    entries are refused without being compared. Independently, ``global_per_minute`` wrong
    entries within a minute from all clients together (a client that reconnects to get a new
    id) close token entry for everyone until the minute's count drops below it. Each
    wrong entry is logged (``icenav.security``); the first of a penalty and every global
    excess raise an alarm at ERROR level. The token is compared as SHA-256 digests with
    ``hmac.compare_digest``, so neither its content nor its length leak through timing.

    Parameters
    ----------
    token : str
        The control token.
    clock : callable
        Monotonic time (s), injectable for tests.
    on_alarm : callable, optional
        Also called with each alarm's text (the console shows it).
    """

    def __init__(
        self,
        token: str,
        *,
        free_attempts: int = 3,
        base_delay_s: float = 1.0,
        max_delay_s: float = 300.0,
        global_per_minute: int = 20,
        clock: Callable[[], float] = time.monotonic,
        on_alarm: Callable[[str], None] | None = None,
    ) -> None:
        if not token:
            raise ConfigurationError("the control token must not be empty")
        if free_attempts < 0 or global_per_minute < 1:
            raise ConfigurationError(
                f"free_attempts must be >= 0 and global_per_minute >= 1, got "
                f"{free_attempts} and {global_per_minute}"
            )
        if not (0 < base_delay_s <= max_delay_s and math.isfinite(max_delay_s)):
            raise ConfigurationError(
                f"need 0 < base_delay_s <= max_delay_s (s), got {base_delay_s}, {max_delay_s}"
            )
        self._digest = hashlib.sha256(token.encode()).digest()
        self._free = int(free_attempts)
        self._base = float(base_delay_s)
        self._max = float(max_delay_s)
        self._global = int(global_per_minute)
        self._clock = clock
        self._on_alarm = on_alarm
        self._lock = threading.Lock()
        self._fails: OrderedDict[str, int] = OrderedDict()
        self._until: dict[str, float] = {}
        self._recent: list[float] = []
        self.wrong = 0
        """Wrong entries so far (all clients)."""
        self.alarms = 0
        """Alarms raised so far."""

    def check(self, client: str, given: str) -> TokenVerdict:
        """Check ``given`` (already stripped) for ``client``."""
        now = self._clock()
        with self._lock:
            wait = self._until.get(client, 0.0) - now
            if wait > 0:
                return TokenVerdict(False, f"too many wrong tokens: wait {math.ceil(wait)} s")
            self._recent = [t for t in self._recent if now - t < 60.0]
            if len(self._recent) >= self._global:
                return TokenVerdict(
                    False, "too many wrong tokens from all clients: try again in a minute"
                )
        given_digest = hashlib.sha256(given.encode()).digest()
        ok = hmac.compare_digest(given_digest, self._digest)
        with self._lock:
            if ok:
                self._fails.pop(client, None)
                self._until.pop(client, None)
                return TokenVerdict(True)
            self.wrong += 1
            self._recent.append(now)
            if len(self._recent) == self._global:
                self._alarm(
                    f"{self._global} wrong control tokens within a minute from all clients: "
                    "token entries refused until the count drops"
                )
            n = self._fails.get(client, 0) + 1
            _remember(self._fails, client, n)
            logger.warning("wrong control token from %s (%d in a row)", client, n)
            if n <= self._free:
                return TokenVerdict(False, "wrong control token: viewing only")
            delay = min(self._max, self._base * 2.0 ** (n - self._free - 1))
            self._until[client] = now + delay
            if len(self._until) > _MAX_CLIENTS:
                self._until = {c: t for c, t in self._until.items() if t > now}
            if n == self._free + 1:
                self._alarm(f"{n} wrong control tokens in a row from {client}: rate-limited")
            return TokenVerdict(
                False, f"wrong control token: viewing only; next try in {math.ceil(delay)} s"
            )

    def _alarm(self, text: str) -> None:
        self.alarms += 1
        logger.error("ALARM: %s", text)
        if self._on_alarm is not None:
            self._on_alarm(text)
