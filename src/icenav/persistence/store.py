"""Crash-safe SQLite persistence of a procedure session (stdlib ``sqlite3``, WAL mode).

What is stored: roadmap vertices, edges and the vertex trace, saved views, calibrations in
use, and an append-only event log (operator inputs, commands, faults). Writes are
incremental: the controller calls :meth:`SessionStore.sync_roadmap` (or ``add_vertices`` /
``add_edges`` / ``add_trace``) every cycle and the store commits a batch every
``batch_states`` rows or ``batch_seconds`` seconds; :meth:`SessionStore.add_view` flushes the
pending batch and commits at once, so after a ``kill -9`` a reopened session has every view
saved before the kill and the roadmap up to the last committed batch.

Schema (``PRAGMA user_version`` = :data:`SCHEMA_VERSION`, ``PRAGMA application_id`` =
:data:`APPLICATION_ID`)::

    meta(key TEXT PRIMARY KEY, value TEXT)                 roadmap config (JSON), created
    vertices(id INTEGER PRIMARY KEY, phi1, phi2, phi3, d4)  rad, rad, rad, mm
    edges(u INTEGER, v INTEGER, w REAL, PRIMARY KEY (u, v)) w in metric units
    trace(seq INTEGER PRIMARY KEY, vertex INTEGER)
    views(name TEXT PRIMARY KEY, vertex, phi1, phi2, phi3, d4, created_s, arrival TEXT,
          approach TEXT, tip2base BLOB, thumbnail BLOB, notes TEXT, ordinal INTEGER)
    calibrations(name TEXT PRIMARY KEY, kind TEXT, data TEXT, created_s REAL)
    events(seq INTEGER PRIMARY KEY AUTOINCREMENT, t REAL, kind TEXT, data TEXT)
    view_em(name TEXT PRIMARY KEY, tip2base BLOB)          a view's EM pose (added on open
                                                           for writing; older files lack it)
"""

from __future__ import annotations

import functools
import io
import json
import os
import queue
import sqlite3
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav.devices.registration import Registration
from icenav.errors import (
    FileFormatError,
    IcenavError,
    PlanningError,
    StoreError,
    UnsupportedVersionError,
)
from icenav.persistence.lock import SessionLock
from icenav.recovery.roadmap import Roadmap, RoadmapConfig, RoadmapMetric
from icenav.recovery.views import View, ViewLibrary

__all__ = [
    "APPLICATION_ID",
    "CALIBRATION_IN_USE",
    "Event",
    "SCHEMA_VERSION",
    "SessionStore",
    "StoreWriter",
]

SCHEMA_VERSION = 1
"""Version of the session file layout written by this icenav."""

APPLICATION_ID = 0x1CE0A71
"""``PRAGMA application_id`` marking an icenav session file."""

CALIBRATION_IN_USE = "calibration"
"""Row of the calibrations table that holds the calibration in use (its calibration-file
document), which a reopened session installs again."""

_SCHEMA = """
CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE vertices(id INTEGER PRIMARY KEY, phi1 REAL NOT NULL, phi2 REAL NOT NULL,
                      phi3 REAL NOT NULL, d4 REAL NOT NULL);
CREATE TABLE edges(u INTEGER NOT NULL, v INTEGER NOT NULL, w REAL NOT NULL,
                   PRIMARY KEY (u, v)) WITHOUT ROWID;
CREATE TABLE trace(seq INTEGER PRIMARY KEY, vertex INTEGER NOT NULL);
CREATE TABLE views(name TEXT PRIMARY KEY, vertex INTEGER NOT NULL, phi1 REAL NOT NULL,
                   phi2 REAL NOT NULL, phi3 REAL NOT NULL, d4 REAL NOT NULL,
                   created_s REAL NOT NULL, arrival TEXT NOT NULL, approach TEXT NOT NULL,
                   tip2base BLOB, thumbnail BLOB, notes TEXT NOT NULL, ordinal INTEGER NOT NULL);
CREATE TABLE calibrations(name TEXT PRIMARY KEY, kind TEXT NOT NULL, data TEXT NOT NULL,
                          created_s REAL NOT NULL);
CREATE TABLE events(seq INTEGER PRIMARY KEY AUTOINCREMENT, t REAL NOT NULL,
                    kind TEXT NOT NULL, data TEXT NOT NULL);
"""
_VIEW_EM_TABLE = "CREATE TABLE IF NOT EXISTS view_em(name TEXT PRIMARY KEY, tip2base BLOB NOT NULL)"
"""A view's EM pose (:attr:`icenav.recovery.views.View.em_tip2base`, .npy bytes)."""

