"""Physiological motion for the twin: a heart rhythm that varies from beat to beat, and
irregular breathing that moves the heart relative to the robot's base.

Equations (numbered as in ``docs/digital-twin.md``, section 9):

* (P1) Beat ``k`` starts at ``T_k`` and lasts ``RR_k = RR0 (1 + e_k - a_rsa r(T_k))``, where
  ``e_k`` is an AR(1) sequence (sd ``rr_sd``, lag-1 correlation ``rr_correlation``) and
  ``r`` the breathing level (respiratory sinus arrhythmia: shorter beats in inspiration).
* (P2) Cardiac phase ``phi(t) = (t - T_k) / RR_k`` for ``T_k <= t < T_k+1``.
* (P3) Contraction amplitude of beat ``k``: ``a_k = (1 + sigma_a n_k) (1 - s_v r(T_k))``
  (beat-to-beat variation, and the respiratory variation of the stroke volume under
  ventilation), scaling the phantom's whole cardiac displacement field.
* (P4) Breath ``j`` starts at ``B_j`` and lasts ``P_j = P0 (1 + sigma_P m_j)``; within it the
  level is ``r(t) = b(t) + A_j sin^(2n)(pi tau)``, ``tau = (t - B_j) / P_j`` (Lujan et al.'s
  breathing curve: a long dwell at end-expiration, ``n = 2``), ``A_j = 1 + sigma_A g_j``
  and ``b`` the end-expiratory baseline, drawn per breath and interpolated across it.
* (P5) The heart moves rigidly with the level:
  ``u_resp(x, t) = r(t) (d + theta (axis x (x - c)))``: a translation ``d`` (mm) and a small
  rotation ``theta`` (rad) about ``axis`` through ``c``, per unit level (a nominal breath).
* (P6) The heart's position and shape at a given phase vary from beat to beat:
  ``u_beat(x, t) = w(x) ((1 - s) D_k(x) + s D_k+1(x))``, ``s = (1 - cos(pi phi)) / 2``,
  with the field ``D_k(x) = sigma_d (a_k + B_k r / L) / sqrt(1 + |r|^2 / L^2)``,
  ``r = x - c``, drawn per beat (entries of ``a_k`` and ``B_k`` ~ N(0, 1)): every point
  moves by ``sigma_d`` per axis (sd), points closer than about ``L`` move together;
  ``w(x)`` is 1 in the heart and falls to 0 along the caval veins within ``taper`` of the
  cavo-atrial junctions (the veins outside the pericardium are held by the liver and the
  mediastinum, they do not take part in the heart's beat-to-beat shape); continuous across
  the R wave.

All draws come from ``numpy.random.default_rng`` seeded with the patient's seed; beats and
breaths are generated in order, so a value depends only on the seed and the time asked.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite, check_positive
from icenav.errors import ConfigurationError
from icenav.sim.anatomy import HeartPhantom

__all__ = [
    "Breathing",
    "BreathingParams",
    "CardiacRhythm",
    "PhysiologicalHeart",
    "RhythmParams",
]

_T_START = -60.0
"""Beats and breaths are generated from this time (s), so queries a little before the
simulation's time 0 (a gated window looking back) are answered."""


def _fraction(value: float, name: str, hi: float = 0.5) -> float:
    v = float(value)
    if not math.isfinite(v) or not 0.0 <= v < hi:
        raise ConfigurationError(f"{name} must be in [0, {hi}), got {value!r}")
    return v


