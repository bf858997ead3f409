"""``icenav eval recovery --plant``: the bench runs the plant it is given, on its own clock."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from icenav.errors import PluginError
from icenav.eval.recovery import RecoveryConfig, _parser, config_from_args
from icenav.eval.recovery_bench import DT, Bench
from icenav.sim.families import NonlinearPlayPlant, RateDependentPlant
from icenav.sim.operator import OperatorConfig, ScriptedOperator


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


WIDE = (1.0, 1.0, 0.5, 10.0)
"""Exploration reach of an operator of large moves (rad, rad, rad, mm)."""


def _rest_forces(bench: Bench, moves: int, limit: float | None) -> tuple[list[float], list[int]]:
    """Rest force (mean over a second, N) after each exploration move, and the back-offs."""
    rest, backs = [], []
    for _ in range(moves):
        backs.append(bench.explore(1, limit))
        rest.append(float(np.mean(bench.drive(bench.operator.dwell(1.0)))))
    return rest, backs


def test_the_looking_operator_does_not_leave_the_catheter_pushing_a_wall() -> None:
    """``rest_force_n``: after each exploration move the operator reads the force at rest
    and backs off towards where the move started until it is below the limit (or it gave up
    after its back-offs); the blind operator (None) explores as before, move for move."""
    cfg = RecoveryConfig(seed=100, patient=0, condition="in-vivo", image_size=32)
    blind, looking = Bench(cfg), Bench(cfg)
    for bench in (blind, looking):  # an operator of large moves (reaches a wall in 3)
        bench.operator = ScriptedOperator(seed=0, config=OperatorConfig(explore_reach=WIDE))
    rest_blind, _ = _rest_forces(blind, 3, None)
    assert max(rest_blind) > 0.4  # the blind operator leaves it pushing (a test that can fail)
    rest, backs = _rest_forces(looking, 3, 0.4)
    assert sum(backs) > 0
    for f, n in zip(rest, backs, strict=True):
        assert f <= 0.4 + 0.05 or n == 6  # the readout over the next second, as it looked
    # where nothing pushes, the looking operator's moves are the blind one's: explore(1)
    # n times draws the targets explore(n) draws
    one, many = (ScriptedOperator(seed=0, config=OperatorConfig(explore_reach=WIDE)) for _ in "ab")
    np.testing.assert_array_equal(
        np.concatenate([one.explore(1) for _ in range(3)]), many.explore(3)
    )


def test_the_rest_force_option_reaches_the_config() -> None:
    from icenav.eval.recovery_bench import REST_FORCE_N

    assert config_from_args(_parser().parse_args([])).rest_force_n == REST_FORCE_N
    assert config_from_args(_parser().parse_args(["--rest-force", "0.2"])).rest_force_n == 0.2
    assert config_from_args(_parser().parse_args(["--rest-force", "none"])).rest_force_n is None
    for bad in ("0", "-1", "lots"):
        with pytest.raises(SystemExit):
            _parser().parse_args(["--rest-force", bad])
