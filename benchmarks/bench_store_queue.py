"""The session writer under a loop faster than the disk: queue depth and "view saved" delay.

A scripted operator runs ``N_CYCLES`` control cycles as fast as the loop goes (a random walk
recorded in the roadmap, a command logged every 5 cycles, a view saved every 10,000 cycles)
into a threaded :class:`icenav.persistence.recorder.StoreRecorder`, whose writer queue holds
at most one sync and one log job. Baseline in the same run: the same events with one writer
job per sync and per log row (what the recorder did before: the queue grows without bound
and a view waits behind every job). Reported: the largest queue depth and the mean time from
"save view" to the view committed.
"""

from __future__ import annotations

import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import Result
from icenav.persistence.recorder import StoreRecorder
from icenav.persistence.store import SessionStore, StoreWriter
from icenav.recovery.roadmap import Roadmap, RoadmapConfig

N_CYCLES = 60_000


class _OneJobPerEvent:
    """The baseline: every sync and every log row is a writer job of its own."""

    def __init__(self, store: SessionStore, roadmap: Roadmap) -> None:
        self.roadmap = roadmap
        self.writer = StoreWriter(store)
        self._n = 0

    def __call__(self, event: str, payload: dict[str, Any]) -> object:
        rm = self.roadmap
        if event == "state":
            self._n += 1
            if self._n % 10 == 0:
                upto = rm.counts()
                self.writer.submit(lambda st: st.sync_roadmap(rm, upto))
        elif event == "view_saved":
            view, upto = payload["view"], rm.counts()
            self.writer.submit(lambda st: st.add_view(view, rm, upto), payload["on_durable"])
        else:
            t, data = time.time(), {k: str(v) for k, v in payload.items()}
            self.writer.submit(lambda st: st.log_event(t, event, data))
        return None

    def close(self) -> None:
        self.writer.close()


def _run(bounded: bool) -> tuple[int, float]:
    """(largest queue depth, mean seconds from saving a view to its commit)."""
    folder = Path(tempfile.mkdtemp(prefix="icenav-bench-queue-"))
    cfg = RoadmapConfig(epsilon=1.0)
    store = SessionStore(folder / "s.icenav", config=cfg, new_session=True)
    rm = Roadmap(config=cfg)
    rec: Any = (
        StoreRecorder(store, rm, sync_every=10, threaded=True)
        if bounded
        else _OneJobPerEvent(store, rm)
    )
    rng = np.random.default_rng(0)
    q = np.zeros(4)
    delays: list[float] = []
    done = threading.Event()
    depth = 0
    for i in range(N_CYCLES):
        q = q + rng.normal(0.0, 0.05, 4) * [0.02, 0.02, 0.02, 1.0]
        rm.add(q)
        rec("state", {"q": q})
        if i % 5 == 0:
            rec("command", {"i": i})
        depth = max(depth, rec.writer.pending_jobs)
        if i % 10_000 == 9_999 and rm.recording:
            view, t0 = rm.make_view(f"v{i}", created_s=float(i)), time.perf_counter()

            def on_durable(error: BaseException | None, t0: float = t0) -> None:
                delays.append(time.perf_counter() - t0)
                done.set()

            rec("view_saved", {"view": view, "on_durable": on_durable})
    rec.close()
    store.close()
    return depth, float(np.mean(delays)) if delays else float("nan")


def main() -> list[Result]:
    depth, delay = _run(bounded=True)
    depth0, delay0 = _run(bounded=False)
    return [
        Result(
            "writer queue, largest depth",
            depth,
            "jobs",
            depth0,
            "one job per event",
            "bounded (<= 4)",
            depth <= 4,
        ),  # fmt: skip
        Result(
            "view saved -> committed, mean", delay * 1e3, "ms", delay0 * 1e3, "one job per event"
        ),  # fmt: skip
    ]
