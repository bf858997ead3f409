"""SessionStore: round trip, batching, kill -9 recovery, refused files, write failures."""

from __future__ import annotations

import math
import signal
import sqlite3
import subprocess
import sys
import textwrap
from contextlib import closing
from pathlib import Path

import numpy as np
import pytest

from icenav.errors import FileFormatError, StoreError, UnsupportedVersionError
from icenav.geometry.kinematics import forward
from icenav.persistence.store import SCHEMA_VERSION, SessionStore, StoreWriter
from icenav.recovery.roadmap import Roadmap, RoadmapConfig, RoadmapMetric

DEG = math.pi / 180


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def walk(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steps = rng.normal(0, 1, (n, 4)) * np.array([0.3 * DEG] * 3 + [0.3])
    return np.clip(np.cumsum(steps, axis=0), [-1.5, -1.5, -6, -50], [1.5, 1.5, 6, 50])


def test_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "session.icenav"
    cfg = RoadmapConfig(epsilon=1.5, metric=RoadmapMetric(roll_weight=0.5))
    rm = Roadmap(config=cfg)
    views = []
    with SessionStore(path, config=cfg, batch_states=100) as store:
        for i, q in enumerate(walk(0, 3000)):
            rm.add(q)
            store.sync_roadmap(rm)
            if i in (500, 1500, 2500):
                em = forward(q).copy()
                em[:3, 3] += 0.3  # the tracked pose: not the model's
                view = rm.make_view(
                    f"view {i}",
                    created_s=i / 100,
                    tip2base=forward(q),
                    thumbnail=np.arange(48, dtype=np.uint8).reshape(6, 8),
                    notes="n",
                    em_tip2base=em if i != 500 else None,
                )
                store.add_view(view, rm)
                views.append(view)
        store.rename_view("view 1500", "mitral")
        store.delete_view("view 2500")
        store.save_calibration("F", "dense", {"grid_deg": 10, "values": [1.0, 2.0]}, 3.0)
        store.log_event(1.0, "input", {"button": "A"})
        store.log_event(2.0, "fault", {"axis": "phi1", "code": 0x2310})
        store.sync_roadmap(rm)
    with SessionStore(path) as store:
        assert store.config == cfg
        back = store.load_roadmap()
        lib = store.load_views()
        assert [e.kind for e in store.events()] == ["input", "fault"]
        assert store.events("fault")[0].data == {"axis": "phi1", "code": 0x2310}
        assert store.calibrations()["F"] == ("dense", {"grid_deg": 10, "values": [1.0, 2.0]}, 3.0)
    np.testing.assert_array_equal(back.vertices(), rm.vertices())
    uv0, w0 = rm.edges()
    uv1, w1 = back.edges()
    assert {tuple(e) for e in uv0.tolist()} == {tuple(e) for e in uv1.tolist()}
    np.testing.assert_array_equal(back.trace(), rm.trace())
    assert lib.names() == ["view 500", "mitral"]
    assert lib.get("view 500").em_tip2base is None and lib.get("mitral").em_tip2base is not None
    for saved, loaded in zip((views[0], views[1]), lib.list(), strict=True):
        np.testing.assert_array_equal(saved.q, loaded.q)
        np.testing.assert_array_equal(saved.tip2base, loaded.tip2base)
        np.testing.assert_array_equal(saved.thumbnail, loaded.thumbnail)
        np.testing.assert_array_equal(saved.em_tip2base, loaded.em_tip2base)  # renamed too
        assert (saved.vertex, saved.arrival_direction, saved.approach, saved.created_s) == (
            loaded.vertex,
            loaded.arrival_direction,
            loaded.approach,
            loaded.created_s,
        )
    # the restored roadmap plans the same returns
    for view in lib:
        np.testing.assert_array_equal(
            back.plan(back.current_state, view, approach=True),
            rm.plan(back.current_state, view, approach=True),
        )


def test_batches_commit_by_count_and_by_time(tmp_path: Path) -> None:
    path = tmp_path / "s.icenav"
    clock = FakeClock()
    store = SessionStore(path, batch_states=50, batch_seconds=2.0, clock=clock)
    rm = Roadmap()

    def committed_vertices() -> int:
        with closing(sqlite3.connect(path)) as other:  # another reader: committed rows only
            return int(other.execute("SELECT COUNT(*) FROM vertices").fetchone()[0])

    rm.add([0, 0, 0, 0.0])
    assert store.sync_roadmap(rm) is False and committed_vertices() == 0
    clock.t = 2.5
    rm.add([0, 0, 0, 0.5])
    assert store.sync_roadmap(rm) is True and committed_vertices() == 2
    for v in np.arange(1.0, 60.0, 0.5):
        rm.add([0, 0, 0, v])
    assert store.sync_roadmap(rm) is True and committed_vertices() == rm.n_vertices
    store.close()


WRITER = textwrap.dedent(
    """
    import sys
    import numpy as np
    from icenav.recovery.roadmap import Roadmap
    from icenav.persistence.store import SessionStore

    path = sys.argv[1]
    rng = np.random.default_rng(3)
    store = SessionStore(path, batch_states=10**9, batch_seconds=1e9)
    rm = Roadmap()
    q = np.zeros(4)
    i = 0
    while True:
        q = np.clip(q + rng.normal(0, 1, 4) * [0.005, 0.005, 0.005, 0.3], -1.4, 1.4)
        rm.add(q)
        store.sync_roadmap(rm)
        i += 1
        if i % 500 == 0:
            view = rm.make_view(f"v{i}", created_s=float(i))
            store.add_view(view, rm)
            print("VIEW", view.name, view.vertex, flush=True)
        elif i % 97 == 0:
            store.commit()
            print("COMMIT", rm.n_vertices, rm.n_edges, rm.n_trace, flush=True)
    """
)


def test_kill_9_loses_no_view_and_no_committed_batch(tmp_path: Path) -> None:
    path = tmp_path / "crash.icenav"
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    proc = subprocess.Popen(
        [sys.executable, str(script), str(path)], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None
    views: dict[str, int] = {}
    committed = (0, 0, 0)
    try:
        while len(views) < 4:
            line = proc.stdout.readline()
            assert line, "the writer died early"
            parts = line.split()
            if parts[0] == "VIEW":
                views[parts[1]] = int(parts[2])
            else:
                committed = (int(parts[1]), int(parts[2]), int(parts[3]))
    finally:
        proc.send_signal(signal.SIGKILL)  # mid-write: it never stops writing
        proc.wait()
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    with SessionStore(path) as store:
        rm = store.load_roadmap()
        lib = store.load_views()
    assert set(views) <= set(lib.names())
    for view in lib:
        np.testing.assert_array_equal(rm.vertices()[view.vertex], view.q)
        assert view.vertex == views.get(view.name, view.vertex)
    assert rm.n_vertices >= committed[0]
    assert rm.n_edges >= committed[1] and rm.n_trace >= committed[2]
    uv, _ = rm.edges()
    assert uv.max() < rm.n_vertices and rm.trace().max() < rm.n_vertices
    for view in lib:  # every view is reachable on the restored roadmap
        path_back = rm.plan(rm.current_state, view)
        np.testing.assert_array_equal(path_back[-1], view.q)


def test_future_version_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "future.icenav"
    SessionStore(path).close()
    with closing(sqlite3.connect(path)) as db:
        db.execute(f"PRAGMA user_version={SCHEMA_VERSION + 1}")
    with pytest.raises(UnsupportedVersionError, match="newer than this icenav"):
        SessionStore(path)


def test_corrupt_and_foreign_files_are_refused(tmp_path: Path) -> None:
    junk = tmp_path / "junk.icenav"
    junk.write_bytes(np.random.default_rng(0).bytes(8192))
    with pytest.raises(FileFormatError, match="not a readable icenav session"):
        SessionStore(junk)
    assert junk.read_bytes()[:16] != b"SQLite format 3\x00"  # untouched
    foreign = tmp_path / "other.sqlite"
    with closing(sqlite3.connect(foreign)) as db:
        db.execute("CREATE TABLE t(x)")
        db.commit()
    with pytest.raises(FileFormatError, match="not an icenav session"):
        SessionStore(foreign)
    # a real session with a damaged page
    good = tmp_path / "damaged.icenav"
    with SessionStore(good, batch_states=10) as store:
        rm = Roadmap()
        for q in walk(1, 3000):
            rm.add(q)
        store.sync_roadmap(rm)
    data = bytearray(good.read_bytes())
    assert len(data) > 20 * 4096
    data[8 * 4096 : 12 * 4096] = b"\xa5" * (4 * 4096)
    good.write_bytes(bytes(data))
    with pytest.raises(FileFormatError, match="corrupt"):
        SessionStore(good)


def test_read_only_and_full_disk_give_store_errors(tmp_path: Path) -> None:
    path = tmp_path / "s.icenav"
    rm = Roadmap()
    for q in walk(2, 200):
        rm.add(q)
    with SessionStore(path) as store:
        store.sync_roadmap(rm)
    ro = SessionStore(path, read_only=True)
    assert ro.load_roadmap().n_vertices == rm.n_vertices
    with pytest.raises(StoreError, match="read-only"):
        ro.log_event(0.0, "fault", {})
    ro._db.close()
    store = SessionStore(path, batch_states=10**9)
    pages = store._db.execute("PRAGMA page_count").fetchone()[0]
    store._db.execute(f"PRAGMA max_page_count={pages + 1}")  # simulate a full disk
    for q in walk(3, 20000):
        rm.add(q)
    with pytest.raises(StoreError, match="full"):
        store.sync_roadmap(rm)
        store.commit()
    store._db.close()
    with pytest.raises(StoreError, match="does not exist"):
        SessionStore(tmp_path / "missing.icenav", read_only=True)


# --- the writer thread (issue 9: no commit or fsync on the control thread) ----------------


def test_writer_runs_jobs_in_order_and_reports_errors(tmp_path: Path) -> None:
    store = SessionStore(tmp_path / "s.icenav")
    writer = StoreWriter(store)
    order: list[int] = []
    outcomes: list[BaseException | None] = []
    for i in range(50):
        writer.submit(lambda st, i=i: order.append(i))
    writer.submit(lambda st: st.log_event(1.0, "input", {"k": 1}), outcomes.append)

    def boom(st: SessionStore) -> None:
        raise StoreError("disk on fire")

    writer.submit(boom, outcomes.append)  # reported to on_done, not kept
    writer.flush()
    assert order == list(range(50))
    assert outcomes[0] is None and isinstance(outcomes[1], StoreError)
    writer.submit(boom)  # no on_done: kept for the next raise_pending, raised once
    writer.drain()
    with pytest.raises(StoreError, match="disk on fire"):
        writer.raise_pending()
    writer.raise_pending()
    writer.submit(lambda st: (_ for _ in ()).throw(ValueError("odd")))
    with pytest.raises(StoreError, match="cannot write session file .*: odd"):
        writer.flush()
    writer.close()
    with pytest.raises(StoreError, match="writer of .* is closed"):
        writer.submit(lambda st: None)
    assert [e.kind for e in store.events()] == ["input"]
    store.close()


@pytest.mark.parametrize("seed", range(2))
def test_threaded_recorder_stores_exactly_what_the_roadmap_holds(tmp_path: Path, seed: int) -> None:
    from icenav.apps.wiring import StoreRecorder

    path = tmp_path / "s.icenav"
    cfg = RoadmapConfig(epsilon=1.0, max_vertices=1000, tree_cache=5)
    store = SessionStore(path, config=cfg, batch_states=64)
    rm = Roadmap(config=cfg, capacity=16)  # grows (reallocates) while the writer reads
    recorder = StoreRecorder(store, rm, sync_every=3, threaded=True)
    durable: list[tuple[str, bool]] = []
    views = []
    for i, q in enumerate(walk(seed, 4000)):
        rm.add(q)
        recorder("state", {"q": q})
        if i % 1000 == 999 and rm.recording:
            view = rm.make_view(f"v{i}", created_s=float(i))
            views.append(view)

            def on_durable(error: BaseException | None, name: str = view.name) -> None:
                with closing(sqlite3.connect(path)) as other:  # committed rows only
                    rows = other.execute("SELECT name FROM views WHERE name=?", (name,))
                    durable.append((name, error is None and rows.fetchone() is not None))

            assert recorder("view_saved", {"view": view, "on_durable": on_durable}) == "pending"
    recorder.close()
    store.close()
    assert durable == [(v.name, True) for v in views]  # "done" meant on disk
    with SessionStore(path, read_only=True) as again:
        assert again.config == cfg  # the budget is part of the session
        back = again.load_roadmap()
        assert [v.name for v in again.load_views()] == [v.name for v in views]
    np.testing.assert_array_equal(back.vertices(), rm.vertices())
    np.testing.assert_array_equal(back.trace(), rm.trace())
    uv0, w0 = rm.edges()
    uv1, w1 = back.edges()
    assert sorted(zip(map(tuple, uv0.tolist()), w0.tolist(), strict=True)) == sorted(
        zip(map(tuple, uv1.tolist()), w1.tolist(), strict=True)
    )


# ------------------------------------------------------------------ one writer per file

HOLDER = textwrap.dedent(
    """
    import sys
    from icenav.persistence.store import SessionStore
    from icenav.recovery.roadmap import Roadmap

    store = SessionStore(sys.argv[1], batch_states=1)
    rm = Roadmap()
    for i in range(50):
        rm.add([0.0, 0.0, 0.0, 0.1 * i])
    store.add_view(rm.make_view("held", created_s=1.0), rm)
    print("HOLDING", flush=True)
    sys.stdin.read()  # hold the store until killed
    """
)


def _holder(path: Path) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()  # blocks until the child holds the store
    assert line.strip() == "HOLDING", proc.stderr.read() if proc.stderr else line
    return proc


def test_a_second_process_is_refused_names_the_holder_and_may_read(tmp_path: Path) -> None:
    import socket

    from icenav.errors import SessionLockedError

    path = tmp_path / "session.icenav"
    proc = _holder(path)
    try:
        with pytest.raises(SessionLockedError, match=str(path)) as info:
            SessionStore(path)
        assert f"pid {proc.pid} on host {socket.gethostname()}" in str(info.value)
        assert info.value.holder.startswith(f"pid {proc.pid}")
        with SessionStore(path, read_only=True) as reader:  # reading is allowed meanwhile
            assert reader.load_views().names() == ["held"]
    finally:
        proc.send_signal(signal.SIGKILL)  # kill -9: the OS releases the lock
        proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    with SessionStore(path) as store:  # the next open succeeds
        assert store._db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"  # noqa: SLF001
        assert store.load_views().names() == ["held"]
        rm = store.load_roadmap()
        store.add_view(rm.make_view("after", created_s=2.0), rm)
    with SessionStore(path, read_only=True) as store:
        assert store.load_views().names() == ["held", "after"]


def test_two_stores_in_one_process_are_refused_too_and_close_releases(tmp_path: Path) -> None:
    from icenav.errors import SessionLockedError

    path = tmp_path / "s.icenav"
    first = SessionStore(path)
    with pytest.raises(SessionLockedError, match=f"pid {__import__('os').getpid()}"):
        SessionStore(path)
    first.close()
    SessionStore(path).close()  # released by close


def test_an_empty_file_is_a_new_session_only_by_explicit_choice(tmp_path: Path) -> None:
    path = tmp_path / "empty.icenav"
    path.touch()
    with pytest.raises(StoreError, match=r"empty \(0 bytes\).*--new-session"):
        SessionStore(path)
    with pytest.raises(StoreError, match=r"read-only: it is empty"):
        SessionStore(path, read_only=True)
    assert path.stat().st_size == 0  # refused, untouched
    with SessionStore(path, new_session=True) as store:
        assert store.load_views().names() == []
    with pytest.raises(StoreError, match="holds data.*never written over"):
        SessionStore(path, new_session=True)
    SessionStore(path).close()  # resumed as a session


def test_a_missing_folder_is_named(tmp_path: Path) -> None:
    folder = tmp_path / "no" / "such"
    with pytest.raises(StoreError, match=f"the folder {folder} does not exist"):
        SessionStore(folder / "s.icenav")
    with pytest.raises(StoreError, match=f"the folder {folder} does not exist"):
        SessionStore(folder / "s.icenav", read_only=True)
    assert not folder.exists()


def test_a_file_without_the_view_em_table_loads_and_gains_it(tmp_path: Path) -> None:
    """Files written before the views' EM poses were stored: their views load without one;
    opened for writing, the file gains the table and keeps the next view's pose."""
    path = tmp_path / "old.icenav"
    rm = Roadmap()
    with SessionStore(path) as store:
        for q in walk(1, 50):
            rm.add(q)
        store.add_view(rm.make_view("old", created_s=0.0), rm)
    with closing(sqlite3.connect(path)) as db:
        db.execute("DROP TABLE view_em")  # as an older icenav wrote it
        db.commit()
    with SessionStore(path, read_only=True) as store:
        assert store.load_views().get("old").em_tip2base is None
    with SessionStore(path) as store:
        rm.add(rm.vertices()[-1])
        store.add_view(rm.make_view("new", created_s=1.0, em_tip2base=np.eye(4)), rm)
    with SessionStore(path, read_only=True) as store:
        lib = store.load_views()
    assert lib.get("old").em_tip2base is None
    np.testing.assert_array_equal(lib.get("new").em_tip2base, np.eye(4))
