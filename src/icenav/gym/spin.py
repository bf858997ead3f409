"""``icenav/Spin-v0``: correct the image-spinning commands so the tip follows its intended pose.

The task of ``icenav eval spin`` (the paper's Table I): from an initial AP bend the image
plane turns 360 deg about the tip axis with the tip fixed (model joint path
``q_model(k)``, :func:`icenav.geometry.trajectories.spin_trajectory`, ``n_samples`` samples,
end included). Each episode (``reset(seed=...)``) draws a catheter, a vessel and a bend,
relaxes the catheter and drives the approach from rest to the spin's start open loop
(``approach_steps`` straight-line steps), exactly as the evaluation does. At step ``k`` the
agent adds a correction to the model command: the motor command is
``q_model(k) + a * max_correction`` (knobs clipped to +-90 deg). With zero corrections an
episode is the evaluation's ``none`` condition, sample for sample (tested).

Spaces (rad, mm)
----------------
- action: float32 (4,) in [-1, 1], the correction (phi1, phi2, phi3, d4) as a fraction of
  ``max_correction`` (default 15 deg per knob and roll, 5 mm): normalised, as RL libraries
  want it.
- observation: float32 (16,):
  ``[0:3]`` EM-tracked tip position minus the intended one (mm, base frame);
  ``[3:6]`` rotation error (rad): the rotation vector that turns the measured tip frame
  onto the intended one, in the measured tip frame (:func:`icenav.refinement.pose_stage.
  pose_error`); both 0 when the tracker reports MISSING or before the first sample;
  ``[6]`` 1 if ``[0:6]`` hold a valid measurement, else 0;
  ``[7:11]`` the model command of the next step ``q_model(k)`` (rad, rad, rad, mm);
  ``[11:15]`` the previous action (normalised correction); ``[15]`` progress ``k / n_samples``.
- reward: ``-(e_pos / position_scale_mm + e_rot / rotation_scale_deg)`` with the errors as
  ``eval spin`` measures them: ``e_pos`` the distance of the tip from the intended tip
  (mm), ``e_rot`` the angle between the intended and the tip orientation (deg); from the
  twin's true pose (``reward_from="true"``, the default) or from the EM tracker
  (``"em"``, the paper's protocol; a MISSING sample repeats the last valid error).
- truncation after the last sample; no termination.

``info``: ``true_position_error_mm``, ``true_rotation_error_deg``, ``em_position_error_mm``,
``em_rotation_error_deg`` (NaN when MISSING), ``catheter_seed``, ``vessel``, ``bend_deg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from icenav._typing import Array
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, forward
from icenav.geometry.trajectories import spin_trajectory
from icenav.gym.population import (
    TRAINING_CATHETERS,
    PlantFactory,
    check_seed_range,
    default_plant_factory,
)
from icenav.refinement.pose_stage import pose_error
from icenav.sim.params import Vessel

__all__ = ["OBSERVATION_SIZE", "SpinConfig", "SpinEnv", "rotation_angle_deg"]

_DEG = math.pi / 180.0
OBSERVATION_SIZE = 16
"""Length of the observation vector."""


def rotation_angle_deg(r_a: Array, r_b: Array) -> float:
    """Angle (deg, in [0, 180]) of the rotation between the (3, 3) rotations ``r_a``, ``r_b``
    (from the cosine and the sine, robust near 0 and 180 deg)."""
    rel = r_a.T @ r_b
    cos = 0.5 * (float(np.trace(rel)) - 1.0)
    sk = rel - rel.T
    sin = 0.5 * math.sqrt(float(sk[0, 1] ** 2 + sk[0, 2] ** 2 + sk[1, 2] ** 2))
    return math.degrees(math.atan2(sin, cos))


@dataclass(frozen=True)
class SpinConfig:
    """Settings of :class:`SpinEnv` (each also a keyword of ``gymnasium.make``)."""

    n_samples: int = 360
    """Samples of the spin (steps of an episode); the paper's 360."""
    bends_deg: tuple[float, ...] = (20.0, 40.0, 60.0)
    """Initial AP bends drawn from (deg); the paper's."""
    vessels: tuple[str, ...] = ("straight",)
    """Vessels drawn from (straight, moderate, steep)."""
    catheter_seeds: tuple[int, int] = TRAINING_CATHETERS
    """Half-open range of catheter seeds drawn from."""
    max_correction: tuple[float, float, float, float] = (15 * _DEG, 15 * _DEG, 15 * _DEG, 5.0)
    """Largest correction of the model command (rad, rad, rad, mm): action 1 is this."""
    position_scale_mm: float = 5.0
    """Position error that costs 1 per step (mm)."""
    rotation_scale_deg: float = 10.0
    """Rotation error that costs 1 per step (deg)."""
    reward_from: str = "true"
    """"true": the twin's true tip pose; "em": the EM tracker's."""
    approach_steps: int = 20
    """Open-loop steps from rest to the spin's start (as ``eval spin``)."""
    plant_factory: PlantFactory = field(default=default_plant_factory, compare=False)
    """``factory(seed, vessel) -> (plant, tracker)``."""

    def __post_init__(self) -> None:
        if isinstance(self.n_samples, bool) or not 2 <= int(self.n_samples) <= 10_000:
            raise ConfigurationError(f"n_samples must be in [2, 10000], got {self.n_samples!r}")
        lim = math.degrees(DEFAULT_GEOMETRY.knob_limit)
        if not self.bends_deg or any(not 0.0 < float(b) <= lim for b in self.bends_deg):
            raise ConfigurationError(
                f"bends_deg must be in (0, {lim:.0f}] deg, got {self.bends_deg!r}"
            )
        if not self.vessels:
            raise ConfigurationError("vessels must name at least one vessel")
        for v in self.vessels:
            Vessel.named(v)
        check_seed_range(self.catheter_seeds, "catheter_seeds")
        c = np.asarray(self.max_correction, dtype=np.float64)
        if c.shape != (4,) or not np.all(np.isfinite(c)) or np.any(c <= 0):
            raise ConfigurationError(
                f"max_correction must be 4 positive numbers (rad, rad, rad, mm), got "
                f"{self.max_correction!r}"
            )
        for name in ("position_scale_mm", "rotation_scale_deg"):
            if not float(getattr(self, name)) > 0:
                raise ConfigurationError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if self.reward_from not in ("true", "em"):
            raise ConfigurationError(
                f"reward_from must be 'true' or 'em', got {self.reward_from!r}"
            )
        if isinstance(self.approach_steps, bool) or not 1 <= int(self.approach_steps) <= 1000:
            raise ConfigurationError(
                f"approach_steps must be in [1, 1000], got {self.approach_steps!r}"
            )