@dataclass(frozen=True)
class RhythmParams:
    """Heart rhythm of one patient (or of a phantom's pump)."""

    heart_rate_bpm: float = 72.0
    """Mean heart rate (beats/min)."""
    rr_sd: float = 0.0
    """Beat-to-beat standard deviation of the RR interval, fraction of the mean (P1)."""
    rr_correlation: float = 0.0
    """Lag-1 correlation of consecutive RR deviations (P1)."""
    rsa: float = 0.0
    """Respiratory sinus arrhythmia: RR shortened by this fraction at a nominal breath's
    peak (P1)."""
    amplitude_sd: float = 0.0
    """Beat-to-beat standard deviation of the contraction amplitude, fraction (P3)."""
    stroke_variation: float = 0.0
    """Respiratory variation of the contraction amplitude: reduced by this fraction at a
    nominal breath's peak (P3)."""
    shape_sd_mm: float = 0.0
    """Beat-to-beat standard deviation of the heart's position at a fixed phase, per axis
    (mm, ``sigma_d`` of P6); 0: every beat the same."""
    shape_length_mm: float = 40.0
    """Length ``L`` (mm) over which the beat-to-beat shape field varies by ``sigma_d`` (P6):
    about the right atrium's long axis (4.2 cm, Bommer et al. 1979, cited by the paper)."""
    shape_centre_mm: tuple[float, float, float] = (30.0, -10.0, 10.0)
    """Centre ``c`` of the beat-to-beat shape field (anatomy frame, mm): mid-heart (P6)."""
    shape_vein_taper_mm: float = 20.0
    """Length (mm) along the caval veins, from the cavo-atrial junction, over which the
    beat-to-beat shape field falls to zero (``w`` of P6): about the intrathoracic,
    intrapericardial length of the IVC (1-2 cm); the veins beyond are held by the liver and
    the mediastinum."""

    def __post_init__(self) -> None:
        hr = check_positive(self.heart_rate_bpm, "heart_rate_bpm", "beats/min")
        if not 30.0 <= hr <= 200.0:
            raise ConfigurationError(f"heart_rate_bpm must be in [30, 200] beats/min, got {hr}")
        _fraction(self.rr_sd, "rr_sd", 0.2)
        _fraction(abs(self.rr_correlation), "|rr_correlation|", 1.0)
        _fraction(self.rsa, "rsa", 0.3)
        _fraction(self.amplitude_sd, "amplitude_sd", 0.3)
        _fraction(self.stroke_variation, "stroke_variation", 0.5)
        sd = float(check_finite(self.shape_sd_mm, "shape_sd_mm", "mm"))
        if not 0.0 <= sd <= 5.0:
            raise ConfigurationError(f"shape_sd_mm must be in [0, 5] mm, got {sd} mm")
        check_positive(self.shape_length_mm, "shape_length_mm", "mm")
        check_finite(self.shape_centre_mm, "shape_centre_mm", "mm")
        check_positive(self.shape_vein_taper_mm, "shape_vein_taper_mm", "mm")

    @property
    def period_s(self) -> float:
        """Mean beat duration (s)."""
        return 60.0 / self.heart_rate_bpm


@dataclass(frozen=True)
class BreathingParams:
    """Breathing of one patient: level per breath and the heart's motion per unit level."""

    period_s: float = 4.1
    """Mean breath duration (s); a ventilated patient's set rate (about 15 /min)."""
    period_sd: float = 0.0
    """Breath-to-breath standard deviation of the duration, fraction (P4)."""
    amplitude_sd: float = 0.0
    """Breath-to-breath standard deviation of the depth, fraction (P4)."""
    baseline_sd: float = 0.0
    """Standard deviation of the end-expiratory level per breath, in units of a nominal
    breath (P4)."""
    shape_n: int = 2
    """Exponent ``n`` of Lujan et al.'s ``sin^(2n)`` breathing curve (P4)."""
    translation_mm: tuple[float, float, float] = (0.0, -1.3, -4.9)
    """Heart translation at a nominal breath's peak (anatomy x left, y posterior, z superior;
    mm): Shechter et al. 2004, inspiration moves the heart 4.9 mm caudally and 1.3 mm
    anteriorly (P5)."""
    rotation_rad: float = math.radians(1.5)
    """Heart rotation at a nominal breath's peak (rad; Shechter et al.: 1.5 deg
    cranio-dorsal) about ``rotation_axis`` through ``pivot_mm`` (P5)."""
    rotation_axis: tuple[float, float, float] = (-1.0, 0.0, 0.0)
    """Axis of the respiratory rotation (anatomy frame): superior parts move posterior."""
    pivot_mm: tuple[float, float, float] = (30.0, -10.0, 10.0)
    """Centre of the respiratory rotation (anatomy frame, mm): mid-heart."""

    def __post_init__(self) -> None:
        check_positive(self.period_s, "period_s", "s")
        _fraction(self.period_sd, "period_sd", 0.5)
        _fraction(self.amplitude_sd, "amplitude_sd", 0.8)
        _fraction(self.baseline_sd, "baseline_sd", 1.0)
        if isinstance(self.shape_n, bool) or self.shape_n not in (1, 2, 3):
            raise ConfigurationError(f"shape_n must be 1, 2 or 3, got {self.shape_n!r}")
        check_finite(self.translation_mm, "translation_mm", "mm")
        check_finite(self.rotation_rad, "rotation_rad", "rad")
        axis = check_finite(self.rotation_axis, "rotation_axis")
        if axis.shape != (3,) or float(np.linalg.norm(axis)) == 0.0:
            raise ConfigurationError(f"rotation_axis must be a non-zero 3-vector, got {axis}")


