"""The population engines: local pool and Ray give the same results, in item order."""

from __future__ import annotations

import os
from dataclasses import asdict
from typing import Any

import pytest

from icenav.errors import ConfigurationError, JobError
from icenav.eval.engine import run_jobs
from icenav.eval.spin import evaluate_catheter

SEEDS = [100, 101]
"""Development catheters (100-109 develop methods; 110-119 stay held out)."""


def square_unless_three(x: int, scale: int = 1) -> int:
    """A module-level (picklable) job that fails on one item."""
    if x == 3:
        raise ValueError(f"item {x} is unlucky")
    return scale * x * x


def blas_threads(_: int) -> str | None:
    """The thread count a worker's BLAS was told to use."""
    return os.environ.get("OPENBLAS_NUM_THREADS")


def spin_records(seed: int) -> list[dict[str, Any]]:
    """The spin evaluation of one catheter, reduced (condition none: no calibration)."""
    run = evaluate_catheter(seed, ("straight", "steep"), bends_deg=(20, 40), conditions=("none",))
    return [asdict(r) for r in run.records]


@pytest.mark.parametrize("jobs", [1, 2])
def test_local_engine_keeps_item_order_and_passes_kwargs(jobs: int) -> None:
    seen: list[int] = []
    out = run_jobs(
        square_unless_three,
        [5, 1, 4, 2],
        jobs=jobs,
        kwargs={"scale": 2},
        on_result=lambda item, _: seen.append(item),
        progress=False,
    )
    assert out == [50, 2, 32, 8]
    assert sorted(seen) == [1, 2, 4, 5]


@pytest.mark.parametrize("jobs", [1, 2])
def test_local_engine_names_the_failing_item(jobs: int) -> None:
    with pytest.raises(JobError, match=r"job 2 \(catheter 3\) failed: ValueError: item 3") as err:
        run_jobs(
            square_unless_three,
            [1, 2, 3, 4],
            jobs=jobs,
            describe=lambda s: f"catheter {s}",
            progress=False,
        )
    assert err.value.item == 3 and err.value.index == 2
    if jobs > 1:
        assert "square_unless_three" in err.value.remote_traceback
    else:
        assert isinstance(err.value.__cause__, ValueError)


def test_pool_workers_run_one_blas_thread_and_the_parent_keeps_its_own(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    assert run_jobs(blas_threads, [1, 2], jobs=2, progress=False) == ["1", "1"]
    assert "OPENBLAS_NUM_THREADS" not in os.environ
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")  # the caller's choice is kept
    assert run_jobs(blas_threads, [1, 2], jobs=2, progress=False) == ["3", "3"]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"engine": "dask"}, "engine must be one of"),
        ({"jobs": 0}, r"jobs must be an int in \[1, 64\]"),
        ({"jobs": 2.0}, "jobs must be an int"),
        ({"address": "auto"}, "for the ray engine"),
    ],
)
def test_bad_settings_are_rejected(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        run_jobs(square_unless_three, [1], **kwargs)


def test_progress_bar_counts_the_jobs(capsys: pytest.CaptureFixture[str]) -> None:
    run_jobs(square_unless_three, [1, 2], progress=True, desc="catheters")
    err = capsys.readouterr().err
    assert "catheters" in err and "2/2" in err


@pytest.mark.slow
def test_ray_engine_gives_the_local_results(ray_local: Any) -> None:
    out = run_jobs(square_unless_three, [5, 1, 4, 2], engine="ray", kwargs={"scale": 2})
    assert out == [50, 2, 32, 8]
    with pytest.raises(JobError, match=r"job 1 \(3\) failed: ValueError: item 3") as err:
        run_jobs(square_unless_three, [1, 3, 4], engine="ray", progress=False)
    assert err.value.item == 3
    assert "square_unless_three" in err.value.remote_traceback


@pytest.mark.slow
def test_spin_records_are_identical_on_both_engines(ray_local: Any) -> None:
    local = run_jobs(spin_records, SEEDS, jobs=2, progress=False)
    ray_out = run_jobs(spin_records, SEEDS, engine="ray", progress=False)
    assert ray_out == local
    assert [recs[0]["seed"] for recs in local] == SEEDS
    assert local[0] != local[1]  # the seeds make different catheters
    assert local[0] == spin_records(SEEDS[0])  # and the same as in this process