class SpinEnv(gymnasium.Env[Any, Any]):
    """Spin the image plane with corrected commands (see the module docstring).

    Parameters
    ----------
    config : SpinConfig, optional
        Settings; keywords override its fields (``SpinEnv(n_samples=120)``).

    ``reset(seed=..., options=...)``: options ``catheter_seed``, ``vessel`` and ``bend_deg``
    pin what is otherwise drawn.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, config: SpinConfig | None = None, **overrides: Any) -> None:
        cfg = config if config is not None else SpinConfig()
        self.config = cfg = replace(cfg, **overrides) if overrides else cfg
        self._max_correction = np.asarray(cfg.max_correction, dtype=np.float64)
        self.action_space: spaces.Box = spaces.Box(-1.0, 1.0, (4,), dtype=np.float32)
        c = np.ones(4)
        lim = DEFAULT_GEOMETRY.knob_limit
        lo, hi = DEFAULT_GEOMETRY.translation_limits
        roll = 2 * math.pi + math.pi
        low = np.concatenate(
            [
                [-200.0] * 3,
                [-math.pi] * 3,
                [0.0],
                [-lim, -lim, -roll, lo],
                -c,
                [0.0],
            ]
        ).astype(np.float32)
        high = np.concatenate(
            [[200.0] * 3, [math.pi] * 3, [1.0], [lim, lim, roll, hi], c, [1.0]]
        ).astype(np.float32)
        self._obs_low, self._obs_high = low, high
        self.observation_space: spaces.Box = spaces.Box(low, high, dtype=np.float32)
        self._plant: Any = None
        self._tracker: Any = None
        self._k = 0
        self._last_em = (0.0, 0.0)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Array, dict[str, Any]]:
        super().reset(seed=seed)
        cfg = self.config
        opts = dict(options or {})
        rng = self.np_random
        lo, hi = cfg.catheter_seeds
        cath = int(opts.pop("catheter_seed", rng.integers(lo, hi)))
        vessel = str(opts.pop("vessel", cfg.vessels[int(rng.integers(len(cfg.vessels)))]))
        bend = float(opts.pop("bend_deg", cfg.bends_deg[int(rng.integers(len(cfg.bends_deg)))]))
        if opts:
            raise ConfigurationError(f"unknown reset option(s) {sorted(opts)}")
        sp = spin_trajectory([math.radians(bend), 0.0, 0.0, 0.0], cfg.n_samples, include_end=True)
        self._q_model = sp.q_model
        self._intended = forward(sp.q_model, check=False)
        self._plant, self._tracker = cfg.plant_factory(cath, vessel)
        self._plant.reset()
        # the approach from rest to the spin's start, open loop (eval spin's protocol)
        n = cfg.approach_steps
        for q in np.linspace(np.zeros(4), sp.q_model[0], n + 1)[1:]:
            self._plant.move(q)
        self._k = 0
        self._last_em = (0.0, 0.0)
        self._correction = np.zeros(4)
        self._info = {"catheter_seed": cath, "vessel": vessel, "bend_deg": bend}
        return self._observation(None), dict(self._info)

    def step(self, action: Array) -> tuple[Array, float, bool, bool, dict[str, Any]]:
        if self._plant is None:
            raise ConfigurationError("call reset() before step()")
        if self._k >= self.config.n_samples:
            raise ConfigurationError("the spin is over: call reset()")
        cfg = self.config
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (4,) or not np.all(np.isfinite(a)):
            raise ConfigurationError(f"action must be 4 finite corrections, got {action!r}")
        a = np.clip(a, self.action_space.low, self.action_space.high)
        k = self._k
        q = self._q_model[k] + a * self._max_correction
        lim = DEFAULT_GEOMETRY.knob_limit
        q[:2] = np.clip(q[:2], -lim, lim)
        true = self._plant.move(q)
        em = self._tracker.measure_tip2base()
        intended = self._intended[k]
        p0 = self._intended[0, :3, 3]  # the spin keeps the tip where it starts
        tp = float(np.linalg.norm(true[:3, 3] - p0))
        tr = rotation_angle_deg(intended[:3, :3], true[:3, :3])
        if em is None:
            ep = er = math.nan
        else:
            ep = float(np.linalg.norm(em[:3, 3] - p0))
            er = rotation_angle_deg(intended[:3, :3], em[:3, :3])
            self._last_em = (ep, er)
        if cfg.reward_from == "true":
            pos, rot = tp, tr
        else:
            pos, rot = self._last_em
        reward = -(pos / cfg.position_scale_mm + rot / cfg.rotation_scale_deg)
        self._correction = a
        self._k = k + 1
        truncated = self._k >= cfg.n_samples
        info = {
            **self._info,
            "true_position_error_mm": tp,
            "true_rotation_error_deg": tr,
            "em_position_error_mm": ep,
            "em_rotation_error_deg": er,
        }
        return self._observation(em), float(reward), False, truncated, info

    def _observation(self, em: Array | None) -> Array:
        k = min(self._k, self.config.n_samples - 1)
        obs = np.zeros(OBSERVATION_SIZE)
        if em is not None:
            target = self._intended[self._k - 1]
            obs[0:3] = em[:3, 3] - self._intended[0, :3, 3]
            obs[3:6] = pose_error(target, em)[3:]
            obs[6] = 1.0
        obs[7:11] = self._q_model[k]
        obs[11:15] = self._correction
        obs[15] = self._k / self.config.n_samples
        out: Array = np.clip(obs, self._obs_low, self._obs_high).astype(np.float32)
        return out