class Breathing:
    """Irregular breathing (P4)-(P5): the level ``r(t)`` (1 at a nominal breath's peak, 0 at
    end-expiration) and the heart's rigid respiratory displacement.

    Its :meth:`signal` is what a bellows or the ventilator records; it serves as the
    :class:`icenav.refinement.gating.RespiratoryMonitor` of the twin (it never reads the
    catheter).

    Parameters
    ----------
    params : BreathingParams
    seed : int
        Patient seed: breath durations, depths and baselines.
    """

    def __init__(self, params: BreathingParams, seed: int) -> None:
        self.params = params
        self._rng = np.random.default_rng([int(seed), 0xB7])
        self._starts = [_T_START]
        self._periods: list[float] = []
        self._depths: list[float] = []
        self._bases = [self._draw_base()]
        self._arrays: tuple[Array, Array, Array, Array] | None = None
        """starts, periods, bases, depths as arrays (rebuilt when a breath is drawn): the
        lists were converted at every call, 15 % of an in-vivo ``eval recovery``."""
        axis = np.asarray(params.rotation_axis, np.float64)
        self._axis = axis / np.linalg.norm(axis)
        self._pivot = np.asarray(params.pivot_mm, np.float64)
        self._d = np.asarray(params.translation_mm, np.float64)

    def _draw_base(self) -> float:
        p = self.params
        return float(p.baseline_sd * self._rng.standard_normal()) if p.baseline_sd else 0.0

    def _extend(self, t: float) -> None:
        p = self.params
        while self._starts[-1] <= t:
            g = self._rng.standard_normal(2)
            period = p.period_s * max(0.5, 1.0 + p.period_sd * g[0])
            self._periods.append(period)
            self._depths.append(max(0.0, 1.0 + p.amplitude_sd * g[1]))
            self._bases.append(self._draw_base())
            self._starts.append(self._starts[-1] + period)
            self._arrays = None

    def signal(self, t: ArrayLike) -> Array:
        """Breathing level r(t) (P4) at times ``t`` (s), same shape as ``t``."""
        tt = np.asarray(t, np.float64)
        flat = np.atleast_1d(tt).ravel()
        if flat.size == 0:
            return np.zeros(tt.shape)
        self._extend(float(flat.max()))
        if self._arrays is None:
            self._arrays = (
                np.asarray(self._starts),
                np.asarray(self._periods),
                np.asarray(self._bases),
                np.asarray(self._depths),
            )
        starts, periods, bases, depths = self._arrays
        k = np.clip(np.searchsorted(starts, flat, side="right") - 1, 0, len(self._periods) - 1)
        tau = np.clip((flat - starts[k]) / periods[k], 0.0, 1.0)
        # Eq. (P4): baseline interpolated over the breath, Lujan's sin^(2n) curve on top
        level = (1.0 - tau) * bases[k] + tau * bases[k + 1]
        level = level + depths[k] * np.sin(np.pi * tau) ** (2 * self.params.shape_n)
        out: Array = level.reshape(tt.shape)
        return out

    def level(self, t: float) -> float:
        """Breathing level r(t) (P4) at one time ``t`` (s): :meth:`signal` of a scalar, to
        the bit (the same operations on Python floats, the sine and its power on a
        one-element array as there), without the array set-up that dominated its cost
        (``docs/digital-twin.md`` section 8)."""
        tf = float(t)
        self._extend(tf)
        starts, periods = self._starts, self._periods
        k = min(max(bisect.bisect_right(starts, tf) - 1, 0), len(periods) - 1)
        tau = min(max((tf - starts[k]) / periods[k], 0.0), 1.0)
        bases = self._bases
        level = (1.0 - tau) * bases[k] + tau * bases[k + 1]
        wave = np.sin(np.array([np.pi * tau])) ** (2 * self.params.shape_n)
        return float(level + self._depths[k] * float(wave[0]))

    def breath_starts(self, t0: float, t1: float) -> Array:
        """Start times (s) of the breaths that begin in [t0, t1)."""
        self._extend(t1)
        s = np.asarray(self._starts)
        out: Array = s[(s >= t0) & (s < t1)]
        return out

    def displacement(self, points: Array, t: float) -> Array:
        """Rigid respiratory displacement (P5) of ``points`` (N, 3) at time ``t`` (mm, anatomy)."""
        r = self.level(t)
        if r == 0.0:
            return np.zeros_like(points)
        # axis x (p - pivot), written out: np.cross costs 45 us a call on (N, 3) points
        a, v = self._axis, points - self._pivot
        cross = np.empty(v.shape)  # filled per component: np.stack cost as much again
        cross[..., 0] = a[1] * v[..., 2] - a[2] * v[..., 1]
        cross[..., 1] = a[2] * v[..., 0] - a[0] * v[..., 2]
        cross[..., 2] = a[0] * v[..., 1] - a[1] * v[..., 0]
        rot = cross * self.params.rotation_rad
        out: Array = r * (self._d + rot)
        return out

    def translation_mm(self, t: float) -> Array:
        """The heart's respiratory translation (3,) at time ``t`` (mm, anatomy frame)."""
        out: Array = self.level(t) * self._d
        return out


