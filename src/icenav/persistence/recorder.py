"""The session recorder: what the controller records goes into its :class:`SessionStore`.

The controller calls the recorder with ``(event, payload)`` from its loop thread (see
:data:`EVENTS`); the recorder writes on a thread of its own (``threaded=True``), so no
insert, commit or fsync runs on the control thread.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from icenav.persistence.store import SessionStore, StoreWriter
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
    """

    def __init__(
        self, store: SessionStore, roadmap: Roadmap, sync_every: int = 10, threaded: bool = False
    ):
        self.store = store
        self.roadmap = roadmap
        self.sync_every = max(1, int(sync_every))
        self._n = 0
        self.writer: StoreWriter | None = StoreWriter(store) if threaded else None
        """The writer thread (None when not threaded)."""

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
                upto = roadmap.counts()
                self._run(lambda st: st.sync_roadmap(roadmap, upto))
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
            t = time.time()
            data = {k: str(v) for k, v in payload.items()}
            self._run(lambda st: st.log_event(t, event, data))
        return None

    def drain(self) -> None:
        """Wait until the writer has run every job queued so far (no-op when not threaded);
        errors stay pending for the next call or :meth:`flush`."""
        if self.writer is not None:
            self.writer.drain()

    def flush(self) -> None:
        """Sync and commit everything pending (waits for the writer); raises a pending
        write error."""
        roadmap = self.roadmap

        def sync(st: SessionStore) -> None:
            st.sync_roadmap(roadmap)
            st.commit()

        self._run(sync, wait=True)

    def close(self) -> None:
        """Flush and stop the writer thread (the store stays open)."""
        try:
            self.flush()
        finally:
            if self.writer is not None:
                self.writer.close()
