"""The shortened soak (2 simulated minutes; the full 4 h runs in `make soak`)."""

from __future__ import annotations

from pathlib import Path

import pytest

from icenav.apps.soak import SoakConfig, main, run_soak
from icenav.errors import ConfigurationError


@pytest.mark.slow
def test_short_soak_keeps_store_consistent_and_memory_bounded(tmp_path: Path) -> None:
    cfg = SoakConfig(duration_s=120.0, view_every_s=15.0, return_every_s=25.0, seed=3)
    report = run_soak(cfg, tmp_path / "soak.icenav")
    assert report.states == 12000
    assert report.faults == 0
    assert report.store_consistent
    assert report.views_saved >= 4
    assert report.returns_done >= 3 and report.returns_failed == 0
    assert report.max_return_error < 1e-6  # returns end exactly on the view's motor state
    # bounded: the deques keep at most their maxlen, the roadmap merges revisited states
    assert report.max_deque_len <= 100_000
    assert report.roadmap_vertices < report.states
    assert report.roadmap_edges > report.roadmap_vertices  # a connected roadmap, not a chain
    # no store commit ran on the control thread (the writer thread did them all), and no
    # full garbage collection ran inside a cycle (the GC policy: between cycles only)
    assert report.commit_in_cycle_max_ms == 0.0
    assert report.gc_collections[2] == 0
    assert report.isolated_views == 0


@pytest.mark.slow
def test_short_soak_with_a_small_vertex_budget(tmp_path: Path) -> None:
    """The budget closes within the run (a budget far too small for this operator, who
    explores new joint space all the time): the roadmap stops at it, every return that
    runs ends exactly on its view, and a return with no recorded path is refused with a
    clear message, never driven through unrecorded space."""
    cfg = SoakConfig(
        duration_s=100.0, view_every_s=10.0, return_every_s=17.0, seed=5, max_vertices=1500
    )
    report = run_soak(cfg, tmp_path / "soak.icenav")
    assert report.roadmap_vertices <= 1500
    assert report.roadmap_unrecorded > 0  # the budget did close
    assert report.faults == 0 and report.store_consistent
    assert report.returns_done >= 2
    assert report.max_return_error < 1e-6
    for message in report.failure_messages:  # refused: the roadmap has no path from here
        assert (
            "is not connected to start vertex" in message  # a view beyond the closed budget
            or "from the nearest recorded state" in message  # the robot is beyond it
        ), message
    assert report.returns_failed <= report.isolated_views


def test_soak_settings_are_checked() -> None:
    with pytest.raises(ConfigurationError, match="duration_s must be finite and > 0 s"):
        SoakConfig(duration_s=float("nan"))
    with pytest.raises(ConfigurationError, match="rate_hz"):
        SoakConfig(rate_hz=0.0)
    with pytest.raises(ConfigurationError, match="heap_top"):
        SoakConfig(heap_top=-1)


@pytest.mark.parametrize("argv", [["--hours", "-1"], ["--minutes", "nan"], ["--hours", "x"]])
def test_soak_cli_rejects_bad_durations(argv: list[str], capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert "usage" in capsys.readouterr().err
