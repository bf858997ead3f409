"""The session recorder: a bounded writer queue under a loop faster than the disk, nothing
lost; the operator's forces stored beside the roadmap."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from icenav.persistence.forces import ForceSync, load_forces, rest_snapshot
from icenav.persistence.recorder import StoreRecorder
from icenav.persistence.store import SessionStore
from icenav.recovery.force import ForceRecord
from icenav.recovery.roadmap import Roadmap


def test_a_fast_loop_queues_at_most_one_sync_and_one_log_job_and_loses_nothing(
    tmp_path: Path,
) -> None:
    store = SessionStore(tmp_path / "s.icenav", new_session=True)
    rm = Roadmap(epsilon=1.0)
    forces = ForceRecord()
    rec = StoreRecorder(store, rm, sync_every=2, threaded=True, forces=forces)
    assert rec.writer is not None
    release, started = threading.Event(), threading.Event()

    def blocker(_: SessionStore) -> None:  # the disk is slow: the writer is held here
        started.set()
        release.wait()

    rec.writer.submit(blocker)
    started.wait()
    rng = np.random.default_rng(3)
    q = np.zeros(4)
    for i in range(3000):  # a scripted operator, far faster than the writer
        q = q + rng.normal(0.0, 0.3, 4) * [0.01, 0.01, 0.01, 1.0]
        rm.add(q)
        forces.record(rm.current_vertex, 0.001 * i, None)
        rec("state", {"q": q})
        rec("command", {"i": i})
        assert rec.writer.pending_jobs <= 3  # the blocker, one sync, one log job
    assert rec.coalesced > 4000
    release.set()
    rec.close()
    events = [e.data["i"] for e in store.events("command")]
    back, stored = store.load_roadmap(), load_forces(store)
    store.close()
    assert events == [str(i) for i in range(3000)]  # every row, in order
    np.testing.assert_array_equal(back.vertices(), rm.vertices())
    np.testing.assert_array_equal(back.trace(), rm.trace())
    ids = np.arange(rm.n_vertices)
    np.testing.assert_array_equal(stored.forces.at(ids), forces.forces.at(ids))


def test_the_force_rows_survive_a_batch_rolled_back_by_a_full_disk(tmp_path: Path) -> None:
    """The force tables are committed when the recorder opens a session, and a batch rolled
    back later (what a full disk does: ROLLBACK, BEGIN) loses no tip reading and no rest
    pose for good: the next sync reads what the file holds and writes them again."""
    with SessionStore(tmp_path / "s.icenav", new_session=True) as store:
        forces = ForceRecord()
        sync = ForceSync(store)
        store._restart_batch()  # noqa: SLF001 - a full disk before anything was written
        pose = np.eye(4)
        pose[:3, 3] = [1.0, 2.0, 40.0]
        forces.note_motion(pose, operator=True, q=[0.1, 0.0, 0.2, 5.0])
        forces.record(0, 0.4, pose)
        sync.sync(forces, [], forces.n_tip_rows, rest_snapshot(forces))
        store._restart_batch()  # noqa: SLF001 - the batch with those rows is lost
        sync.sync(forces, [], forces.n_tip_rows, rest_snapshot(forces))
        store.commit()
        back = load_forces(store)
    np.testing.assert_array_equal(back.rest_tip, [1.0, 2.0, 40.0])
    np.testing.assert_array_equal(back.rest_q, [0.1, 0.0, 0.2, 5.0])
    assert back.tips.n_samples == 1
