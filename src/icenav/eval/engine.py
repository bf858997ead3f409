"""Engines for population runs: the same jobs in a local process pool or on a Ray cluster.

An evaluation over many catheters (``icenav eval spin --seeds 110-119``) is a list of
independent jobs ``fn(item, **kwargs)``, one per item (a catheter seed, a patient, ...).
:func:`run_jobs` runs them on one of two engines and returns the results in the order of the
items, whichever finishes first:

- ``local`` (the default): ``jobs == 1`` runs them one after the other in this process;
  ``jobs > 1`` in a pool of ``jobs`` processes (``spawn``, so a threaded parent is never
  forked), as ``eval spin --jobs`` always did, with one BLAS / OpenMP thread per worker.
- ``ray``: one Ray task per item (1 CPU each), on the running Ray instance if this process
  has one (``ray.init`` was called), else on the cluster at ``address`` (``"auto"``: the
  one started on this machine with ``ray start --head``; ``"ray://host:10001"``: a remote
  head through Ray Client), else on a local instance started for this call and shut down
  after it. The cluster's CPUs bound the parallelism; ``jobs`` is the local pool's size
  and is ignored. Ray is the optional extra ``icenav[cluster]``; every node needs icenav
  installed (the same version) because the tasks import ``fn`` by its module name.

A job is a pure function of its item: the twin is seeded by the item, so both engines give
the same results for the same items (tested). A failing job stops the run (the jobs not yet
started are cancelled) with a :class:`~icenav.errors.JobError` naming the item, with the
worker's traceback. A progress bar (tqdm, on standard error) counts the finished jobs.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import multiprocessing
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, TypeVar

from tqdm import tqdm

from icenav.errors import ConfigurationError, JobError

__all__ = ["ENGINES", "MAX_LOCAL_JOBS", "run_jobs"]

ENGINES = ("local", "ray")
"""The engines :func:`run_jobs` knows."""
MAX_LOCAL_JOBS = 64
"""Largest local process pool."""

T = TypeVar("T")
R = TypeVar("R")


def _call(fn: Callable[..., R], item: Any, kwargs: Mapping[str, Any]) -> R:
    """One job (module level, so processes and Ray workers import it by name)."""
    return fn(item, **kwargs)


def _job_error(
    index: int, item: Any, describe: Callable[[Any], str], exc: BaseException
) -> JobError:
    remote = ""
    cause = exc.__cause__
    if cause is not None and type(cause).__name__ == "_RemoteTraceback":
        remote = str(cause)  # concurrent.futures carries the worker's traceback text here
    return JobError(
        f"job {index} ({describe(item)}) failed: {type(exc).__name__}: {exc}",
        item=item,
        index=index,
        remote_traceback=remote,
    )


def run_jobs(
    fn: Callable[..., R],
    items: Sequence[T],
    *,
    engine: str = "local",
    jobs: int = 1,
    address: str | None = None,
    progress: bool = True,
    kwargs: Mapping[str, Any] | None = None,
    on_result: Callable[[T, R], None] | None = None,
    describe: Callable[[T], str] = repr,
    desc: str = "jobs",
) -> list[R]:
    """Run ``fn(item, **kwargs)`` for every item on ``engine``; results in item order.

    Parameters
    ----------
    fn : callable
        The job. With ``jobs > 1`` or on Ray it must be picklable: a module-level function
        (or a ``functools.partial`` of one).
    items : sequence
        One job per item (e.g. catheter seeds); items and results must be picklable.
    engine : "local" | "ray"
        Where the jobs run (see the module docstring).
    jobs : int
        Local engine: processes in the pool, 1 to :data:`MAX_LOCAL_JOBS` (1: in this
        process). Ignored on Ray (the cluster's CPUs decide).
    address : str, optional
        Ray only: the cluster to join when this process is not connected to one yet
        (``"auto"``, ``"ray://host:10001"``); None starts a local Ray instance for the call.
    progress : bool
        Show a progress bar (standard error) counting finished jobs.
    kwargs : mapping, optional
        Keyword arguments passed to every job.
    on_result : callable(item, result), optional
        Called in this process as each job finishes (completion order), e.g. to print.
    describe : callable(item) -> str
        How an item is named in errors (default ``repr``).
    desc : str
        Label of the progress bar.

    Returns
    -------
    list
        ``[fn(item, **kwargs) for item in items]``.

    Raises
    ------
    ConfigurationError
        Unknown engine, ``jobs`` out of range, ``address`` with the local engine, or Ray
        not installed.
    JobError
        A job raised; names the item, chains or carries the worker's traceback.
    """
    if engine not in ENGINES:
        raise ConfigurationError(f"engine must be one of {ENGINES}, got {engine!r}")
    if isinstance(jobs, bool) or not isinstance(jobs, int) or not 1 <= jobs <= MAX_LOCAL_JOBS:
        raise ConfigurationError(
            f"jobs must be an int in [1, {MAX_LOCAL_JOBS}] processes, got {jobs!r}"
        )
    if address is not None and engine != "ray":
        raise ConfigurationError(f"address {address!r} is for the ray engine, not {engine!r}")
    items = list(items)
    kw: Mapping[str, Any] = dict(kwargs or {})
    results: dict[int, R] = {}
    bar = tqdm(total=len(items), desc=desc, unit="job", disable=not progress)

    def done(i: int, result: R) -> None:
        results[i] = result
        bar.update(1)
        if on_result is not None:
            on_result(items[i], result)

    try:
        if engine == "ray":
            _run_ray(fn, items, kw, address, done, describe)
        elif jobs == 1 or len(items) <= 1:
            for i, item in enumerate(items):
                try:
                    result = fn(item, **kw)
                except Exception as exc:
                    raise _job_error(i, item, describe, exc) from exc
                done(i, result)
        else:
            _run_pool(fn, items, kw, jobs, done, describe)
    finally:
        bar.close()
    return [results[i] for i in range(len(items))]


def _run_pool(
    fn: Callable[..., R],
    items: list[Any],
    kw: Mapping[str, Any],
    jobs: int,
    done: Callable[[int, R], None],
    describe: Callable[[Any], str],
) -> None:
    ctx = multiprocessing.get_context("spawn")  # no fork of a threaded parent
    pool = concurrent.futures.ProcessPoolExecutor(max_workers=jobs, mp_context=ctx)
    try:
        # the workers start on the first submit and inherit the environment then
        with _one_thread_per_worker():
            futures = {pool.submit(_call, fn, item, kw): i for i, item in enumerate(items)}
        for fut in concurrent.futures.as_completed(futures):
            i = futures[fut]
            try:
                result = fut.result()
            except Exception as exc:
                raise _job_error(i, items[i], describe, exc) from exc
            done(i, result)
    finally:
        # on an error: drop the jobs not started yet, wait for the running ones
        pool.shutdown(wait=True, cancel_futures=True)


THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
"""Thread-pool sizes of the numerical libraries, set to 1 in the local pool's workers."""


@contextlib.contextmanager
def _one_thread_per_worker() -> Iterator[None]:
    """While the pool starts: one thread per numerical library in its workers (unless the
    caller set them), as Ray's workers run. ``jobs`` processes each with a multi-threaded
    BLAS oversubscribe the cores: measured on one catheter's calibration (dense and
    5-point), 8.4 s of CPU with the default threads against 5.4 s with one."""
    saved = {k: os.environ.get(k) for k in THREAD_VARIABLES}
    for k, v in saved.items():
        if v is None:
            os.environ[k] = "1"
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as exc:
        raise ConfigurationError(
            "the ray engine needs the optional extra: pip install 'icenav[cluster]' "
            f"({type(exc).__name__}: {exc})"
        ) from exc
    return ray


def _run_ray(
    fn: Callable[..., R],
    items: list[Any],
    kw: Mapping[str, Any],
    address: str | None,
    done: Callable[[int, R], None],
    describe: Callable[[Any], str],
) -> None:
    ray = _import_ray()
    started = not ray.is_initialized()
    if started:
        if address is None:  # a local instance for this call, on the loopback address
            ray.init(
                include_dashboard=False,
                configure_logging=False,
                log_to_driver=False,
                _node_ip_address="127.0.0.1",
            )
        else:
            ray.init(address=address, configure_logging=False)
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(_call)
        fn_ref = ray.put(fn)
        kw_ref = ray.put(dict(kw))
        refs = {task.remote(fn_ref, item, kw_ref): i for i, item in enumerate(items)}
        pending = list(refs)
        try:
            while pending:
                ready, pending = ray.wait(pending, num_returns=1)
                i = refs[ready[0]]
                try:
                    result = ray.get(ready[0])
                except ray.exceptions.RayTaskError as exc:
                    cause = getattr(exc, "cause", None) or exc
                    err = JobError(
                        f"job {i} ({describe(items[i])}) failed: {type(cause).__name__}: {cause}",
                        item=items[i],
                        index=i,
                        remote_traceback=str(exc),
                    )
                    raise err from exc
                done(i, result)
        finally:
            for ref in pending:  # after an error: the jobs not finished yet
                ray.cancel(ref)
    finally:
        if started:
            ray.shutdown()
