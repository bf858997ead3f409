"""``icenav/ViewFinding-v0``: steer the twin's catheter until the ICE image shows a target view.

Each episode (``reset(seed=...)``) draws a catheter (:data:`~icenav.gym.population.
TRAINING_CATHETERS`), a patient (:func:`~icenav.gym.population.sample_patient`), a vessel
and a target view (:data:`icenav.sim.anatomy.EXAMPLE_VIEWS`), and relaxes the catheter at a
random start near the home view. The target is one heart beat of images rendered at the
view's pose (``base2anatomy @ forward(q_view)``: where the kinematic model puts the view) in
this patient; the catheter's own elasticity and play stand between the agent's commands
and that pose.

Spaces (units as the project's: rad, mm, s)
-------------------------------------------
- observation: ``{"image": uint8 (S, S, 1), "q": float32 (4,)}``: the ICE B-mode picture
  (:class:`icenav.sim.ultrasound.UltrasoundRenderer`, S = ``image_size``, apex at the top
  middle) and the commanded motor joint state (phi1, phi2, phi3 rad; d4 mm) within the
  environment's box (knobs +-90 deg, roll +-``roll_limit_rad``, translation
  +-``translation_limit_mm``).
- action: float32 (4,), the joint increment of this step, bounded by ``max_increment``
  (default +-2 deg per knob, +-5 deg roll, +-1 mm translation). A step that would leave the
  box stops at its edge (``info["clipped"]``).
- reward: ``s - 1 - contact_penalty_per_n * F`` (+ ``success_bonus`` on success), with ``s``
  the blurred NCC of the picture with the target frame nearest in cardiac phase, over the
  sector (:func:`icenav.refinement.similarity.beat_score`, in [-1, 1]) and ``F`` the
  contact force of the catheter on the anatomy (N), read as
  ``getattr(plant.state, "contact_force_n", 0.0)``: 0 for a plant without contact, the
  force once the twin models contact. Every step costs, less the closer the view.
- termination: ``s >= similarity_threshold`` (the view is found); truncation after
  ``max_steps`` steps. One step is one frame (``frame_time_s``): the heart beats on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from icenav._typing import Array
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, forward
from icenav.gym.population import (
    TRAINING_CATHETERS,
    Patient,
    PlantFactory,
    check_seed_range,
    default_plant_factory,
    sample_patient,
)
from icenav.recovery.beats import BeatClip
from icenav.refinement.similarity import beat_score
from icenav.sim.anatomy import EXAMPLE_VIEWS
from icenav.sim.params import Vessel
from icenav.sim.ultrasound import Frame, ProbeConfig, UltrasoundRenderer

__all__ = ["ViewFindingConfig", "ViewFindingEnv"]

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class ViewFindingConfig:
    """Settings of :class:`ViewFindingEnv` (each also a keyword of ``gymnasium.make``)."""

    image_size: int = 64
    """Side of the square ICE picture (pixels)."""
    n_beams: int | None = None
    """Beams of the renderer's polar grid (default: ``image_size``)."""
    n_samples: int | None = None
    """Samples per beam (default: ``2 * image_size``)."""
    frame_time_s: float = 1.0 / 30.0
    """Time of one step (s): one ICE frame."""
    max_steps: int = 200
    """Steps before the episode is truncated."""
    similarity_threshold: float = 0.85
    """The view is found when the similarity reaches this value."""
    contact_penalty_per_n: float = 0.5
    """Reward lost per newton of contact force."""
    success_bonus: float = 0.0
    """Reward added on the step that finds the view."""
    max_increment: tuple[float, float, float, float] = (2 * _DEG, 2 * _DEG, 5 * _DEG, 1.0)
    """Largest joint increment per step (rad, rad, rad, mm): the action's bounds."""
    roll_limit_rad: float = math.pi
    """The environment's roll range: +- this (rad)."""
    translation_limit_mm: float = 30.0
    """The environment's translation range: +- this (mm), within the geometry's."""
    start_knob_rad: float = 10 * _DEG
    """Start: each knob uniform in +- this (rad); roll uniform in the roll range."""
    start_translation_mm: float = 10.0
    """Start: translation uniform in +- this (mm)."""
    views: tuple[str, ...] = tuple(EXAMPLE_VIEWS)
    """Target views drawn from (names of ``EXAMPLE_VIEWS``)."""
    vessels: tuple[str, ...] = ("straight",)
    """Vessels drawn from (straight, moderate, steep)."""
    catheter_seeds: tuple[int, int] = TRAINING_CATHETERS
    """Half-open range of catheter seeds drawn from."""
    target_phases: int = 8
    """Frames of the target beat (cardiac phases)."""
    similarity_sigma_px: float = 1.0
    """Gaussian blur of the similarity (pixels)."""
    plant_factory: PlantFactory = field(default=default_plant_factory, compare=False)
    """``factory(seed, vessel) -> (plant, tracker)`` (the tracker is not used here)."""

    def __post_init__(self) -> None:
        size = self.image_size
        if isinstance(size, bool) or not isinstance(size, int) or not 16 <= size <= 512:
            raise ConfigurationError(f"image_size must be an int in [16, 512] pixels, got {size!r}")
        for name, lo, hi, unit in (
            ("frame_time_s", 1e-3, 1.0, "s"),
            ("similarity_threshold", -1.0, 1.0, ""),
            ("contact_penalty_per_n", 0.0, 1e3, "per N"),
            ("success_bonus", 0.0, 1e3, ""),
            ("roll_limit_rad", 0.1, 4 * math.pi, "rad"),
            ("translation_limit_mm", 1.0, 50.0, "mm"),
            ("start_knob_rad", 0.0, math.pi / 2, "rad"),
            ("similarity_sigma_px", 0.1, 16.0, "px"),
        ):
            v = float(getattr(self, name))
            if not lo <= v <= hi:
                raise ConfigurationError(f"{name} must be in [{lo}, {hi}] {unit}, got {v}")
        if not 0.0 <= self.start_translation_mm <= self.translation_limit_mm:
            raise ConfigurationError(
                f"start_translation_mm must be in [0, translation_limit_mm = "
                f"{self.translation_limit_mm}] mm, got {self.start_translation_mm}"
            )
        inc = np.asarray(self.max_increment, dtype=np.float64)
        if inc.shape != (4,) or not np.all(np.isfinite(inc)) or np.any(inc <= 0):
            raise ConfigurationError(
                f"max_increment must be 4 positive numbers (rad, rad, rad, mm), got "
                f"{self.max_increment!r}"
            )
        if isinstance(self.max_steps, bool) or not 1 <= int(self.max_steps) <= 100_000:
            raise ConfigurationError(f"max_steps must be in [1, 100000], got {self.max_steps!r}")
        if not 1 <= int(self.target_phases) <= 64:
            raise ConfigurationError(
                f"target_phases must be in [1, 64] frames, got {self.target_phases!r}"
            )
        bad = [v for v in self.views if v not in EXAMPLE_VIEWS]
        if bad or not self.views:
            raise ConfigurationError(f"unknown view(s) {bad}; choose from {list(EXAMPLE_VIEWS)}")
        for vessel in self.vessels:
            Vessel.named(vessel)  # raises ConfigurationError naming the known vessels
        if not self.vessels:
            raise ConfigurationError("vessels must name at least one vessel")
        check_seed_range(self.catheter_seeds, "catheter_seeds")

    def probe(self) -> ProbeConfig:
        """The renderer's settings: the default probe at this picture size."""
        n = self.image_size
        return ProbeConfig(
            image_size=n,
            n_beams=self.n_beams or n,
            n_samples=self.n_samples or 2 * n,
            speckle_reduction_px=1.5 * n / 256.0,
        )