class CardiacRhythm:
    """Beat times and contraction amplitudes (P1)-(P3).

    Parameters
    ----------
    params : RhythmParams
    seed : int
        Patient seed.
    breathing : Breathing, optional
        Modulates RR (sinus arrhythmia) and the amplitude (stroke variation).
    """

    def __init__(self, params: RhythmParams, seed: int, breathing: Breathing | None = None) -> None:
        self.params = params
        self.breathing = breathing
        self._rng = np.random.default_rng([int(seed), 0xC4])
        self._starts = [_T_START]
        self._rr: list[float] = []
        self._amp: list[float] = []
        # P6 draws come from their own stream: the RR and amplitude sequences of a seed are
        # the same with or without the shape variation
        self._shape_rng = np.random.default_rng([int(seed), 0xC6])
        self._shape: list[Array] = []
        self._e = 0.0
        self._starts_arr = np.asarray(self._starts)

    @property
    def period_s(self) -> float:
        """Mean beat duration (s)."""
        return self.params.period_s

    def _extend(self, t: float) -> None:
        p = self.params
        rho = p.rr_correlation
        grew = False
        while self._starts[-1] <= t:
            start = self._starts[-1]
            g = self._rng.standard_normal(2)
            # Eq. (P1): AR(1) RR deviations, shortened in inspiration
            self._e = rho * self._e + math.sqrt(1.0 - rho * rho) * p.rr_sd * g[0]
            r = self.breathing.level(start) if self.breathing is not None else 0.0
            rr = p.period_s * max(0.5, 1.0 + self._e - p.rsa * r)
            # Eq. (P3): beat-to-beat and respiratory variation of the contraction
            amp = max(0.0, 1.0 + p.amplitude_sd * g[1]) * (1.0 - p.stroke_variation * r)
            self._rr.append(rr)
            self._amp.append(amp)
            self._shape.append(self._shape_rng.standard_normal(12))
            self._starts.append(start + rr)
            grew = True
        if grew:
            self._starts_arr = np.asarray(self._starts)

    def beat_index(self, t: float) -> int:
        """Index of the beat that contains time ``t`` (s)."""
        self._extend(t)
        # bisect on the list: the index np.searchsorted(side="right") gives, without the
        # array call (a hot path of the walls, `docs/digital-twin.md` section 8)
        return bisect.bisect_right(self._starts, t) - 1

    def beat_start(self, k: int) -> float:
        """Start time (s) of beat ``k`` (the R wave)."""
        while len(self._starts) <= k + 1:
            self._extend(self._starts[-1])
        return float(self._starts[k])

    def beat_duration(self, k: int) -> float:
        """Duration RR_k (s) of beat ``k``."""
        return self.beat_start(k + 1) - self.beat_start(k)

    def phase(self, t: float) -> float:
        """Cardiac phase (P2) at ``t`` (s): fraction of the beat in [0, 1), 0 = R wave."""
        k = self.beat_index(t)
        return float(min(max((t - self._starts[k]) / self._rr[k], 0.0), 1.0 - 1e-12))

    def amplitude(self, t: float) -> float:
        """Contraction amplitude a_k (P3) of the beat at ``t`` (1 = the phantom's nominal)."""
        return self._amp[self.beat_index(t)]

    def shape_displacement(self, points: Array, t: float) -> Array:
        """Eq. (P6): the beat-to-beat shape displacement (mm) of ``points`` (N, 3) at ``t``
        (s), anatomy frame; zeros when ``shape_sd_mm`` is 0."""
        p = self.params
        if p.shape_sd_mm == 0.0:
            return np.zeros_like(points)
        k = self.beat_index(t)
        self.beat_start(k + 1)  # draws beat k + 1
        s = 0.5 * (1.0 - math.cos(math.pi * self.phase(t)))
        g = (1.0 - s) * self._shape[k] + s * self._shape[k + 1]
        r = (points - np.asarray(p.shape_centre_mm)) / p.shape_length_mm
        # Eq. (P6): a_k + B_k r / L, normalised so that every point's sd is sigma_d per axis
        # (the affine field d_k + G_k r of session 7 grew without bound away from c: 1.7
        # sigma_d at the right atrium's wall, 1.8 sigma_d along the IVC)
        field = g[:3] + r @ g[3:].reshape(3, 3).T
        norm = np.sqrt(1.0 + np.einsum("...i,...i->...", r, r))[..., None]
        out: Array = p.shape_sd_mm * field / norm
        return out

    def time_at_phase(self, k: int, phase: float) -> float:
        """Time (s) of cardiac phase ``phase`` in beat ``k``."""
        return self.beat_start(k) + float(phase) * self.beat_duration(k)


