"""``icenav eval recovery --engine local|ray``: the same seeds give the same records on both
engines, and a progress bar counts the runs on each."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from icenav.eval.recovery import main

QUICK = ["--quick", "--open-loop-only", "--seed", "100,101", "--patient", "0"]


def _records(path: Path) -> list[dict[str, Any]]:
    records: list[dict[str, Any]] = json.loads(path.read_text())
    return records


@pytest.mark.slow
def test_recovery_records_are_identical_on_both_engines(
    ray_local: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    local, on_ray = tmp_path / "local.json", tmp_path / "ray.json"
    assert main([*QUICK, "--json", str(local)]) == 0
    assert "2/2" in capsys.readouterr().err
    assert main([*QUICK, "--engine", "ray", "--json", str(on_ray)]) == 0
    assert "2/2" in capsys.readouterr().err
    a, b = _records(local), _records(on_ray)
    assert [r["seed"] for r in a] == [100] * (len(a) // 2) + [101] * (len(a) // 2)
    assert a == b  # every number, not only the seeds
    h = len(a) // 2
    errors = [r["true_tip_error_mm_mean"] for r in a]
    assert errors[:h] != errors[h:]  # and the two catheters give different results


def test_address_needs_the_ray_engine(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--quick", "--address", "auto"]) == 2
    assert "--address needs --engine ray" in capsys.readouterr().err
