"""A simulated electromagnetic tracker (NDI 3D Guidance / Aurora-like) at the catheter tip.

The sensor is fixed to the tip (``sensor2tip``); the field generator is fixed to the robot
(``tracker2base``). Each sample reports ``sensor2tracker`` with the error a real EM tracker
shows (equations (E1)-(E3) of docs/digital-twin.md)::

    p_meas = p_true + b(p_true) + j,      j ~ N(0, (jitter / sqrt 3)^2 I3)         # (E1)
    R_meas = Exp(c(p_true) + k) R_true,   k ~ N(0, (rot_jitter / sqrt 3)^2 I3)     # (E2)
    b(p) = sum_m a_m sin(w_m . p + phase_m),  |w_m| = 2 pi / wavelength          # (E3)

``b`` (and ``c`` for orientation) is a smooth, position-dependent field distortion, fixed
for a given seed (the "static" error of the tracker); ``j``, ``k`` are per-sample jitter. The
tracker samples at its own rate, reports a sample ``latency_s`` after its acquisition, drops
samples in short bursts (status MISSING, pose None) and flags poses outside its measurement
volume (OUT_OF_VOLUME, pose None). A stale pose is never reported as VALID: each call reports
the newest sample, and the same sample (same timestamp) until a newer one is due.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from icenav._typing import Array
from icenav._validation import check_transform
from icenav.devices.registration import Registration
from icenav.devices.tracker import ToolStatus, TrackerFrame, check_n_average, mean_sensor_pose
from icenav.errors import ConfigurationError, TrackerError
from icenav.geometry.se3 import rigid_inverse, rotvec_to_matrix
from icenav.sim.plant import CatheterPlant

__all__ = [
    "DEFAULT_SENSOR2TIP",
    "DEFAULT_TRACKER2BASE",
    "EMTracker",
    "ToolStatus",
    "TrackerConfig",
    "TrackerFrame",
    "rotvec_to_matrix",  # from icenav.geometry.se3 (kept for the twin's users)
]


def _make_transform(rotvec: tuple[float, float, float], trans: tuple[float, float, float]) -> Array:
    t = np.eye(4)
    t[:3, :3] = rotvec_to_matrix(np.array(rotvec, dtype=np.float64))
    t[:3, 3] = trans
    t.setflags(write=False)
    return t


DEFAULT_TRACKER2BASE = rigid_inverse(_make_transform((math.pi / 2, 0.0, 0.0), (20.0, -30.0, 280.0)))
"""Default registration: the field generator about 28 cm from the base, turned 90 deg."""
DEFAULT_TRACKER2BASE.setflags(write=False)
DEFAULT_SENSOR2TIP = _make_transform((0.0, 0.0, 0.0), (-1.0, 0.0, -4.0))
"""Default sensor mount: 4 mm proximal of the image centre, 1 mm off-axis (mm)."""


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of the simulated EM tracker (defaults: NDI 3D Guidance, Model 800 sensor)."""

    rate_hz: float = 80.0
    """Sample rate (Hz)."""
    latency_s: float = 0.012
    """Time between acquisition and report (s)."""
    position_bias_rms_mm: float = 1.3
    """RMS of the smooth field-distortion position error over the volume (mm)."""
    position_jitter_rms_mm: float = 0.5
    """RMS of the per-sample position jitter (mm); total RMS = hypot(bias, jitter) = 1.39 mm."""
    rotation_bias_rms_rad: float = math.radians(0.45)
    """RMS of the smooth orientation distortion (rad)."""
    rotation_jitter_rms_rad: float = math.radians(0.2)
    """RMS of the per-sample orientation jitter (rad); total RMS 0.49 deg."""
    distortion_wavelength_mm: float = 250.0
    """Spatial wavelength of the field distortion (mm): how fast the bias varies in space."""
    dropout_probability: float = 0.01
    """Probability that a sample starts a dropout burst."""
    dropout_mean_samples: float = 3.0
    """Mean length of a dropout burst (samples, >= 1)."""
    volume_min_mm: tuple[float, float, float] = (-250.0, -250.0, 50.0)
    """Lower corner of the measurement volume in the tracker frame (mm)."""
    volume_max_mm: tuple[float, float, float] = (250.0, 250.0, 550.0)
    """Upper corner of the measurement volume in the tracker frame (mm)."""
    tracker2base: Array = field(default_factory=lambda: DEFAULT_TRACKER2BASE)
    """(4, 4) fixed pose of the tracker frame in the robot base frame (mm)."""
    sensor2tip: Array = field(default_factory=lambda: DEFAULT_SENSOR2TIP)
    """(4, 4) fixed pose of the sensor in the tip (image centre) frame (mm)."""

    def __post_init__(self) -> None:
        def positive(name: str, unit: str) -> None:
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ConfigurationError(f"{name} must be finite and > 0 {unit}, got {v} {unit}")

        def nonneg(name: str, unit: str) -> None:
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v >= 0):
                raise ConfigurationError(f"{name} must be finite and >= 0 {unit}, got {v} {unit}")

        positive("rate_hz", "Hz")
        positive("distortion_wavelength_mm", "mm")
        for name, unit in (
            ("latency_s", "s"),
            ("position_bias_rms_mm", "mm"),
            ("position_jitter_rms_mm", "mm"),
            ("rotation_bias_rms_rad", "rad"),
            ("rotation_jitter_rms_rad", "rad"),
        ):
            nonneg(name, unit)
        pd = float(self.dropout_probability)
        if not (0.0 <= pd < 1.0):
            raise ConfigurationError(f"dropout_probability must be in [0, 1), got {pd}")
        ml = float(self.dropout_mean_samples)
        if not (math.isfinite(ml) and ml >= 1.0):
            raise ConfigurationError(f"dropout_mean_samples must be >= 1 samples, got {ml}")
        lo = np.asarray(self.volume_min_mm, dtype=np.float64)
        hi = np.asarray(self.volume_max_mm, dtype=np.float64)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(lo < hi):
            raise ConfigurationError(
                f"volume_min_mm must be below volume_max_mm on every axis (mm), "
                f"got {self.volume_min_mm} and {self.volume_max_mm}"
            )
        for name in ("tracker2base", "sensor2tip"):
            arr = check_transform(getattr(self, name), name)
            if arr.shape != (4, 4):
                raise ConfigurationError(f"{name} must be one (4, 4) transform, got {arr.shape}")
            arr = arr.copy()
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)


