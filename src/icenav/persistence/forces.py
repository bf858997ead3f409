"""The operator's contact forces in the session file (:class:`icenav.recovery.force.ForceRecord`):
restored on reopen, so a return after a crash-restart is checked against the same trace.

Three tables, added to a session file when it is first opened for writing by an icenav that
has them (the layout stays version 1: older files gain them, older icenav ignore them)::

    forces(vertex INTEGER PRIMARY KEY, force_n REAL)       Eq. (F1): largest force per vertex
    tip_forces(seq INTEGER PRIMARY KEY, x, y, z, ux, uy, uz, force_n)
                                                           Eq. (F2): tip (mm), axis, force (N)
    rest_tip(id INTEGER PRIMARY KEY CHECK (id = 0), x, y, z, q1, q2, q3, q4)
                                                           Eq. (F5): where the operator left
                                                           the tip (mm) and the motors; no row:
                                                           no rest pose

A restarted session keeps the rest pose only while the robot's motors stand where the
operator left them (:meth:`ForceRecord.keep_rest_if_at`, called by the controller when it
starts), so a return after a crash still refuses to start into a patient who moved meanwhile.

The tables are committed when created; rows land in the store's current batch (committed
with the roadmap's rows). After a lost batch (disk full) the next sync writes the tip
readings and the rest pose again from what the file holds; the per-vertex forces of the lost
batch stay lost (a return then takes the nearest recorded value along its path).
"""

from __future__ import annotations

import sqlite3

import numpy as np

from icenav.errors import FileFormatError
from icenav.persistence.store import SessionStore
from icenav.recovery.force import ForceRecord

__all__ = ["ForceSync", "Rest", "load_forces", "rest_snapshot"]

_TABLES = (
    "CREATE TABLE IF NOT EXISTS forces(vertex INTEGER PRIMARY KEY, force_n REAL NOT NULL)",
    "CREATE TABLE IF NOT EXISTS tip_forces(seq INTEGER PRIMARY KEY, x REAL NOT NULL, "
    "y REAL NOT NULL, z REAL NOT NULL, ux REAL NOT NULL, uy REAL NOT NULL, uz REAL NOT NULL, "
    "force_n REAL NOT NULL)",
    "CREATE TABLE IF NOT EXISTS rest_tip(id INTEGER PRIMARY KEY CHECK (id = 0), "
    "x REAL NOT NULL, y REAL NOT NULL, z REAL NOT NULL, q1 REAL NOT NULL, q2 REAL NOT NULL, "
    "q3 REAL NOT NULL, q4 REAL NOT NULL)",
)

Rest = tuple[tuple[float, ...], tuple[float, ...]] | None
"""A rest pose as the store writes it: (tip (3,) mm, motor state (4,)), or None."""


def load_forces(store: SessionStore) -> ForceRecord:
    """The force record stored in ``store`` (empty for a file without one)."""
    db = store._db  # noqa: SLF001 - the store's connection, on the thread that owns it
    try:
        names = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if not {"forces", "tip_forces"} <= names:
            return ForceRecord()
        vr = db.execute("SELECT vertex, force_n FROM forces ORDER BY vertex").fetchall()
        tr = db.execute(
            "SELECT x, y, z, ux, uy, uz, force_n FROM tip_forces ORDER BY seq"
        ).fetchall()
        rr = (
            db.execute("SELECT x, y, z, q1, q2, q3, q4 FROM rest_tip").fetchall()
            if "rest_tip" in names
            else []
        )
    except sqlite3.Error as exc:
        raise FileFormatError(f"{store.path}: cannot read the stored forces: {exc}") from exc
    v = np.array(vr, np.float64).reshape(-1, 2)
    t = np.array(tr, np.float64).reshape(-1, 7)
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(t))) or (len(v) and v[:, 1].min() < 0):
        raise FileFormatError(f"{store.path}: a stored contact force is not finite and >= 0 N")
    rest = None
    if rr:
        r = np.array(rr[0], np.float64)
        if not np.all(np.isfinite(r)):
            raise FileFormatError(
                f"{store.path}: the stored rest pose (table rest_tip) is not finite"
            )
        rest = (r[:3], r[3:])
    return ForceRecord.from_rows(v, t, rest=rest)


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
        # committed at once: a batch rolled back later (a full disk) must not take the
        # tables with it, or every later write of a force row would fail
        store.commit()
        self._synced_tips = int(db.execute("SELECT COUNT(*) FROM tip_forces").fetchone()[0])

    def _rest_on_disk(self) -> Rest:
        """The rest row the file holds now (in the current batch), or None."""
        row = self.store._db.execute(  # noqa: SLF001
            "SELECT x, y, z, q1, q2, q3, q4 FROM rest_tip"
        ).fetchone()
        return None if row is None else (tuple(row[:3]), tuple(row[3:]))

    def sync(
        self,
        record: ForceRecord,
        vertex_rows: list[tuple[int, float]],
        n_tips: int,
        rest: Rest,
    ) -> None:
        """Queue ``vertex_rows`` (taken on the control thread,
        :meth:`ForceRecord.take_vertex_rows`), the tip readings below ``n_tips`` and the rest
        pose taken with them (:func:`rest_snapshot`; None: there is none). What
        the file holds is read first, so rows a rolled-back batch (a full disk) took with it
        are written again rather than left as a gap."""
        st = self.store
        db = st._db  # noqa: SLF001
        on_disk = int(db.execute("SELECT COALESCE(MAX(seq) + 1, 0) FROM tip_forces").fetchone()[0])
        self._synced_tips = min(self._synced_tips, on_disk)
        if self._rest_on_disk() != rest:
            st._exec_many("DELETE FROM rest_tip", [()])  # noqa: SLF001
            if rest is not None:
                st._exec_many(  # noqa: SLF001
                    "INSERT INTO rest_tip VALUES (0, ?, ?, ?, ?, ?, ?, ?)",
                    [(*rest[0], *rest[1])],
                )
            st._queue(1)  # noqa: SLF001
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


def rest_snapshot(record: ForceRecord) -> Rest:
    """``record``'s rest pose, taken on the control thread (the thread that changes it) for
    :meth:`ForceSync.sync`: tip (3,) mm and motor state (4,), or None when there is none (or
    it has no motor state, which a restart could not check)."""
    tip, q = record.rest_tip, record.rest_q
    return None if tip is None or q is None else (tuple(tip.tolist()), tuple(q.tolist()))
