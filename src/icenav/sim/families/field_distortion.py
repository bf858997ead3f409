"""Tracker family ``field-distortion``: an EM field distorted at a short wavelength, read
differently by sensors of different orientation, and metal in the robot that turns with the
roll.

An EM tracker's error comes from the field it measures: conductive and ferromagnetic
objects distort it, and a sensor coil reads the distorted field along its own axis, so the
error depends on both the sensor's position and its orientation (Kindratenko 2000; Ikits,
Brederson, Hansen & Hollerbach 2001, who correct it with polynomials in position *and*
orientation; Franz et al. 2014). A metal part near the sensor acts like an induced dipole
whose error field falls off steeply with distance (Nixon, McCallum, Fright & Price 1998).
The sensor pose ``(p, R)`` in the tracker frame, its coil axis ``n = R e_z``, is reported
as (jitter, rate, latency, dropouts and volume as the default tracker, ``sim/tracker.py``)::

    b(p, n) = sum_m (a_m + A_m n) sin(w_m . p + phi_m),  |w_m| = 2 pi / lambda   (D1)
    c(p, n) = sum_m (g_m + G_m n) sin(w_m . p + phi_m)                           (D2)
    x(q) = x0 + (rho cos(phi3 + psi), rho sin(phi3 + psi), d4),
    mu(q) = Rot_z(phi3) mu0                                                       (D3) the metal
    r = p_base - x(q),  B = (r0^2 / (|r|^2 + s^2))^(3/2) (3 r^ (r^ . mu) - mu)   (D4) its dipole
    p_meas = p + b + e_p (B + (B . n) n) / 2 + j                                 (D5)
    R_meas = Exp(c + e_r (n x B) + k) R                                           (D6)

``lambda`` is drawn per tracker in [60, 80] mm (the default tracker's 250 mm field is
nearly affine over the catheter's workspace; at 60-80 mm the bias changes within one spin
circle). ``a_m, A_m, g_m, G_m`` are Gaussian, scaled to the RMS values of
:class:`DistortionConfig`; the metal (a drive part of the front unit, ``rho`` off the
shaft's axis, ``x0`` below the base) turns with the robot's roll ``phi3`` and travels with
its translation ``d4`` (the robot's commanded joints, ``plant.state.q_motor``; a plant
without them: roll 0, d4 0).

How it differs from the default tracker and our compensation: the default's bias is a
250 mm-wavelength field of the position only (E3), which the roll-circle fit of
``compensation/tracker_bias.py`` removes as a base-frame bias; here the bias changes with
the sensor's orientation (so with the roll, at a fixed tip position) and with the robot's
roll through the metal, and varies within a spin's circle.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from icenav._typing import Array
from icenav.devices.registration import Registration
from icenav.devices.tracker import ToolStatus, TrackerFrame
from icenav.errors import ConfigurationError
from icenav.sim.families.base import check_seed
from icenav.sim.tracker import EMTracker, TrackerConfig, rotvec_to_matrix

__all__ = ["DistortionConfig", "FieldDistortionTracker"]

TAG = 0xF1E1D
"""Random-stream tag of the family."""


@dataclass(frozen=True)
class DistortionConfig:
    """The distortion of (D1)-(D6) (lengths mm, angles rad)."""

    wavelength_min_mm: float = 60.0
    """Shortest wavelength lambda drawn (mm)."""
    wavelength_max_mm: float = 80.0
    """Longest wavelength lambda drawn (mm)."""
    n_waves: int = 12
    """Plane waves in (D1)-(D2)."""
    position_rms_mm: float = 0.8
    """RMS of the orientation-free part a_m of (D1) over the volume (mm)."""
    orientation_rms_mm: float = 0.6
    """RMS of the orientation part A_m n of (D1), over positions and orientations (mm)."""
    rotation_rms_rad: float = math.radians(0.35)
    """RMS of g_m of (D2) (rad)."""
    rotation_orientation_rms_rad: float = math.radians(0.3)
    """RMS of G_m n of (D2) (rad)."""
    metal_centre_mm: tuple[float, float, float] = (0.0, 0.0, -40.0)
    """x0 of (D3): the roll drive's axis point in the base frame at d4 = 0 (mm)."""
    metal_radius_mm: float = 20.0
    """rho of (D3): the metal part's distance from the shaft's axis (mm)."""
    metal_reference_mm: float = 60.0
    """r0 of (D4): the distance at which the dipole's factor is 1 (mm)."""
    metal_size_mm: float = 20.0
    """s of (D4): the part's size, which softens the dipole's 1/r^3 near it (mm)."""
    metal_position_mm: float = 2.5
    """e_p of (D5): position error scale at r0 (mm)."""
    metal_rotation_rad: float = math.radians(1.0)
    """e_r of (D6): rotation error scale at r0 (rad)."""

    def __post_init__(self) -> None:
        lo, hi = float(self.wavelength_min_mm), float(self.wavelength_max_mm)
        if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo <= hi):
            raise ConfigurationError(
                f"wavelengths must satisfy 0 < min <= max (mm), got {lo} and {hi} mm"
            )
        if isinstance(self.n_waves, bool) or not 1 <= int(self.n_waves) <= 200:
            raise ConfigurationError(f"n_waves must be in [1, 200], got {self.n_waves!r}")
        for name in (
            "position_rms_mm",
            "orientation_rms_mm",
            "rotation_rms_rad",
            "rotation_orientation_rms_rad",
            "metal_radius_mm",
            "metal_size_mm",
            "metal_position_mm",
            "metal_rotation_rad",
        ):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v >= 0.0):
                raise ConfigurationError(f"{name} must be finite and >= 0, got {v}")
        r0 = float(self.metal_reference_mm)
        if not (math.isfinite(r0) and r0 > 0.0):
            raise ConfigurationError(f"metal_reference_mm must be > 0 mm, got {r0} mm")
        c = np.asarray(self.metal_centre_mm, dtype=np.float64)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ConfigurationError(f"metal_centre_mm must be 3 finite mm, got {c}")


