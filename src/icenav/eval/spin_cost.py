"""``icenav eval spin --costs``: the robot time and the moves of each calibration.

Each calibration of ``eval spin`` is one of the console's procedures
(:func:`icenav.calibration.procedures.make_procedure`); its robot time is what the
controller's calibration runner takes at the controller's stated speeds
(:class:`icenav.control.config.ControllerConfig`: every move at half of ``max_velocity``
with a ``calibration_ramp_s`` ramp, ``plan_settle_s`` of settling and one control cycle per
tracker reading), as :func:`icenav.control.calibration_runner.preview` adds it up, the return
to the start included. The moves are the procedure's visits (an adaptive procedure's count
is the one on the constant-curvature model; on a real catheter its search may take a few
more).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from icenav.calibration.hysteresis import short_hysteresis_plan
from icenav.calibration.procedure import CalibrationOutcome, VisitGenerator
from icenav.calibration.procedures import make_procedure, plan_visits
from icenav.calibration.short import short_ring_plan
from icenav.control.calibration_runner import preview
from icenav.control.config import ControllerConfig
from icenav.errors import ConfigurationError

__all__ = [
    "CALIBRATION_KINDS",
    "CalibrationCost",
    "calibration_costs",
    "format_costs",
    "short_calibration_cost",
]

CALIBRATION_KINDS = ("dense", "five_point", "dense+hysteresis")
"""The calibrations ``eval spin`` runs: the paper's dense and 5-point, and ours."""


@dataclass(frozen=True)
class CalibrationCost:
    """What one calibration costs on the robot."""

    kind: str
    """The procedure's kind."""
    n_moves: int
    """States visited (robot moves), the return excluded."""
    n_readings: int
    """Tracker readings among them."""
    robot_s: float
    """Robot time at the controller's speeds (s), the return included."""
    max_velocity: tuple[float, ...]
    """The motor speeds the moves ran at (rad/s, rad/s, rad/s, mm/s)."""


def calibration_costs(
    kinds: Sequence[str] = CALIBRATION_KINDS, config: ControllerConfig | None = None
) -> list[CalibrationCost]:
    """The cost of each calibration ``kind`` from rest at the speeds of ``config`` (default:
    the controller's defaults)."""
    cfg = ControllerConfig() if config is None else config
    speed_scale = 0.5  # the runner's calibration pace (calibration_runner.preview)
    out = []
    for kind in kinds:
        p = preview(
            make_procedure(kind, geometry=cfg.geometry),
            np.zeros(4),
            np.asarray(cfg.max_velocity),
            settle_s=cfg.plan_settle_s,
            ramp_s=cfg.calibration_ramp_s,
            dt=cfg.dt,
            speed_scale=speed_scale,
            geometry=cfg.geometry,
        )
        v = tuple(float(x) * speed_scale for x in cfg.max_velocity)
        out.append(CalibrationCost(kind, p.n_visits, p.n_readings, p.duration_s, v))
    return out


@dataclass(frozen=True)
class _ShortMoves:
    """The short calibration's moves after the 5-point search, as a procedure, for the
    runner's preview."""

    rings: bool = False
    bias_circle: bool = False
    kind: str = "short moves"
    label: str = "short calibration: the moves after the 5-point search"

    def visits(self) -> VisitGenerator:
        if self.rings:
            plan = short_ring_plan(bias_circle=self.bias_circle).plan
        else:
            plan = short_hysteresis_plan().plan
        return plan_visits(plan)

    def fit(self, recording: object) -> CalibrationOutcome:
        raise ConfigurationError(  # pragma: no cover - only previewed
            "the short calibrations are fitted by icenav.eval.spin.calibrate(short=True)"
        )


def short_calibration_cost(
    config: ControllerConfig | None = None, *, rings: bool = False, bias_circle: bool = False
) -> CalibrationCost:
    """The short calibration (``eval spin`` condition ``short``): the 5-point search and the
    short roll sweeps (:func:`icenav.calibration.hysteresis.short_hysteresis_plan`), each
    from rest, added up; with ``rings`` the ``short+rings`` one
    (:func:`icenav.calibration.short.short_ring_plan` after the 5-point search), with
    ``bias_circle`` too the ``short+rings+prior`` one (the plan with the short roll circle)."""
    cfg = ControllerConfig() if config is None else config
    (five,) = calibration_costs(("five_point",), cfg)
    p = preview(
        _ShortMoves(rings, bias_circle and rings),
        np.zeros(4),
        np.asarray(cfg.max_velocity),
        settle_s=cfg.plan_settle_s,
        ramp_s=cfg.calibration_ramp_s,
        dt=cfg.dt,
        geometry=cfg.geometry,
    )
    return CalibrationCost(
        ("short+rings+prior" if bias_circle else "short+rings") if rings else "short",
        five.n_moves + p.n_visits,
        five.n_readings + p.n_readings,
        five.robot_s + p.duration_s,
        five.max_velocity,
    )


def format_costs(costs: Sequence[CalibrationCost]) -> str:
    """A table: kind, moves, readings, robot time (min), and the motor speeds."""
    lines = ["calibration cost at the controller's pace (robot time, the return included):"]
    for c in costs:
        lines.append(
            f"  {c.kind:<18s} {c.n_moves:>5d} moves {c.n_readings:>5d} readings "
            f"{c.robot_s / 60.0:6.1f} min"
        )
    if costs:
        v = costs[0].max_velocity
        lines.append(
            f"  (knobs {math.degrees(v[0]):.0f} deg/s, roll {math.degrees(v[2]):.0f} deg/s, "
            f"translation {v[3]:.0f} mm/s)"
        )
    return "\n".join(lines)