class ViewFindingEnv(gymnasium.Env[dict[str, Any], Any]):
    """Find a target ICE view with the twin's catheter (see the module docstring).

    Parameters
    ----------
    config : ViewFindingConfig, optional
        Settings; keywords override its fields (``ViewFindingEnv(image_size=128)``).
    render_mode : "rgb_array", optional
        ``render()`` returns the current picture beside the target (H, 2 W, 3) uint8.

    ``reset(seed=..., options=...)``: options ``catheter_seed``, ``patient_seed``,
    ``view``, ``vessel`` and ``q_start`` (motor joint state) pin what is otherwise drawn.
    ``info``: ``similarity``, ``contact_force_n``, ``clipped``, ``catheter_seed``,
    ``patient_seed``, ``view``, ``vessel``, ``tip2anatomy`` (4, 4) (mm).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}
    q_low: Array
    """(4,) lower corner of the environment's joint box (rad, rad, rad, mm; float64)."""
    q_high: Array
    """(4,) upper corner of the joint box."""

    def __init__(
        self,
        config: ViewFindingConfig | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        cfg = config if config is not None else ViewFindingConfig()
        self.config = cfg = replace(cfg, **overrides) if overrides else cfg
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ConfigurationError(
                f"render_mode must be 'rgb_array' or None, got {render_mode!r}"
            )
        self.render_mode = render_mode
        n = cfg.image_size
        lim = DEFAULT_GEOMETRY.knob_limit
        self.q_low = np.array([-lim, -lim, -cfg.roll_limit_rad, -cfg.translation_limit_mm])
        self.q_high = -self.q_low
        self.observation_space: spaces.Dict = spaces.Dict(
            {
                "image": spaces.Box(0, 255, (n, n, 1), np.uint8),
                "q": spaces.Box(self.q_low.astype(np.float32), self.q_high.astype(np.float32)),
            }
        )
        inc = np.asarray(cfg.max_increment, dtype=np.float32)
        self.action_space: spaces.Box = spaces.Box(-inc, inc, dtype=np.float32)
        # one renderer (the speckle texture is the probe's); each patient brings its phantom
        self._renderer = UltrasoundRenderer(config=cfg.probe())
        self._mask: NDArray[np.bool_] | None = None
        self._plant: Any = None
        self._q = np.zeros(4)
        self._t = 0.0
        self._steps = 0
        self._noise0 = 0
        self._targets: list[BeatClip] = []
        self._target_phases = np.zeros(0)
        self._frame: Frame | None = None
        self._info: dict[str, Any] = {}

    # --- episode -------------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        super().reset(seed=seed)
        cfg = self.config
        opts = dict(options or {})
        rng = self.np_random
        lo, hi = cfg.catheter_seeds
        cath = int(opts.pop("catheter_seed", rng.integers(lo, hi)))
        pat_seed = int(opts.pop("patient_seed", rng.integers(0, 2**31 - 1)))
        view = str(opts.pop("view", cfg.views[int(rng.integers(len(cfg.views)))]))
        vessel = str(opts.pop("vessel", cfg.vessels[int(rng.integers(len(cfg.vessels)))]))
        q0 = np.array(
            [
                rng.uniform(-cfg.start_knob_rad, cfg.start_knob_rad),
                rng.uniform(-cfg.start_knob_rad, cfg.start_knob_rad),
                rng.uniform(-cfg.roll_limit_rad, cfg.roll_limit_rad),
                rng.uniform(-cfg.start_translation_mm, cfg.start_translation_mm),
            ]
        )
        if "q_start" in opts:
            q0 = np.asarray(opts.pop("q_start"), dtype=np.float64)
            if q0.shape != (4,) or np.any(q0 < self.q_low) or np.any(q0 > self.q_high):
                raise ConfigurationError(
                    f"q_start must be 4 values within {self.q_low.tolist()} .. "
                    f"{self.q_high.tolist()} (rad, rad, rad, mm), got {q0.tolist()}"
                )
        if opts:
            raise ConfigurationError(f"unknown reset option(s) {sorted(opts)}")
        if view not in EXAMPLE_VIEWS:
            raise ConfigurationError(f"unknown view {view!r}; choose from {list(EXAMPLE_VIEWS)}")
        self._noise0 = int(rng.integers(0, 2**30))
        patient = sample_patient(pat_seed)
        self._patient: Patient = patient
        self._base2anatomy = patient.base2anatomy
        self._renderer.phantom = patient.phantom()
        self._plant, _ = cfg.plant_factory(cath, vessel)
        self._plant.reset(q0)
        self._q = q0
        self._steps = 0
        self._t = float(rng.uniform(0.0, self._renderer.phantom.motion.period_s))
        self._build_targets(view)
        self._info = {
            "catheter_seed": cath,
            "patient_seed": pat_seed,
            "view": view,
            "vessel": vessel,
        }
        obs, similarity, force = self._observe()
        info = self._step_info(similarity, force, clipped=False)
        return obs, info

    def step(self, action: Array) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        if self._plant is None:
            raise ConfigurationError("call reset() before step()")
        cfg = self.config
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (4,) or not np.all(np.isfinite(a)):
            raise ConfigurationError(f"action must be 4 finite increments, got {action!r}")
        a = np.clip(a, self.action_space.low, self.action_space.high)
        want = self._q + a
        q = np.clip(want, self.q_low, self.q_high)
        clipped = bool(np.any(q != want))
        self._plant.move(q)
        self._q = q
        self._steps += 1
        self._t += cfg.frame_time_s
        obs, similarity, force = self._observe()
        terminated = similarity >= cfg.similarity_threshold
        reward = similarity - 1.0 - cfg.contact_penalty_per_n * force
        if terminated:
            reward += cfg.success_bonus
        truncated = not terminated and self._steps >= cfg.max_steps
        return (
            obs,
            float(reward),
            terminated,
            truncated,
            self._step_info(similarity, force, clipped),
        )

    def render(self) -> Array | None:
        """The current picture beside the target (nearest phase): (S, 2 S, 3) uint8."""
        if self.render_mode != "rgb_array" or self._frame is None:
            return None
        target = self._nearest_target(self._frame.cardiac_phase)
        pair = np.hstack([self._frame.image, target.images[0].astype(np.uint8)])
        out: Array = np.repeat(pair[..., None], 3, axis=2)
        return out

    # --- internals -----------------------------------------------------------------------

    def _tip2anatomy(self, tip2base: Array) -> Array:
        out: Array = self._base2anatomy @ tip2base
        return out

    def _build_targets(self, view: str) -> None:
        """One beat of target frames at the view's model pose, ``target_phases`` phases."""
        cfg = self.config
        pose = self._tip2anatomy(forward(np.asarray(EXAMPLE_VIEWS[view]), check=False))
        period = self._renderer.phantom.motion.period_s
        frames = [
            self._renderer.render(pose, k * period / cfg.target_phases, noise_seed=k, check=False)
            for k in range(cfg.target_phases)
        ]
        self._mask = frames[0].labels >= 0
        self._targets = [
            BeatClip(f.image[None].astype(np.float64), np.array([f.cardiac_phase]), self._mask)
            for f in frames
        ]
        self._target_phases = np.array([f.cardiac_phase for f in frames])
        self._target_pose = pose

    def _nearest_target(self, phase: float) -> BeatClip:
        d = np.abs(self._target_phases - phase)
        d = np.minimum(d, 1.0 - d)  # phases wrap at one beat
        return self._targets[int(np.argmin(d))]

    def _observe(self) -> tuple[dict[str, Any], float, float]:
        pose = self._tip2anatomy(self._plant.state.tip2base)
        seed = (self._noise0 + self._steps) & 0x7FFFFFFF
        frame = self._renderer.render(pose, self._t, noise_seed=seed, check=False)
        self._frame = frame
        clip = BeatClip(frame.image[None].astype(np.float64), np.array([frame.cardiac_phase]))
        sigma = self.config.similarity_sigma_px
        similarity = beat_score(
            clip, self._nearest_target(frame.cardiac_phase), sigma_px=sigma, factor=1
        )
        # the contact force once the twin models contact (0 for a plant without it)
        force = float(getattr(self._plant.state, "contact_force_n", 0.0))
        obs = {"image": frame.image[..., None].copy(), "q": self._q.astype(np.float32)}
        return obs, float(similarity), force

    def _step_info(self, similarity: float, force: float, clipped: bool) -> dict[str, Any]:
        assert self._frame is not None
        return {
            **self._info,
            "similarity": similarity,
            "contact_force_n": force,
            "clipped": clipped,
            "tip2anatomy": self._frame.tip2anatomy,
        }