class _Waves:
    """(D1)/(D2): sum_m (a_m + A_m n) sin(w_m . p + phi_m)."""

    def __init__(
        self,
        rng: np.random.Generator,
        w: Array,
        phase: Array,
        rms: float,
        orientation_rms: float,
    ) -> None:
        n = w.shape[0]
        scale = math.sqrt(2.0 / (3.0 * n))  # E|sum|^2 = 3 n sigma^2 / 2 = rms^2
        self.w = w
        self.phase = phase
        self.a = rng.normal(size=(n, 3)) * (rms * scale)
        # E|A n|^2 = tr(A^T A) / 3 = 3 sigma^2 for a uniformly oriented unit n
        self.big_a = rng.normal(size=(n, 3, 3)) * (orientation_rms * scale)

    def __call__(self, p: Array, axis: Array) -> Array:
        s = np.sin(self.w @ p + self.phase)
        return s @ self.a + np.einsum("m,mij,j->i", s, self.big_a, axis)


class FieldDistortionTracker:
    """An EM tracker with the distortion of (D1)-(D6), observing one plant.

    The default tracker (:class:`~icenav.sim.tracker.EMTracker`, its own field bias set to
    zero) supplies the sampling: rate, latency, jitter, dropouts, volume; this class adds
    the distortion to each sample it reports. It has the default tracker's protocol:
    ``start``, ``stop``, ``get_frame``, ``measure_tip2base``, ``registration``, ``config``.

    Parameters
    ----------
    plant : object with ``state.tip2base`` (and, for the metal, ``state.q_motor``)
        The catheter whose tip is tracked.
    seed : int
        Seeds the distortion (the family's stream) and the sampling noise.
    distortion : DistortionConfig
        The distortion's settings.
    config : TrackerConfig, optional
        Rate, latency, jitter, dropouts, volume, transforms (its bias RMS values are ignored:
        the distortion replaces them).
    clock : callable returning s, optional
        Time source of the sampling (default ``time.monotonic``).
    """

    def __init__(
        self,
        plant: object,
        seed: int = 0,
        distortion: DistortionConfig | None = None,
        config: TrackerConfig | None = None,
        clock: Callable[[], float] | None = None,
    ) -> None:
        seed = check_seed(seed)
        self.plant = plant
        self.distortion = DistortionConfig() if distortion is None else distortion
        base_cfg = TrackerConfig() if config is None else config
        if not isinstance(base_cfg, TrackerConfig):
            raise ConfigurationError(f"config must be a TrackerConfig, got {type(config).__name__}")
        self._inner = EMTracker(
            plant,  # type: ignore[arg-type]  # needs only state.tip2base
            seed=seed,
            config=replace(base_cfg, position_bias_rms_mm=0.0, rotation_bias_rms_rad=0.0),
            clock=clock,
        )
        d = self.distortion
        rng = np.random.default_rng([seed, TAG])
        n = int(d.n_waves)
        self.wavelength_mm = float(rng.uniform(d.wavelength_min_mm, d.wavelength_max_mm))
        dirs = rng.normal(size=(n, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        w = dirs * (2.0 * math.pi / self.wavelength_mm)
        phase = rng.uniform(0.0, 2.0 * math.pi, size=n)
        self._pos = _Waves(rng, w, phase, d.position_rms_mm, d.orientation_rms_mm)
        self._rot = _Waves(rng, w, phase, d.rotation_rms_rad, d.rotation_orientation_rms_rad)
        mu0 = rng.normal(size=3)
        self._mu0 = mu0 / np.linalg.norm(mu0)
        self._psi = float(rng.uniform(0.0, 2.0 * math.pi))
        t2b = self._inner.config.tracker2base
        self._tracker2base = np.asarray(t2b, dtype=np.float64)
        self._base2tracker = np.linalg.inv(self._tracker2base)
        self._last_timestamp: float | None = None
        self._last_frame: TrackerFrame | None = None

    # --- the protocol ---------------------------------------------------------------------

    @property
    def config(self) -> TrackerConfig:
        """Rate, latency, jitter, transforms of the sampling (bias RMS 0: see distortion)."""
        return self._inner.config

    @property
    def registration(self) -> Registration | None:
        """The registration tip poses are mapped through (the inner tracker's: the twin's
        true one unless a lab's estimate was set; None: unregistered)."""
        return self._inner.registration

    @registration.setter
    def registration(self, value: Registration | None) -> None:
        self._inner.registration = value

    @property
    def running(self) -> bool:
        """True between start() and stop()."""
        return self._inner.running

    def start(self) -> None:
        """Start sampling (see :meth:`EMTracker.start`)."""
        self._inner.start()
        self._last_timestamp = None
        self._last_frame = None

    def stop(self) -> None:
        """Stop sampling; :meth:`get_frame` then raises TrackerError."""
        self._inner.stop()

    def get_frame(self) -> TrackerFrame:
        """The newest sample due (as :meth:`EMTracker.get_frame`), distorted at the pose and
        robot joints of the moment it was acquired."""
        frame = self._inner.get_frame()
        if frame.sensor2tracker is None:
            return frame
        if self._last_frame is not None and frame.timestamp == self._last_timestamp:
            return self._last_frame
        meas, quality = self._distort(np.asarray(frame.sensor2tracker))
        meas.setflags(write=False)
        out = TrackerFrame(frame.timestamp, meas, ToolStatus.VALID, quality)
        self._last_timestamp = frame.timestamp
        self._last_frame = out
        return out

    def measure_tip2base(self, n_average: int = 1) -> Array | None:
        """Tracked tip pose (4, 4) in the base frame, averaged over ``n_average`` fresh
        samples (None when none was VALID). The distortion is the same for every sample of
        one pose, so it is added to the average (exactly: a mean position plus a constant,
        a fixed rotation times the chordal mean)."""
        mean_tip2base = self._inner.measure_tip2base(n_average)
        if mean_tip2base is None:
            return None
        m = self.config.sensor2tip
        s2t = self._base2tracker @ mean_tip2base @ m
        meas, _ = self._distort(s2t)
        return self._tracker2base @ meas @ np.linalg.inv(m)

    # --- the distortion -------------------------------------------------------------------

    def true_sensor2tracker(self) -> Array:
        """(4, 4) true pose of the sensor in the tracker frame (mm)."""
        return self._inner.true_sensor2tracker()

    def robot_joints(self) -> tuple[float, float]:
        """(phi3 rad, d4 mm) of the robot now: the plant's commanded joints, or (0, 0)."""
        q = getattr(getattr(self.plant, "state", None), "q_motor", None)
        if q is None:
            return 0.0, 0.0
        q = np.asarray(q, dtype=np.float64)
        return float(q[2]), float(q[3])

    def distortion_at(
        self, p_in_tracker: Array, rotation: Array, roll: float = 0.0, d4: float = 0.0
    ) -> tuple[Array, Array]:
        """Position error (3,) mm and rotation error (3,) rad (a rotation vector, tracker
        frame) of a sensor at ``p_in_tracker`` (3,) with orientation ``rotation`` (3, 3) in
        the tracker frame, the robot at roll ``roll`` (rad) and translation ``d4`` (mm):
        (D1)-(D6) without jitter."""
        d = self.distortion
        p = np.asarray(p_in_tracker, dtype=np.float64)
        axis = np.asarray(rotation, dtype=np.float64)[:, 2]
        bias_p = self._pos(p, axis)
        bias_r = self._rot(p, axis)
        # (D3)-(D4): the metal's dipole, in the base frame
        r_t2b = self._tracker2base[:3, :3]
        p_base = r_t2b @ p + self._tracker2base[:3, 3]
        n_base = r_t2b @ axis
        ang = roll + self._psi
        x = np.asarray(d.metal_centre_mm, dtype=np.float64) + np.array(
            [d.metal_radius_mm * math.cos(ang), d.metal_radius_mm * math.sin(ang), d4]
        )
        c, s = math.cos(roll), math.sin(roll)
        mu = np.array(
            [c * self._mu0[0] - s * self._mu0[1], s * self._mu0[0] + c * self._mu0[1], self._mu0[2]]
        )
        r = p_base - x
        dist = float(np.linalg.norm(r))
        rhat = r / max(dist, 1e-9)
        soft = d.metal_reference_mm**2 / (dist * dist + d.metal_size_mm**2)
        field = soft**1.5 * (3.0 * rhat * (rhat @ mu) - mu)
        e_p = 0.5 * d.metal_position_mm * (field + (field @ n_base) * n_base)  # (D5)
        e_r = d.metal_rotation_rad * np.cross(n_base, field)  # (D6)
        return bias_p + r_t2b.T @ e_p, bias_r + r_t2b.T @ e_r

    def _distort(self, sensor2tracker: Array) -> tuple[Array, float]:
        """The measured pose (4, 4): (D5)-(D6) applied to a (jittered) sensor pose, with the
        distortion evaluated at the plant's true pose now; and the sample's quality."""
        true = self.true_sensor2tracker()
        roll, d4 = self.robot_joints()
        bias_p, bias_r = self.distortion_at(true[:3, 3], true[:3, :3], roll, d4)
        out = np.eye(4)
        out[:3, :3] = rotvec_to_matrix(bias_r) @ sensor2tracker[:3, :3]
        out[:3, 3] = sensor2tracker[:3, 3] + bias_p
        scale = 2.0 * math.hypot(
            self.distortion.position_rms_mm, self.distortion.orientation_rms_mm
        )
        return out, float(math.exp(-float(np.linalg.norm(bias_p)) / max(scale, 1e-9)))
