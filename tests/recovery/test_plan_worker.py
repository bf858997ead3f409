"""The planner's worker process: the same tree as in the caller's thread, a script without a
``__main__`` guard runs once, and a killed worker falls back and is replaced."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from icenav.recovery import planner
from icenav.recovery.plan_worker import PlanWorker, shortest_path_tree


def _graph(n: int = 200, seed: int = 3) -> sp.csr_matrix:
    """A random connected weighted graph as the planner hands it over (upper triangle)."""
    rng = np.random.default_rng(seed)
    u = np.arange(n - 1)
    v = u + 1  # a chain keeps it connected
    eu = rng.integers(0, n, 3 * n)
    ev = rng.integers(0, n, 3 * n)
    keep = eu != ev
    uu = np.concatenate([u, np.minimum(eu, ev)[keep]])
    vv = np.concatenate([v, np.maximum(eu, ev)[keep]])
    w = rng.uniform(0.1, 2.0, len(uu))
    return sp.coo_matrix((w, (uu, vv)), shape=(n, n)).tocsr()


def test_the_worker_gives_the_tree_of_the_callers_thread() -> None:
    half = _graph()
    worker = PlanWorker()
    try:
        got = worker.tree(half.indptr, half.indices, half.data, half.shape[0], 17)
        again = worker.tree(half.indptr, half.indices, half.data, half.shape[0], 5)
    finally:
        worker.close()
    want = shortest_path_tree(half.indptr, half.indices, half.data, half.shape[0], 17)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert again[0][5] == 0.0 and np.isfinite(again[0]).all()
    assert worker._proc.poll() is not None  # closed: the process has exited


def test_a_script_without_a_main_guard_runs_once(tmp_path: Path) -> None:
    """multiprocessing's spawn re-ran such a script's body inside the worker."""
    marker = tmp_path / "runs.txt"
    script = tmp_path / "lab_script.py"
    script.write_text(
        textwrap.dedent(
            f"""
            from icenav.recovery.planner import warm_up_planner
            with open({str(marker)!r}, "a") as f:
                f.write("ran\\n")
            print("worker:", warm_up_planner())
            """
        )
    )
    out = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=120, check=True
    )
    assert "worker: True" in out.stdout, out
    assert marker.read_text().splitlines() == ["ran"]


def test_a_killed_worker_falls_back_and_the_next_search_starts_a_new_one() -> None:
    half = _graph(50)
    want = shortest_path_tree(half.indptr, half.indices, half.data, 50, 0)
    first = planner._dijkstra_isolated(half, 0)
    assert first is not None
    np.testing.assert_array_equal(first[0], want[0])
    worker = planner._WORKER
    assert worker is not None
    os.kill(worker.pid, signal.SIGKILL)
    worker._proc.wait()
    assert planner._dijkstra_isolated(half, 0) is None  # the caller runs it in its thread
    assert planner._WORKER is None
    again = planner._dijkstra_isolated(half, 0)  # a new worker
    assert again is not None and planner._WORKER is not None
    assert planner._WORKER.pid != worker.pid
    np.testing.assert_array_equal(again[1], want[1])