class PhysiologicalHeart(HeartPhantom):
    """A :class:`~icenav.sim.anatomy.HeartPhantom` whose beat follows a
    :class:`CardiacRhythm` and whose breathing follows a :class:`Breathing`.

    The phantom's own respiratory term is replaced by (P5) and its cardiac displacement is
    scaled by the beat's amplitude (P3) (the displacement is linear in the contraction
    amplitudes); labels, valve opening and speckle follow, since they are evaluated through
    :meth:`cardiac_phase` and :meth:`displacement`. Built from any phantom with the public
    constructor arguments.

    Parameters
    ----------
    phantom : HeartPhantom
        Geometry and cardiac motion (its respiratory amplitude is ignored).
    rhythm : CardiacRhythm
    breathing : Breathing, optional
        None: no breathing (a phantom on the bench).
    """

    def __init__(
        self, phantom: HeartPhantom, rhythm: CardiacRhythm, breathing: Breathing | None = None
    ) -> None:
        motion = replace(
            phantom.motion,
            heart_rate_bpm=rhythm.params.heart_rate_bpm,
            respiratory_amplitude_mm=(0.0, 0.0, 0.0),
        )
        super().__init__(
            phantom.chambers,
            phantom.vessels,
            phantom.valves,
            septum_centre=tuple(float(x) for x in phantom.septum_centre),  # type: ignore[arg-type]
            septum_normal=tuple(float(x) for x in phantom.septum_normal),  # type: ignore[arg-type]
            septum_radius_mm=phantom.septum_radius_mm,
            septum_mm=phantom.septum_mm,
            motion=motion,
        )
        self.rhythm = rhythm
        self.breathing = breathing
        self._veins = self._caval_veins(phantom)

    @staticmethod
    def _caval_veins(phantom: HeartPhantom) -> list[tuple[Array, Array, float]]:
        """(junction (3,), unit axis away from the atrium (3,), radius) of the IVC and SVC."""
        ra = np.asarray(phantom.chamber("ra").centre, np.float64)
        out = []
        for v in phantom.vessels:
            if v.name not in ("ivc", "svc"):
                continue
            a, b = np.asarray(v.start, np.float64), np.asarray(v.end, np.float64)
            if np.linalg.norm(a - ra) > np.linalg.norm(b - ra):
                a, b = b, a  # a: the end at the atrium
            out.append((a, (b - a) / np.linalg.norm(b - a), float(v.radius_mm)))
        return out

    def shape_weight(self, points: Array) -> Array:
        """``w(x)`` of Eq. (P6) at ``points`` (N, 3) (anatomy frame, mm): 1 in the heart,
        falling linearly to 0 along a caval vein over ``shape_vein_taper_mm`` beyond its
        cavo-atrial junction, and back to 1 over 10 mm outside the vein's radius + 5 mm."""
        w = np.ones(points.shape[:-1])
        taper = self.rhythm.params.shape_vein_taper_mm
        for junction, axis, radius in self._veins:
            rel = points - junction
            h = rel @ axis
            rho = np.sqrt(np.maximum(np.einsum("...i,...i->...", rel, rel) - h * h, 0.0))
            along = np.clip(h / taper, 0.0, 1.0)
            inside = np.clip((radius + 15.0 - rho) / 10.0, 0.0, 1.0)
            w = w * (1.0 - along * inside)
        return w

    def cardiac_phase(self, t: float) -> float:
        """Phase (P2) of the rhythm at ``t`` (s)."""
        return self.rhythm.phase(float(t))

    def displacement(self, points: Array, t: float) -> Array:
        """Cardiac displacement scaled by the beat's amplitude (P3), the beat's shape
        variation (P6) and breathing (P5)."""
        u = self.rhythm.amplitude(float(t)) * super().displacement(points, t)
        if self.rhythm.params.shape_sd_mm > 0.0:
            # Eq. (P6): the beat's shape, held off the caval veins beyond the junctions
            w = self.shape_weight(points)[..., None]
            u = u + w * self.rhythm.shape_displacement(points, float(t))
        if self.breathing is not None:
            u = u + self.breathing.displacement(points, float(t))
        out: Array = u
        return out