class _Field:
    """The smooth distortion field b(p) (E3): a sum of plane waves with random directions."""

    def __init__(self, rng: np.random.Generator, rms: float, wavelength: float, n: int = 12):
        dirs = rng.normal(size=(n, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        self.w = dirs * (2.0 * math.pi / wavelength)
        self.phase = rng.uniform(0.0, 2.0 * math.pi, size=n)
        # E|b|^2 = sum |a_m|^2 / 2 = 3 n sigma^2 / 2 = rms^2
        self.a = rng.normal(size=(n, 3)) * (rms * math.sqrt(2.0 / (3.0 * n)))

    def __call__(self, p: Array) -> Array:
        return np.sin(p @ self.w.T + self.phase) @ self.a


class EMTracker:
    """Simulated EM tracker observing one :class:`CatheterPlant` (the usual tracker shape).

    Parameters
    ----------
    plant : CatheterPlant
        The catheter whose true tip pose is measured.
    seed : int
        Seeds the field distortion (fixed for the tracker's life) and the noise stream.
    config : TrackerConfig
        Rate, latency, noise, dropouts, volume and the fixed transforms.
    clock : callable returning seconds, optional
        Time source (default ``time.monotonic``); tests inject a fake clock.
    """

    def __init__(
        self,
        plant: CatheterPlant,
        seed: int = 0,
        config: TrackerConfig | None = None,
        clock: Callable[[], float] | None = None,
    ) -> None:
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
            raise ConfigurationError(f"seed must be an integer >= 0, got {seed!r}")
        self.plant = plant
        self.config = TrackerConfig() if config is None else config
        self.clock: Callable[[], float] = time.monotonic if clock is None else clock
        cfg = self.config
        field_rng = np.random.default_rng([int(seed), 0xE1])
        self._pos_field = _Field(field_rng, cfg.position_bias_rms_mm, cfg.distortion_wavelength_mm)
        self._rot_field = _Field(field_rng, cfg.rotation_bias_rms_rad, cfg.distortion_wavelength_mm)
        self._rng = np.random.default_rng([int(seed), 0xE2])
        self._base2tracker = rigid_inverse(cfg.tracker2base)
        self.registration: Registration | None = Registration.given(
            cfg.tracker2base, cfg.sensor2tip
        )
        """What :meth:`measure_tip2base` maps through: by default the twin's true
        ``tracker2base`` and ``sensor2tip``; set it to an estimated registration (the
        ``registration`` calibration procedure) to run the twin as a lab would, or to None
        (unregistered: no ``tip2base``)."""
        self._running = False
        self._t0 = 0.0
        self._last_index = -1
        self._last_frame: TrackerFrame | None = None
        self._dropout_left = 0

    # --- lifecycle -----------------------------------------------------------------------

    def start(self) -> None:
        """Start sampling; the first sample is acquired now and reported after the latency."""
        self._running = True
        self._t0 = float(self.clock())
        self._last_index = -1
        self._last_frame = None
        self._dropout_left = 0

    def stop(self) -> None:
        """Stop sampling; :meth:`get_frame` then raises TrackerError."""
        self._running = False

    @property
    def running(self) -> bool:
        """True between start() and stop()."""
        return self._running

    # --- measurement ---------------------------------------------------------------------

    def true_sensor2tracker(self) -> Array:
        """(4, 4) true pose of the sensor in the tracker frame (mm), without any error."""
        return self._base2tracker @ self.plant.state.tip2base @ self.config.sensor2tip

    def distortion_at(self, p_in_tracker: Array) -> tuple[Array, Array]:
        """Field distortion at points (..., 3) (mm): position bias (mm), rotation bias (rad)."""
        p = np.asarray(p_in_tracker, dtype=np.float64)
        return self._pos_field(p), self._rot_field(p)

    def _sample(self, timestamp: float) -> TrackerFrame:
        """Acquire one sample now (E1)-(E3), applying dropouts and the volume."""
        cfg = self.config
        if self._dropout_left > 0:
            self._dropout_left -= 1
            return TrackerFrame(timestamp, None, ToolStatus.MISSING, 0.0)
        if cfg.dropout_probability > 0 and self._rng.random() < cfg.dropout_probability:
            # burst length geometric with the configured mean
            length = int(self._rng.geometric(1.0 / cfg.dropout_mean_samples))
            self._dropout_left = length - 1
            return TrackerFrame(timestamp, None, ToolStatus.MISSING, 0.0)
        true = self.true_sensor2tracker()
        p = true[:3, 3]
        if np.any(p < np.asarray(cfg.volume_min_mm)) or np.any(p > np.asarray(cfg.volume_max_mm)):
            return TrackerFrame(timestamp, None, ToolStatus.OUT_OF_VOLUME, 0.0)
        bias_p, bias_r = self.distortion_at(p)
        jit_p = self._rng.normal(size=3) * (cfg.position_jitter_rms_mm / math.sqrt(3.0))
        jit_r = self._rng.normal(size=3) * (cfg.rotation_jitter_rms_rad / math.sqrt(3.0))
        meas = np.eye(4)
        meas[:3, :3] = rotvec_to_matrix(bias_r + jit_r) @ true[:3, :3]
        meas[:3, 3] = p + bias_p + jit_p
        scale = max(cfg.position_bias_rms_mm, 1e-9)
        quality = float(math.exp(-float(np.linalg.norm(bias_p)) / (2.0 * scale)))
        meas.setflags(write=False)
        return TrackerFrame(timestamp, meas, ToolStatus.VALID, quality)

    def get_frame(self) -> TrackerFrame:
        """The newest sample that is due on the tracker's clock.

        A new sample is acquired every ``1 / rate_hz`` s and reported ``latency_s`` later;
        between samples the same frame (same timestamp) is returned. Before the first sample
        is due, a MISSING frame. Raises TrackerError unless started.
        """
        if not self._running:
            raise TrackerError("the EM tracker is not running: call start() first")
        cfg = self.config
        now = float(self.clock())
        index = math.floor((now - self._t0 - cfg.latency_s) * cfg.rate_hz + 1e-9)
        if index < 0:
            return TrackerFrame(self._t0, None, ToolStatus.MISSING, 0.0)
        if index > self._last_index or self._last_frame is None:
            self._last_index = index
            self._last_frame = self._sample(self._t0 + index / cfg.rate_hz)
        return self._last_frame

    def measure_sensor2tracker(self, n_average: int = 1) -> Array | None:
        """Sensor pose (4, 4) in the tracker frame (mm), averaged over ``n_average`` fresh
        samples at the plant's current pose (on hardware this blocks for
        ``n_average / rate_hz`` s; here the samples are drawn at once): mean position,
        chordal mean rotation of the VALID ones; None when none was VALID. Does not need
        start()."""
        n = check_n_average(n_average)
        return mean_sensor_pose([self._sample(float(self.clock())) for _ in range(n)])

    def measure_tip2base(self, n_average: int = 1) -> Array | None:
        """Tracked tip pose (4, 4) in the base frame (mm) of :meth:`measure_sensor2tracker`
        through :attr:`registration`: ``tracker2base @ sensor2tracker @ inv(sensor2tip)``.
        None when no sample was VALID or the tracker is not registered (no sample drawn)."""
        n = check_n_average(n_average)
        if self.registration is None:
            return None
        sensor = self.measure_sensor2tracker(n)
        return None if sensor is None else self.registration.tip2base(sensor)