_TABLES = {"meta", "vertices", "edges", "trace", "views", "calibrations", "events"}


@dataclass(frozen=True)
class Event:
    """One entry of the append-only event log."""

    seq: int
    """Sequence number (increasing)."""
    t: float
    """Time (s, the controller's clock)."""
    kind: str
    """What happened: "input", "command", "fault", "view_saved", ..."""
    data: dict[str, Any]
    """Details (JSON-serialisable)."""


_F = TypeVar("_F", bound=Callable[..., Any])


def _rows_checked(what: str) -> Callable[[_F], _F]:
    """Reading ``what`` from a file whose rows were damaged (edited, half-written by another
    tool) raises FileFormatError naming the file, not a bare ValueError / KeyError / ...
    (reliability fix, found by fuzz target store_rows)."""

    def wrap(fn: _F) -> _F:
        @functools.wraps(fn)
        def inner(self: SessionStore, *args: Any, **kwargs: Any) -> Any:
            try:
                with np.errstate(invalid="raise", over="raise", divide="raise"):
                    return fn(self, *args, **kwargs)
            except (FileFormatError, StoreError):
                raise
            except (IcenavError, ValueError, TypeError, LookupError, ArithmeticError) as e:
                if isinstance(e, IcenavError) and not isinstance(e, ValueError | PlanningError):
                    raise
                raise FileFormatError(f"{self.path}: the stored {what} are corrupt: {e}") from e
            except sqlite3.Error as exc:
                self._raise(exc, "read")
                raise  # unreachable: _raise always raises

        return inner  # type: ignore[return-value]

    return wrap


def _npy_bytes(a: NDArray[Any] | None) -> bytes | None:
    if a is None:
        return None
    buf = io.BytesIO()
    np.save(buf, np.asarray(a), allow_pickle=False)
    return buf.getvalue()


def _npy_load(b: bytes | None) -> NDArray[Any] | None:
    if b is None:
        return None
    return np.asarray(np.load(io.BytesIO(b), allow_pickle=False))


