"""A scripted operator: joystick-like 100 Hz motor joint traces without a person.

Moves are minimum-jerk profiles (smooth like a thumbstick eased in and out) from the current
state to a target, slow enough that no joint exceeds its velocity limit; exploration picks
seeded random targets near the current state; dwelling holds still (optionally with a tiny
seeded tremor, as a hand on a joystick). :func:`drive` sends a trace to a robot backend and
records the measured states in a roadmap, so view recovery runs end to end on the twin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_joint_state, check_positive
from icenav.devices.robot import RobotBackend
from icenav.errors import ConfigurationError
from icenav.recovery.roadmap import Roadmap

__all__ = ["OperatorConfig", "ScriptedOperator", "drive", "minimum_jerk"]


@dataclass(frozen=True)
class OperatorConfig:
    """How the scripted operator moves."""

    rate_hz: float = 100.0
    """Sampling rate of the produced trace (Hz)."""
    max_velocity: tuple[float, float, float, float] = (0.5, 0.5, 0.5, 5.0)
    """Fastest joint speed the operator asks for (rad/s, rad/s, rad/s, mm/s)."""
    box_low: tuple[float, float, float, float] = (-1.2, -1.2, -3.1, -40.0)
    """Lower corner of the region the operator explores (rad, rad, rad, mm)."""
    box_high: tuple[float, float, float, float] = (1.2, 1.2, 3.1, 40.0)
    """Upper corner of that region (rad, rad, rad, mm)."""
    explore_reach: tuple[float, float, float, float] = (0.35, 0.35, 0.5, 8.0)
    """Largest offset of an exploration target from the current state, per joint."""

    def __post_init__(self) -> None:
        check_positive(self.rate_hz, "rate_hz", "Hz")
        for name in ("max_velocity", "box_low", "box_high", "explore_reach"):
            v = tuple(float(x) for x in getattr(self, name))
            if len(v) != 4 or not all(np.isfinite(v)):
                raise ConfigurationError(f"{name} needs 4 finite values, got {v}")
            object.__setattr__(self, name, v)
        for name in ("max_velocity", "explore_reach"):
            for x in getattr(self, name):
                check_positive(x, name, "(rad, rad, rad, mm)[/s]")
        if any(lo >= hi for lo, hi in zip(self.box_low, self.box_high, strict=True)):
            raise ConfigurationError(
                f"box_low {self.box_low} must be below box_high {self.box_high}"
            )


def minimum_jerk(q0: ArrayLike, q1: ArrayLike, duration_s: float, rate_hz: float) -> Array:
    """Minimum-jerk move from ``q0`` to ``q1`` sampled at ``rate_hz``.

    ``q(t) = q0 + (q1 - q0) (10 tau^3 - 15 tau^4 + 6 tau^5)``, ``tau = t / T``: zero velocity
    and acceleration at both ends; peak speed ``1.875 |q1 - q0| / T``.

    Returns
    -------
    trace : ndarray, shape (k, 4)
        Samples after ``q0`` up to and including exactly ``q1`` (k >= 1).
    """
    a = np.asarray(q0, np.float64)
    b = np.asarray(q1, np.float64)
    k = max(1, int(np.ceil(duration_s * rate_hz)))
    tau = np.arange(1, k + 1) / k
    s = tau**3 * (10 - 15 * tau + 6 * tau**2)
    out = a + s[:, None] * (b - a)
    out[-1] = b
    return out


class ScriptedOperator:
    """Produces 100 Hz motor joint traces: moves, exploration, dwelling (seeded).

    Parameters
    ----------
    q0 : array-like, shape (4,)
        Starting motor state (rad, rad, rad, mm).
    config : OperatorConfig
        Speeds, rate and exploration region.
    seed : int
        Seed of the random exploration and tremor.
    """

    def __init__(
        self,
        q0: ArrayLike = (0.0, 0.0, 0.0, 0.0),
        config: OperatorConfig | None = None,
        seed: int = 0,
    ) -> None:
        self.config = config if config is not None else OperatorConfig()
        self.state = np.array(check_joint_state(q0, name="q0"), np.float64).reshape(4)
        self.rng = np.random.default_rng(seed)

    def move_to(self, target: ArrayLike, duration_s: float | None = None) -> Array:
        """A minimum-jerk move to ``target`` (clipped to the exploration box).

        The default duration is the shortest with every joint within ``max_velocity``.
        Returns the (k, 4) trace; the operator's state becomes the target.
        """
        cfg = self.config
        goal = np.clip(check_joint_state(target, name="target"), cfg.box_low, cfg.box_high)
        delta = np.abs(goal - self.state)
        t_min = 1.875 * float(np.max(delta / np.array(cfg.max_velocity)))
        duration = max(t_min, 1.0 / cfg.rate_hz) if duration_s is None else float(duration_s)
        if duration < t_min - 1e-12:
            raise ConfigurationError(
                f"a {duration:.3g} s move would exceed max_velocity; needs >= {t_min:.3g} s"
            )
        trace = minimum_jerk(self.state, goal, duration, cfg.rate_hz)
        self.state = goal.copy()
        return trace

    def dwell(self, duration_s: float, tremor: float = 0.0) -> Array:
        """Hold still for ``duration_s``; ``tremor`` adds seeded noise of that standard
        deviation (rad and mm alike) around the held state. Returns (k, 4)."""
        k = max(1, int(round(duration_s * self.config.rate_hz)))
        trace = np.repeat(self.state[None, :], k, axis=0)
        if tremor > 0:
            trace = trace + self.rng.normal(0.0, tremor, size=trace.shape)
            trace = np.clip(trace, self.config.box_low, self.config.box_high)
            trace[-1] = self.state
        return trace

    def explore(self, n_moves: int) -> Array:
        """``n_moves`` moves to seeded random targets within ``explore_reach`` of the current
        state (inside the box), each followed by a short random pause. Returns (k, 4)."""
        cfg = self.config
        reach = np.array(cfg.explore_reach)
        parts = []
        for _ in range(int(n_moves)):
            target = self.state + self.rng.uniform(-reach, reach)
            parts.append(self.move_to(target))
            pause = float(self.rng.uniform(0.0, 0.3))
            if pause >= 1.0 / cfg.rate_hz:
                parts.append(self.dwell(pause))
        return np.concatenate(parts) if parts else np.empty((0, 4))


def drive(
    trace: ArrayLike, robot: RobotBackend | None = None, roadmap: Roadmap | None = None
) -> Array:
    """Replay an operator trace: command each state on ``robot`` and record the measured
    state in ``roadmap`` (either may be None). Returns the (k, 4) recorded states."""
    arr = np.asarray(trace, np.float64).reshape(-1, 4)
    out = np.empty_like(arr)
    for i, q in enumerate(arr):
        if robot is not None:
            robot.command_position(q)
            q_meas = np.asarray(robot.read_state().q, np.float64)
        else:
            q_meas = q
        if roadmap is not None:
            roadmap.add(q_meas, check=False)
        out[i] = q_meas
    return out
