"""The session recorder: what the controller records goes into its :class:`SessionStore`.

The controller calls the recorder with ``(event, payload)`` from its loop thread (see
:data:`EVENTS`); the recorder writes on a thread of its own (``threaded=True``), so no
insert, commit or fsync runs on the control thread.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from icenav.persistence.forces import ForceSync, Rest, rest_snapshot
from icenav.persistence.store import SessionStore, StoreWriter
from icenav.recovery.force import ForceRecord
from icenav.recovery.roadmap import Roadmap
from icenav.recovery.views import View

__all__ = ["EVENTS", "StoreRecorder"]

EVENTS = ("state", "view_saved", "view_renamed", "view_deleted", "event", "command", "calibration")
"""The events a controller records: a control cycle (the roadmap is synced every
``sync_every``), a view saved / renamed / deleted, and rows of the event log (a text event, a
command with its outcome, a calibration installed: with a ``document`` callable in its
payload, what it returns (unless None) is stored as the session's calibration in use)."""


class StoreRecorder:
    """Records a controller's roadmap, views and events into a :class:`SessionStore`.

    The roadmap is synced incrementally (new vertices, edges and trace since the last sync)
    and committed in batches by the store; a saved view is committed at once, so a view is
    never lost to a crash. Commands and their outcomes (event "command", from
    :mod:`icenav.control.commands`), mode changes, faults and calibrations are rows of the
    session's event log (``events`` table: time, kind, data as JSON).

    With ``threaded=True`` every write runs on a :class:`StoreWriter` thread: a control
    cycle only takes the roadmap's counts (``Roadmap.counts()``, O(1)) and queues a job, so
    no insert, commit or fsync runs on the control thread. A saved view whose payload has
    an ``"on_durable"`` callback returns ``"pending"``, and the callback gets ``None`` once
    the view is committed (or the error), on the writer thread: the controller tells the
    operator "saved" only then. Without the callback the call waits for the commit. A
    failed batch is raised by the next call on the control thread (the controller reports
    it), and the store rewrites the lost rows at the next sync.

    Parameters
    ----------
    store : SessionStore
        The session file.
    roadmap : Roadmap
        The controller's roadmap.
    sync_every : int
        Sync the roadmap every this many "state" events (control cycles).
    threaded : bool
        Write on a thread of its own (see above); False: on the caller's thread.
    forces : ForceRecord, optional
        The operator's contact forces (:mod:`icenav.recovery.force`), synced with the
        roadmap (:mod:`icenav.persistence.forces`); None: none recorded.
    """

    def __init__(
        self,
        store: SessionStore,
        roadmap: Roadmap,
        sync_every: int = 10,
        threaded: bool = False,
        forces: ForceRecord | None = None,
    ):
        self.store = store
        self.roadmap = roadmap
        self.forces = forces
        self._force_sync = ForceSync(store) if forces is not None else None
        self.sync_every = max(1, int(sync_every))
        self._n = 0
        self.writer: StoreWriter | None = StoreWriter(store) if threaded else None
        """The writer thread (None when not threaded)."""
        self._lock = threading.Lock()
        self._sync_queued = False
        self._latest: tuple[tuple[int, int, int], int, Rest] = (
            (0, 0, 0),
            0,
            None,
        )
        self._force_rows: list[tuple[int, float]] = []
        self._log_rows: list[tuple[float, str, dict[str, str]]] = []
        self._log_queued = False
        self.coalesced = 0
        """Syncs and log rows that joined a job already queued instead of queuing one."""

    def _run(self, fn: Callable[[SessionStore], object], wait: bool = False) -> None:
        if self.writer is None:
            fn(self.store)
        else:
            self.writer.submit(fn)
            if wait:
                self.writer.flush()

    def __call__(self, event: str, payload: dict[str, Any]) -> object:
        """Record ``event`` (see :data:`EVENTS`); "pending" for a view whose
        ``on_durable`` callback will be called once it is committed."""
        roadmap = self.roadmap
        if self.writer is not None and event != "view_saved":
            # a failed write reaches the controller here (a view reports its own outcome,
            # and is tried even after an earlier batch failed)
            self.writer.raise_pending()
        if event == "state":
            self._n += 1
            if self._n % self.sync_every == 0:
                self._submit_sync()
        elif event == "view_saved":
            view: View = payload["view"]
            upto = roadmap.counts()
            on_durable = payload.get("on_durable")
            if self.writer is not None and on_durable is not None:
                self.writer.submit(lambda st: st.add_view(view, roadmap, upto), on_durable)
                return "pending"
            self._run(lambda st: st.add_view(view, roadmap, upto), wait=True)
        elif event == "view_deleted":
            name = str(payload["name"])
            self._run(lambda st: st.delete_view(name))
        elif event == "view_renamed":
            old, new = str(payload["old"]), str(payload["new"])
            self._run(lambda st: st.rename_view(old, new))
        elif event == "calibration" and callable(payload.get("document")):
            # a calibration installed: a row of the event log, and its calibration-file
            # document (made here, on the writer thread) as the session's calibration in use
            t = time.time()
            make = payload["document"]
            kind = str(payload.get("kind", ""))
            data = {k: str(v) for k, v in payload.items() if k != "document"}

            def write(st: SessionStore) -> None:
                st.log_event(t, event, data)
                document = make()
                if document is not None:
                    st.save_calibration_document(kind, document, t)

            self._run(write)
        else:  # "event", "command", "calibration": rows of the session's event log
            row = (time.time(), event, {k: str(v) for k, v in payload.items()})
            if self.writer is None:
                self.store.log_event(*row)
                return None
            with self._lock:
                self._log_rows.append(row)
                if self._log_queued:
                    self.coalesced += 1
                    return None
                self._log_queued = True
            self.writer.submit(self._write_log)
        return None

    # Back-pressure without blocking (the writer queue stays bounded): a loop faster than
    # the disk (a scripted operator) would queue a sync every ``sync_every`` cycles and a log
    # row per command, and a saved view would wait behind all of them. Instead at most one
    # sync job and one log job wait in the queue: a sync asked while one waits only moves
    # the counts that job will write up to (the rows below a count never change, so the
    # later sync writes everything the earlier one would have); log rows asked while a log
    # job waits join it. Nothing is dropped and the control thread never waits.

    def _submit_sync(self) -> None:
        """Sync the roadmap's and the forces' new rows (counted here, on the control
        thread), joining a sync job already queued."""
        upto = self.roadmap.counts()
        forces = self.forces
        rows = forces.take_vertex_rows() if forces is not None else []
        n_tips = forces.n_tip_rows if forces is not None else 0
        rest = rest_snapshot(forces) if forces is not None else None
        with self._lock:
            self._latest = (upto, n_tips, rest)
            self._force_rows.extend(rows)
            if self._sync_queued:
                self.coalesced += 1
                return
            self._sync_queued = self.writer is not None
        self._run(self._write_sync)

    def _write_sync(self, st: SessionStore) -> None:
        with self._lock:
            (upto, n_tips, rest), rows = self._latest, self._force_rows
            self._force_rows = []
            self._sync_queued = False
        if self._force_sync is not None and self.forces is not None:
            self._force_sync.sync(self.forces, rows, n_tips, rest)
        st.sync_roadmap(self.roadmap, upto)

    def _write_log(self, st: SessionStore) -> None:
        with self._lock:
            rows, self._log_rows = self._log_rows, []
            self._log_queued = False
        for row in rows:
            st.log_event(*row)

    def drain(self) -> None:
        """Wait until the writer has run every job queued so far (no-op when not threaded);
        errors stay pending for the next call or :meth:`flush`."""
        if self.writer is not None:
            self.writer.drain()

    def flush(self) -> None:
        """Sync and commit everything pending (waits for the writer); raises a pending
        write error."""
        self._submit_sync()
        self._run(lambda st: st.commit(), wait=True)

    def close(self) -> None:
        """Flush and stop the writer thread (the store stays open)."""
        try:
            self.flush()
        finally:
            if self.writer is not None:
                self.writer.close()
