"""``icenav eval recovery --plant``: the bench runs the plant it is given, on its own clock."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from icenav.errors import PluginError
from icenav.eval.recovery import RecoveryConfig, _parser, config_from_args
from icenav.eval.recovery_bench import DT, Bench
from icenav.sim.families import NonlinearPlayPlant, RateDependentPlant


def test_the_option_reaches_the_bench_and_the_twin() -> None:
    cfg = config_from_args(_parser().parse_args(["--plant", "nonlinear-play", "--seed", "210"]))
    assert cfg.plant == "nonlinear-play"
    bench = Bench(cfg)
    assert isinstance(bench.plant, NonlinearPlayPlant) and bench.robot.plant is bench.plant
    # under a disturbance condition the family's plant is the one the disturbances wrap
    bench = Bench(RecoveryConfig(plant="rate-dependent", seed=210, condition="phantom"))
    assert bench.twin is not None and isinstance(bench.twin.plant.inner, RateDependentPlant)
    assert bench.twin.plant.inner.clock is not None  # the bench's simulated clock drives it


def test_a_plugin_without_a_clock_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "no_clock.py"
    path.write_text(
        "from icenav.sim import CatheterPlant, EMTracker\n"
        "def make(seed, vessel):\n"
        "    plant = CatheterPlant(seed=seed, vessel=vessel)\n"
        "    return plant, EMTracker(plant, seed=seed)\n"
    )
    with pytest.raises(PluginError, match="takes no clock= keyword"):
        Bench(RecoveryConfig(plant=f"{path}:make", seed=3))


def test_a_held_set_point_is_no_new_move_of_the_catheter() -> None:
    """The controller re-sends its set-point every cycle; the bench's disturbed twin must keep
    the catheter's time history over a hold (the refinement's 9-s window of complete
    breaths): before the twin's fix every re-sent set-point restarted it."""
    bench = Bench(RecoveryConfig(seed=100, patient=0, condition="in-vivo", image_size=32))
    plant = bench.twin.plant  # type: ignore[union-attr]
    q = np.array([0.05, -0.1, 0.2, 1.0])
    bench.robot.command_position(q)
    moved_at = plant.last_move_s
    for _ in range(50):
        bench.clock.advance(DT)
        bench.robot.command_position(q.copy())
    assert plant.last_move_s == moved_at
    # the breathing still moves the tip over the hold: a pose in the past is not the one now
    past = plant.pose_at(bench.clock.now() - 0.3)
    assert not np.allclose(past[:3, 3], plant.pose_at(bench.clock.now())[:3, 3], atol=1e-6)
    bench.robot.command_position(q + np.array([0.0, 0.0, 0.0, 0.5]))
    assert plant.last_move_s == bench.clock.now()


def test_returns_are_checked_as_the_products_go_to_view() -> None:
    """The bench keeps the operator's forces as the controller does (per vertex and per
    measured tip pose) and checks returns with the controller's margins."""
    from icenav.control.config import ControllerConfig

    bench = Bench(RecoveryConfig(seed=100, patient=0, condition="in-vivo", image_size=32))
    product = ControllerConfig()
    assert bench.force_margin_n == product.force_margin_n
    assert bench.force_margin_fraction == product.force_margin_fraction
    bench.drive(bench.operator.dwell(0.1))
    assert bench.forces.n_recorded > 0 and bench.force_record.tips.n_samples > 0
