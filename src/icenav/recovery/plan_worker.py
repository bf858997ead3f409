"""The roadmap planner's worker process: Dijkstra's shortest-path tree off the controller's
process, so a long search never holds the controller's interpreter (the GIL).

Why not :class:`concurrent.futures.ProcessPoolExecutor`: its ``spawn`` and ``forkserver``
start methods import the parent's ``__main__`` in the child (as ``__mp_main__``), so a lab's
script without an ``if __name__ == "__main__":`` guard ran its whole body a second time inside
the worker (a second controller, its prints and files); ``fork`` is unsafe in a process with
threads. This worker is a plain ``python -m icenav.recovery.plan_worker`` child talking over
its stdin/stdout in length-prefixed pickle frames, which imports nothing of the caller's.

Frames: 8-byte big-endian length, then a pickle. Request ``(indptr, indices, data, n, goal)``
(the half CSR of the roadmap's graph and the goal vertex), reply ``("ok", dist, pred)`` or
``("error", text)``. The child exits at end of input.
"""

from __future__ import annotations

import contextlib
import pickle
import subprocess
import sys
import threading
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from icenav._typing import Array
from icenav.errors import PlanningError

__all__ = ["PlanWorker", "shortest_path_tree"]

_HEADER = 8


def shortest_path_tree(
    indptr: NDArray[Any], indices: NDArray[Any], data: Array, n: int, goal: int
) -> tuple[Array, NDArray[np.int32]]:
    """Distances (n,) to ``goal`` and predecessors (n,) (-9999: none) over the undirected
    graph of a half CSR (upper triangle; weights in the roadmap's metric)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import dijkstra

    half = sp.csr_matrix((data, indices, indptr), shape=(n, n))
    dist, pred = dijkstra(half, directed=False, indices=goal, return_predecessors=True)
    return np.asarray(dist, np.float64), pred.astype(np.int32)


def _write(stream: IO[bytes], obj: object) -> None:
    blob = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(len(blob).to_bytes(_HEADER, "big") + blob)
    stream.flush()


def _read(stream: IO[bytes]) -> Any:
    head = stream.read(_HEADER)
    if len(head) < _HEADER:
        raise PlanningError("the planning worker's pipe closed")
    size = int.from_bytes(head, "big")
    blob = stream.read(size)
    if len(blob) < size:
        raise PlanningError("the planning worker's pipe closed mid-frame")
    return pickle.loads(blob)  # noqa: S301 - our own process on the other end


class PlanWorker:
    """One worker process; :meth:`tree` runs :func:`shortest_path_tree` in it. Thread-safe
    (one request at a time). Any failure (the process killed, a broken pipe) raises
    ``OSError`` / :class:`~icenav.errors.PlanningError` and leaves the worker closed: make a
    new one."""

    def __init__(self) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "icenav.recovery.plan_worker"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
        )
        self._lock = threading.Lock()

    @property
    def pid(self) -> int:
        """The worker process's id."""
        return self._proc.pid

    def tree(
        self, indptr: NDArray[Any], indices: NDArray[Any], data: Array, n: int, goal: int
    ) -> tuple[Array, NDArray[np.int32]]:
        """:func:`shortest_path_tree` in the worker (blocks until it answers)."""
        with self._lock:
            proc = self._proc
            assert proc.stdin is not None and proc.stdout is not None
            try:
                _write(proc.stdin, (indptr, indices, data, int(n), int(goal)))
                reply = _read(proc.stdout)
            except (OSError, PlanningError, pickle.UnpicklingError):
                self._close_locked()
                raise
        if reply[0] != "ok":
            raise PlanningError(f"the planning worker failed: {reply[1]}")
        return reply[1], reply[2]

    def close(self, wait: bool = True) -> None:
        """End the worker (its input closed; killed if it does not exit within 2 s)."""
        with self._lock:
            self._close_locked(wait)

    def _close_locked(self, wait: bool = False) -> None:
        proc = self._proc
        if proc.stdin is not None and not proc.stdin.closed:
            with contextlib.suppress(OSError):
                proc.stdin.close()
        if wait:
            try:
                proc.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        elif proc.poll() is None:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def _serve(inp: IO[bytes], out: IO[bytes]) -> None:
    """The child's loop: answer each request until the input ends."""
    while True:
        try:
            req = _read(inp)
        except PlanningError:  # the parent closed our input: done
            return
        try:
            dist, pred = shortest_path_tree(*req)
            _write(out, ("ok", dist, pred))
        except Exception as exc:  # noqa: BLE001 - reported to the parent, which falls back
            _write(out, ("error", f"{type(exc).__name__}: {exc}"))


if __name__ == "__main__":
    _serve(sys.stdin.buffer, sys.stdout.buffer)