class SessionStore:
    """One procedure session in one SQLite file.

    Parameters
    ----------
    path : str or Path
        The session file; created (with ``config``) if it does not exist.
    config : RoadmapConfig, optional
        Roadmap settings for a new file (ignored when reopening: the file's own are used).
    batch_states : int
        Commit after this many pending vertex/edge/trace rows.
    batch_seconds : float
        ... or when the oldest pending row is this old (s, ``clock``).
    clock : callable, optional
        Time source (s); default ``time.monotonic``.
    read_only : bool
        Open an existing file for reading only; any write raises StoreError. Needs no lock:
        a session being written by another process can be read.
    new_session : bool
        Start a new session in ``path``, which must not exist or be empty (0 bytes); a file
        holding a session is never overwritten. Without it an empty file is refused (it is
        what a crash during creation, or a mistaken ``touch``, leaves).

    A store opened for writing holds an exclusive lock on the file (:mod:`.lock`,
    ``<path>.lock``) until :meth:`close`; the operating system releases it if the process
    dies.

    Raises
    ------
    SessionLockedError
        Another process (or another store here) writes the file; names the holder.
    FileFormatError
        Not an SQLite file, or not an icenav session.
    UnsupportedVersionError
        Written by a newer icenav.
    StoreError
        Cannot create or write the file (missing folder, read-only, disk full, an empty
        file without ``new_session``, ...).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        config: RoadmapConfig | None = None,
        batch_states: int = 1000,
        batch_seconds: float = 1.0,
        clock: Callable[[], float] | None = None,
        read_only: bool = False,
        new_session: bool = False,
    ) -> None:
        self.path = Path(path)
        self.read_only = bool(read_only)
        self.batch_states = int(batch_states)
        self.batch_seconds = float(batch_seconds)
        self._clock = clock if clock is not None else time.monotonic
        self._pending = 0
        self._pending_since: float | None = None
        self._lock: SessionLock | None = None
        self._check_folder()
        if not read_only:
            self._lock = SessionLock(self.path)  # before anything is read or created
        try:
            exists = self._check_path(read_only, new_session)
            self._open(exists, config, read_only)
        except BaseException:
            if self._lock is not None:
                self._lock.release()
            raise

    def _check_folder(self) -> None:
        folder = self.path.parent
        if not folder.is_dir():
            what = "does not exist" if not folder.exists() else "is not a folder"
            raise StoreError(f"cannot open session file {self.path}: the folder {folder} {what}")

    def _check_path(self, read_only: bool, new_session: bool) -> bool:
        """Whether the file holds data; refuses an empty file without ``new_session`` and a
        file with data with it."""
        try:
            size = self.path.stat().st_size if self.path.exists() else None
        except OSError as exc:
            raise StoreError(f"cannot open session file {self.path}: {exc}") from exc
        if read_only and not size:
            what = "does not exist" if size is None else "is empty (0 bytes)"
            raise StoreError(f"cannot open session file {self.path} read-only: it {what}")
        if size == 0 and not new_session:
            raise StoreError(
                f"session file {self.path} is empty (0 bytes), not a session: start a new "
                "session in it explicitly (icenav demo --new-session) or choose another file"
            )
        if size and new_session:
            raise StoreError(
                f"session file {self.path} holds data ({size} bytes): a new session is never "
                "written over a file; choose another file, or resume it without --new-session"
            )
        return bool(size)

    def _open(self, exists: bool, config: RoadmapConfig | None, read_only: bool) -> None:
        try:
            if read_only:
                uri = self.path.resolve().as_uri() + "?mode=ro"
                self._db = sqlite3.connect(
                    uri, uri=True, isolation_level=None, check_same_thread=False
                )
            else:
                # check_same_thread=False: a StoreWriter writes from its own thread (one
                # thread at a time: the writer owns the store while it runs)
                self._db = sqlite3.connect(
                    str(self.path), isolation_level=None, check_same_thread=False
                )
        except sqlite3.Error as exc:
            raise StoreError(f"cannot open session file {self.path}: {exc}") from exc
        try:
            if exists:
                self._check_existing()
            else:
                self._create(config if config is not None else RoadmapConfig())
            if not read_only:
                self._db.execute("PRAGMA journal_mode=WAL")
                # the views' EM poses: added to files written before it (the layout stays
                # version 1; an older icenav ignores the table)
                self._db.execute(_VIEW_EM_TABLE)
            # FULL: a commit is durable even against power loss, not only a killed process.
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("BEGIN")
        except (FileFormatError, StoreError):
            self._db.close()
            raise
        except sqlite3.DatabaseError as exc:
            self._db.close()
            self._raise(exc, "open")
        except UnicodeDecodeError as exc:  # reliability fix: a damaged schema (fuzz target store)
            self._db.close()
            raise FileFormatError(f"{self.path} is a corrupt session file: {exc}") from exc
        self._synced_vertices = self._count("vertices")
        self._synced_edges = self._count("edges")
        self._synced_trace = self._count("trace")

    # --- opening ----------------------------------------------------------------------

    def _raise(self, exc: sqlite3.Error, action: str) -> None:
        text = str(exc)
        low = text.lower()
        if "not a database" in low or "malformed" in low or "file is encrypted" in low:
            raise FileFormatError(
                f"{self.path} is not a readable icenav session file (corrupt or not SQLite): {text}"
            ) from exc
        if "full" in low:
            raise StoreError(
                f"cannot {action} session file {self.path}: the disk (or the database size "
                f"limit) is full: {text}"
            ) from exc
        if "readonly" in low or "read-only" in low:
            raise StoreError(
                f"cannot {action} session file {self.path}: it is read-only: {text}"
            ) from exc
        raise StoreError(f"cannot {action} session file {self.path}: {text}") from exc

    def _check_existing(self) -> None:
        try:
            app = self._db.execute("PRAGMA application_id").fetchone()[0]
            version = self._db.execute("PRAGMA user_version").fetchone()[0]
            tables = {r[0] for r in self._db.execute("SELECT name FROM sqlite_master")}
            check = self._db.execute("PRAGMA quick_check").fetchone()[0]
        except sqlite3.DatabaseError as exc:
            self._raise(exc, "read")
        if check != "ok":
            raise FileFormatError(f"{self.path} is a corrupt session file: {check}")
        if app != APPLICATION_ID:
            raise FileFormatError(
                f"{self.path} is an SQLite file but not an icenav session "
                f"(application_id {app:#x}, expected {APPLICATION_ID:#x})"
            )
        if version > SCHEMA_VERSION:
            raise UnsupportedVersionError(
                f"{self.path} has session format version {version}, newer than this icenav "
                f"supports ({SCHEMA_VERSION}); upgrade icenav to open it"
            )
        if version < 1 or not tables >= _TABLES:
            raise FileFormatError(
                f"{self.path}: unknown session format version {version} or missing tables "
                f"{sorted(_TABLES - tables)}"
            )

    def _create(self, config: RoadmapConfig) -> None:
        try:
            self._db.execute("BEGIN")
            for stmt in _SCHEMA.strip().split(";"):
                if stmt.strip():
                    self._db.execute(stmt)
            cfg = {
                "epsilon": config.epsilon,
                "merge_radius": config.merge_radius,
                "metric": asdict(config.metric),
                "direction_threshold": config.direction_threshold,
                "approach_length": config.approach_length,
                "max_vertices": config.max_vertices,
                "tree_cache": config.tree_cache,
            }
            self._db.execute("INSERT INTO meta VALUES ('roadmap_config', ?)", (json.dumps(cfg),))
            self._db.execute("INSERT INTO meta VALUES ('created_unix_s', ?)", (str(time.time()),))
            self._db.execute(f"PRAGMA application_id={APPLICATION_ID}")
            self._db.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
            self._db.execute("COMMIT")
        except sqlite3.Error as exc:
            self._raise(exc, "create")

    def _count(self, table: str) -> int:
        row = self._db.execute(f"SELECT COUNT(*) FROM {table}").fetchone()
        return int(row[0])

    @property
    @_rows_checked("roadmap settings")
    def config(self) -> RoadmapConfig:
        """The roadmap settings stored in the file."""
        row = self._db.execute("SELECT value FROM meta WHERE key='roadmap_config'").fetchone()
        if row is None:
            raise FileFormatError(f"{self.path}: the roadmap configuration is missing")
        d = json.loads(row[0])
        return RoadmapConfig(
            epsilon=d["epsilon"],
            merge_radius=d["merge_radius"],
            metric=RoadmapMetric(**d["metric"]),
            direction_threshold=d["direction_threshold"],
            approach_length=d["approach_length"],
            # absent in files written before the vertex budget: the defaults
            max_vertices=d.get("max_vertices", RoadmapConfig.max_vertices),
            tree_cache=d.get("tree_cache", RoadmapConfig.tree_cache),
        )

    # --- writing --------------------------------------------------------------------------

    def _exec_many(self, sql: str, rows: Any) -> None:
        try:
            self._db.executemany(sql, rows)
        except sqlite3.Error as exc:
            self._restart_batch()
            self._raise(exc, "write")

    def _restart_batch(self) -> None:
        """After a failed write or commit (disk full, read-only), SQLite may have rolled the
        batch back on its own: roll back what is left, start a new batch and sync again from
        what is on disk, so the next sync rewrites the lost rows instead of leaving a gap.
        (reliability fix: before it, every later commit failed with "no transaction is
        active" and the rolled-back rows were counted as synced.)"""
        try:
            if self._db.in_transaction:
                self._db.execute("ROLLBACK")
            self._db.execute("BEGIN")
            self._synced_vertices = self._count("vertices")
            self._synced_edges = self._count("edges")
            self._synced_trace = self._count("trace")
        except sqlite3.Error:
            pass  # the original error is what the caller reports
        self._pending = 0
        self._pending_since = None

    def _queue(self, k: int) -> None:
        if k > 0:
            if self._pending == 0:
                self._pending_since = self._clock()
            self._pending += k

    def _note_pending(self, k: int) -> None:
        self._queue(k)
        self.maybe_commit()

    def add_vertices(self, first_id: int, q: ArrayLike) -> None:
        """Queue vertices ``first_id, first_id + 1, ...`` with motor states (k, 4)."""
        arr = np.asarray(q, np.float64).reshape(-1, 4)
        rows = [(first_id + i, *r) for i, r in enumerate(arr.tolist())]
        self._exec_many("INSERT OR REPLACE INTO vertices VALUES (?, ?, ?, ?, ?)", rows)
        self._note_pending(len(rows))

    def add_edges(self, uv: ArrayLike, w: ArrayLike) -> None:
        """Queue edges: (k, 2) vertex ids and (k,) lengths (metric units)."""
        e = np.asarray(uv, np.int64).reshape(-1, 2).tolist()
        ws = np.asarray(w, np.float64).reshape(-1).tolist()
        rows = [(a, b, c) for (a, b), c in zip(e, ws, strict=True)]
        self._exec_many("INSERT OR REPLACE INTO edges VALUES (?, ?, ?)", rows)
        self._note_pending(len(rows))

    def add_trace(self, first_seq: int, vertices: ArrayLike) -> None:
        """Queue trace entries ``first_seq, first_seq + 1, ...`` (vertex ids)."""
        ids = np.asarray(vertices, np.int64).reshape(-1).tolist()
        rows = [(first_seq + i, v) for i, v in enumerate(ids)]
        self._exec_many("INSERT OR REPLACE INTO trace VALUES (?, ?)", rows)
        self._note_pending(len(rows))

    def sync_roadmap(self, roadmap: Roadmap, upto: tuple[int, int, int] | None = None) -> bool:
        """Queue what ``roadmap`` gained since the last sync (incremental, no rewrite) and
        commit if the batch is due; return whether it committed. Vertices, edges and trace
        of one sync always land in the same transaction.

        ``upto`` = ``roadmap.counts()`` taken earlier on the thread that grows the roadmap:
        only rows below these counts are read, so a writer thread can sync while the
        roadmap keeps growing (rows below a count never change)."""
        nv, ne, nt = roadmap.counts() if upto is None else upto
        if nv > self._synced_vertices:
            q = roadmap.vertices(self._synced_vertices, nv)
            rows = [(self._synced_vertices + i, *r) for i, r in enumerate(q.tolist())]
            self._exec_many("INSERT OR REPLACE INTO vertices VALUES (?, ?, ?, ?, ?)", rows)
            self._queue(len(rows))
            self._synced_vertices = nv
        if ne > self._synced_edges:
            uv, w = roadmap.edges(self._synced_edges, ne)
            erows = [(a, b, c) for (a, b), c in zip(uv.tolist(), w.tolist(), strict=True)]
            self._exec_many("INSERT OR REPLACE INTO edges VALUES (?, ?, ?)", erows)
            self._queue(len(erows))
            self._synced_edges = ne
        if nt > self._synced_trace:
            tr = roadmap.trace(self._synced_trace, nt).tolist()
            trows = [(self._synced_trace + i, v) for i, v in enumerate(tr)]
            self._exec_many("INSERT OR REPLACE INTO trace VALUES (?, ?)", trows)
            self._queue(len(trows))
            self._synced_trace = nt
        return self.maybe_commit()

    def maybe_commit(self) -> bool:
        """Commit when the batch is full or old enough; return whether it committed."""
        if self._pending == 0:
            return False
        old = (
            self._pending_since is not None
            and self._clock() - self._pending_since >= self.batch_seconds
        )
        if self._pending >= self.batch_states or old:
            self.commit()
            return True
        return False

    def commit(self) -> None:
        """Commit everything pending now."""
        try:
            self._db.execute("COMMIT")
            self._db.execute("BEGIN")
        except sqlite3.Error as exc:
            self._restart_batch()
            self._raise(exc, "commit to")
        self._pending = 0
        self._pending_since = None

    def add_view(
        self,
        view: View,
        roadmap: Roadmap | None = None,
        upto: tuple[int, int, int] | None = None,
    ) -> None:
        """Store a view and commit at once (with the pending roadmap batch, first synced
        from ``roadmap`` if given, up to ``upto`` as in :meth:`sync_roadmap`, so the view's
        vertex is on disk too)."""
        if roadmap is not None:
            self.sync_roadmap(roadmap, upto)
        ordinal = self._db.execute("SELECT COALESCE(MAX(ordinal), 0) + 1 FROM views").fetchone()[0]
        row = (
            view.name,
            view.vertex,
            *view.q.tolist(),
            view.created_s,
            json.dumps(list(view.arrival_direction)),
            json.dumps(list(view.approach)),
            _npy_bytes(view.tip2base),
            _npy_bytes(view.thumbnail),
            view.notes,
            ordinal,
        )
        self._exec_many(
            "INSERT OR REPLACE INTO views VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", [row]
        )
        self._exec_many("DELETE FROM view_em WHERE name=?", [(view.name,)])
        if view.em_tip2base is not None:
            self._exec_many(
                "INSERT INTO view_em VALUES (?, ?)", [(view.name, _npy_bytes(view.em_tip2base))]
            )
        self.commit()

    def rename_view(self, old: str, new: str) -> None:
        """Rename a stored view (committed at once)."""
        self._exec_many("UPDATE views SET name=? WHERE name=?", [(new, old)])
        self._exec_many("UPDATE view_em SET name=? WHERE name=?", [(new, old)])
        self.commit()

    def delete_view(self, name: str) -> None:
        """Delete a stored view (committed at once)."""
        self._exec_many("DELETE FROM views WHERE name=?", [(name,)])
        self._exec_many("DELETE FROM view_em WHERE name=?", [(name,)])
        self.commit()

    def save_calibration(
        self, name: str, kind: str, data: dict[str, Any], created_s: float
    ) -> None:
        """Store a calibration in use (JSON-serialisable ``data``), committed at once."""
        self._exec_many(
            "INSERT OR REPLACE INTO calibrations VALUES (?, ?, ?, ?)",
            [(name, kind, json.dumps(data), float(created_s))],
        )
        self.commit()

    def save_registration(self, registration: Registration, created_s: float) -> None:
        """Store the tracker's registration in use (row ``registration`` of the calibrations
        table, kind ``registration``; :meth:`Registration.to_dict`), committed at once."""
        if not isinstance(registration, Registration):
            raise StoreError(
                f"registration must be a Registration, got {type(registration).__name__}"
            )
        self.save_calibration("registration", "registration", registration.to_dict(), created_s)

    def registration(self) -> Registration | None:
        """The stored registration (None when the session has none)."""
        stored = self.calibrations().get("registration")
        if stored is None:
            return None
        return Registration.from_dict(stored[1], source=f"{self.path}: registration")

    def save_calibration_document(
        self, kind: str, document: dict[str, Any], created_s: float
    ) -> None:
        """Store the calibration in use as its calibration-file document
        (:meth:`icenav.calibration.files.CalibrationFile.to_dict`: samples, kind and fitted
        model), row :data:`CALIBRATION_IN_USE`, committed at once (a crash-restart of the
        session re-installs it)."""
        if not isinstance(document, dict):
            raise StoreError(f"document must be a dict, got {type(document).__name__}")
        self.save_calibration(CALIBRATION_IN_USE, str(kind), document, created_s)

    def calibration_document(self) -> tuple[str, dict[str, Any]] | None:
        """The calibration in use, ``(kind, document)`` (None when the session has none)."""
        stored = self.calibrations().get(CALIBRATION_IN_USE)
        return None if stored is None else (stored[0], stored[1])

    def log_event(self, t: float, kind: str, data: dict[str, Any] | None = None) -> None:
        """Append an event (committed with the next batch; faults commit at once)."""
        self._exec_many(
            "INSERT INTO events(t, kind, data) VALUES (?, ?, ?)",
            [(float(t), kind, json.dumps(data or {}))],
        )
        if kind == "fault":
            self.commit()
        else:
            self._note_pending(1)

    # --- reading --------------------------------------------------------------------------

    @_rows_checked("roadmap rows")
    def load_roadmap(self) -> Roadmap:
        """Rebuild the roadmap from the committed (and pending) rows."""
        try:
            v = np.array(
                self._db.execute(
                    "SELECT phi1, phi2, phi3, d4 FROM vertices ORDER BY id"
                ).fetchall(),
                np.float64,
            ).reshape(-1, 4)
            e = self._db.execute("SELECT u, v, w FROM edges").fetchall()
            t = self._db.execute("SELECT vertex FROM trace ORDER BY seq").fetchall()
        except sqlite3.Error as exc:
            self._raise(exc, "read")
        uv = np.array([(a, b) for a, b, _ in e], np.int64).reshape(-1, 2)
        w = np.array([c for _, _, c in e], np.float64)
        tr = np.array([r[0] for r in t], np.int64)
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(w))):  # reliability fix
            raise FileFormatError(f"{self.path}: a stored vertex or edge is not finite")
        return Roadmap.from_arrays(v, uv, w, tr, config=self.config)

    @_rows_checked("views")
    def load_views(self) -> ViewLibrary:
        """All stored views, in the order they were saved."""
        lib = ViewLibrary()
        rows = self._db.execute(
            "SELECT name, vertex, phi1, phi2, phi3, d4, created_s, arrival, approach, tip2base, "
            "thumbnail, notes FROM views ORDER BY ordinal"
        ).fetchall()
        em = {name: _npy_load(blob) for name, blob in self._view_em_rows()}
        for r in rows:
            lib.add(
                View(
                    name=r[0],
                    vertex=r[1],
                    q=np.array(r[2:6], np.float64),
                    created_s=r[6],
                    arrival_direction=tuple(json.loads(r[7])),
                    approach=tuple(json.loads(r[8])),
                    tip2base=_npy_load(r[9]),
                    thumbnail=_npy_load(r[10]),
                    notes=r[11],
                    em_tip2base=em.get(r[0]),
                )
            )
        return lib

    def _view_em_rows(self) -> list[tuple[str, bytes]]:
        """The views' EM poses (table ``view_em``; a file written by an icenav without it has
        none: its views load with ``em_tip2base`` None)."""
        known = self._db.execute(
            "SELECT 1 FROM sqlite_master WHERE type='table' AND name='view_em'"
        ).fetchone()
        if known is None:
            return []
        return [(r[0], r[1]) for r in self._db.execute("SELECT name, tip2base FROM view_em")]

    @_rows_checked("calibrations")
    def calibrations(self) -> dict[str, tuple[str, dict[str, Any], float]]:
        """Stored calibrations: name -> (kind, data, created_s)."""
        rows = self._db.execute("SELECT name, kind, data, created_s FROM calibrations").fetchall()
        return {r[0]: (r[1], json.loads(r[2]), r[3]) for r in rows}

    @_rows_checked("events")
    def events(self, kind: str | None = None) -> list[Event]:
        """The event log in order (optionally of one kind)."""
        sql = "SELECT seq, t, kind, data FROM events"
        args: tuple[str, ...] = ()
        if kind is not None:
            sql += " WHERE kind=?"
            args = (kind,)
        rows = self._db.execute(sql + " ORDER BY seq", args).fetchall()
        return [Event(r[0], r[1], r[2], json.loads(r[3])) for r in rows]

    # --- closing ------------------------------------------------------------------------

    def close(self) -> None:
        """Commit what is pending, close the file and release the lock."""
        try:
            if self._db.in_transaction:
                self._db.execute("COMMIT")
        except sqlite3.Error as exc:
            self._raise(exc, "commit to")
        finally:
            self._db.close()
            if self._lock is not None:
                self._lock.release()

    def __enter__(self) -> SessionStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class StoreWriter:
    """Runs a :class:`SessionStore`'s writes, in order, on a thread of its own, so that no
    insert, commit or fsync runs on the control thread.

    While the writer runs, it owns the store: every write goes through :meth:`submit`
    (reads at start-up, before the writer, and after :meth:`close` are fine).

    Errors: a job submitted with ``on_done`` gets its outcome there (``None`` or the
    exception), called on the writer thread, *after* the job's commit (so "done" means
    durable when the job commits, as :meth:`SessionStore.add_view` does). The first error
    of a job without ``on_done`` is kept and raised by the next :meth:`raise_pending` (the
    recorder calls it every control cycle, so the operator learns of a full disk within a
    cycle); an error reported to ``on_done`` clears the pending one (the submitter tells
    the operator of it). After an error the store restarts its batch from what is on disk, so later
    syncs rewrite the lost rows.

    Parameters
    ----------
    store : SessionStore
        The store to write to (opened for writing).
    name : str
        Name of the thread.
    """

    def __init__(self, store: SessionStore, name: str = "icenav-store-writer") -> None:
        self.store = store
        self._jobs: queue.Queue[
            tuple[Callable[[SessionStore], object], Callable[[BaseException | None], None] | None]
            | None
        ] = queue.Queue()
        self._error: BaseException | None = None
        self._error_lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._closed = False
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = self._jobs.get()
            try:
                if item is None:
                    return
                fn, on_done = item
                error: BaseException | None = None
                try:
                    fn(self.store)
                except Exception as exc:  # noqa: BLE001 - reported to the submitter
                    error = exc
                if on_done is not None:
                    if error is not None:  # reported there: it supersedes pending errors
                        with self._error_lock:
                            self._error = None
                    try:
                        on_done(error)
                    except Exception as exc:  # noqa: BLE001 - keep the writer alive
                        error = exc
                    else:
                        error = None
                if error is not None:
                    with self._error_lock:
                        if self._error is None:
                            self._error = error
            finally:
                self._jobs.task_done()

    def submit(
        self,
        fn: Callable[[SessionStore], object],
        on_done: Callable[[BaseException | None], None] | None = None,
    ) -> None:
        """Queue ``fn(store)``; ``on_done(error_or_None)`` after it (writer thread)."""
        if self._closed:
            raise StoreError(f"the writer of {self.store.path} is closed")
        self._jobs.put((fn, on_done))

    def raise_pending(self) -> None:
        """Raise (once) the first error of a job submitted without ``on_done``."""
        if self._error is None:
            return
        with self._error_lock:
            error, self._error = self._error, None
        if error is None:
            return
        if isinstance(error, IcenavError):
            raise error
        raise StoreError(f"cannot write session file {self.store.path}: {error}") from error

    def drain(self) -> None:
        """Wait until every job submitted so far has run (blocks on the queue, no polling)."""
        self._jobs.join()

    def flush(self) -> None:
        """Wait for every job, then raise the first pending error, if any."""
        self.drain()
        self.raise_pending()

    @property
    def pending_jobs(self) -> int:
        """Jobs queued and not yet done (approximate: another thread may be adding)."""
        return self._jobs.unfinished_tasks

    def close(self) -> None:
        """Run what is queued, stop the thread; the store stays open (close it after)."""
        if self._closed:
            return
        self._closed = True
        self._jobs.put(None)
        self._thread.join()
