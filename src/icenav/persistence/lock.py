"""One writer per session file: an exclusive lock on ``<session>.lock`` beside it.

The lock is ``flock(LOCK_EX | LOCK_NB)`` on the lock file (``fcntl.flock``). The operating
system releases it when the holder's descriptor closes, including when the process is
killed (``kill -9``), so a crash never leaves a session locked. ``flock`` rather than a
POSIX record lock (``fcntl.lockf``): record locks belong to the process and do not
conflict between two opens in one process, and closing *any* descriptor of the file drops
them; ``flock`` locks belong to the open file, so a second store in the same process is
refused too. The holder writes its PID, host and start time into the lock file for the
error message of whoever is refused; the file itself is never deleted (deleting it would
let two processes lock two different files of the same name).

Limits: on a network file system ``flock`` may be local to one machine (Linux NFS maps it
to a POSIX lock since 2.6.12; CIFS varies): keep sessions on a local disk.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import fcntl
import json
import os
import socket
from pathlib import Path

from icenav.errors import SessionLockedError, StoreError

__all__ = ["SessionLock", "lock_path_for"]


def lock_path_for(session: Path) -> Path:
    """The lock file of a session file: ``<name>.lock`` in the same folder."""
    return session.with_name(session.name + ".lock")


class SessionLock:
    """An exclusive lock on a session file, held until :meth:`release` (or the process
    ends).

    Raises
    ------
    SessionLockedError
        Another process (or another store in this one) holds it; the message names the
        session file and the holder (PID, host, since when).
    StoreError
        The lock file cannot be created (missing folder, permissions).
    """

    def __init__(self, session: Path) -> None:
        self.session = Path(session)
        self.path = lock_path_for(self.session)
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            raise StoreError(
                f"cannot lock session file {self.session}: cannot create {self.path}: "
                f"{exc.strerror or exc}"
            ) from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            raise SessionLockedError(
                f"session file {self.session} is open for writing by {holder}; one process "
                "writes a session at a time (it may be opened read-only meanwhile)",
                holder=holder,
            ) from None
        except OSError as exc:
            os.close(fd)
            raise StoreError(f"cannot lock session file {self.session}: {exc}") from exc
        self._fd: int | None = fd
        info = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "since_utc": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M:%S"),
        }
        with contextlib.suppress(OSError):  # the holder text is for messages only
            os.ftruncate(fd, 0)
            os.pwrite(fd, json.dumps(info).encode(), 0)

    @property
    def held(self) -> bool:
        """Whether this lock is still held."""
        return self._fd is not None

    def release(self) -> None:
        """Release the lock (closing the descriptor releases it; the file stays)."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
        os.close(fd)


def _read_holder(fd: int) -> str:
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode("utf-8"))
        return f"pid {int(info['pid'])} on host {info['host']} (since {info['since_utc']} UTC)"
    except (OSError, ValueError, KeyError, TypeError):
        return "another process (its PID and host were not written yet)"
