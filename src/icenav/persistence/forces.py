"""The operator's contact forces in the session file (:class:`icenav.recovery.force.ForceRecord`):
restored on reopen, so a return after a crash-restart is checked against the same trace.

Two tables, added to a session file when it is first opened for writing by an icenav that
has them (the layout stays version 1: older files gain them, older icenav ignore them)::

    forces(vertex INTEGER PRIMARY KEY, force_n REAL)       Eq. (F1): largest force per vertex
    tip_forces(seq INTEGER PRIMARY KEY, x, y, z, ux, uy, uz, force_n)
                                                           Eq. (F2): tip (mm), axis, force (N)

Rows land in the store's current batch (committed with the roadmap's rows). A lost batch
(disk full) loses its force rows; the tip rows are rewritten from the count on disk.
"""

from __future__ import annotations

import sqlite3

import numpy as np

from icenav.errors import FileFormatError
from icenav.persistence.store import SessionStore
from icenav.recovery.force import ForceRecord

__all__ = ["ForceSync", "load_forces"]

_TABLES = (
    "CREATE TABLE IF NOT EXISTS forces(vertex INTEGER PRIMARY KEY, force_n REAL NOT NULL)",
    "CREATE TABLE IF NOT EXISTS tip_forces(seq INTEGER PRIMARY KEY, x REAL NOT NULL, "
    "y REAL NOT NULL, z REAL NOT NULL, ux REAL NOT NULL, uy REAL NOT NULL, uz REAL NOT NULL, "
    "force_n REAL NOT NULL)",
)


def _has_tables(store: SessionStore) -> bool:
    db = store._db  # noqa: SLF001 - the store's connection, on the thread that owns it
    names = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    return {"forces", "tip_forces"} <= names


def load_forces(store: SessionStore) -> ForceRecord:
    """The force record stored in ``store`` (empty for a file without one)."""
    try:
        if not _has_tables(store):
            return ForceRecord()
        db = store._db  # noqa: SLF001
        vr = db.execute("SELECT vertex, force_n FROM forces ORDER BY vertex").fetchall()
        tr = db.execute(
            "SELECT x, y, z, ux, uy, uz, force_n FROM tip_forces ORDER BY seq"
        ).fetchall()
    except sqlite3.Error as exc:
        raise FileFormatError(f"{store.path}: cannot read the stored forces: {exc}") from exc
    v = np.array(vr, np.float64).reshape(-1, 2)
    t = np.array(tr, np.float64).reshape(-1, 7)
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(t))) or (len(v) and v[:, 1].min() < 0):
        raise FileFormatError(f"{store.path}: a stored contact force is not finite and >= 0 N")
    return ForceRecord.from_rows(v, t)


class ForceSync:
    """Writes a :class:`ForceRecord`'s new rows into a store (on the store's writer thread).

    Parameters
    ----------
    store : SessionStore
        Opened for writing; the tables are created here if missing.
    """

    def __init__(self, store: SessionStore) -> None:
        self.store = store
        db = store._db  # noqa: SLF001
        for sql in _TABLES:
            db.execute(sql)
        self._synced_tips = int(db.execute("SELECT COUNT(*) FROM tip_forces").fetchone()[0])

    def sync(self, record: ForceRecord, vertex_rows: list[tuple[int, float]], n_tips: int) -> None:
        """Queue ``vertex_rows`` (taken on the control thread,
        :meth:`ForceRecord.take_vertex_rows`) and the tip readings below ``n_tips``."""
        st = self.store
        if vertex_rows:
            st._exec_many("INSERT OR REPLACE INTO forces VALUES (?, ?)", vertex_rows)  # noqa: SLF001
            st._queue(len(vertex_rows))  # noqa: SLF001
        if n_tips > self._synced_tips:
            rows = record.tip_rows(self._synced_tips, n_tips)
            seq0 = self._synced_tips
            st._exec_many(  # noqa: SLF001
                "INSERT OR REPLACE INTO tip_forces VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [(seq0 + i, *r) for i, r in enumerate(rows)],
            )
            st._queue(len(rows))  # noqa: SLF001
            self._synced_tips = n_tips
