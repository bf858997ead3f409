"""A transmission model per *tendon* (tendon-sheath capstan play), its identification from
two-knob motions, and its stateful inverse (beyond the paper).

:mod:`icenav.compensation.hysteresis` gives each knob one play whose half-width grows with that
knob's own
angle. The physics it stands for is per tendon (Kaneko et al. 1991; Palli & Melchiorri 2006;
Do et al. 2014; Kato et al. 2016): each knob pulls one tendon of an antagonistic pair through
a long sheath, and capstan friction lets the *distal* pull stick inside a band around the
*proximal* pull whose width grows with the tendon's tension and with the total wrap angle of
its path -- the shaft, the vessel and the bending section's own bend, so the play of one knob
widens when the *other* knob bends the section. Angles below are knob angles (rad): a pull is
expressed as the knob rotation that makes it (pull / handle radius).

Tendons A, B (AP knob x1) and C, D (RL knob x2), sign ``sigma = +1`` for A, C and ``-1`` for B,
D; pair j, other pair k. Per substep (knob change <= ``max_substep``; TR = this module's
equations, the capstan form of the tendon-sheath literature, not the paper's)::

    p_i = sigma_i x_j - s_j                                  # (TR1) proximal pull, slack s_j
    Theta = wrap + friction * hypot(z1, z2)                  # (TR2) capstan exponent mu Theta
    T_i = max(d_i, 0) + max(sigma_i gamma_j z_k, 0)          # (TR3) tension (rad of pull)
    d_i = clip(d_i, p_i - w_j - kappa_j T_i g+(Theta),       # (TR4) friction band
                    p_i + w_j + kappa_j T_i g-(Theta))
    z_j = max(d_A, 0) - max(d_B, 0)                          # (TR5) effective knob

    g+(x) = (e^x - 1) / x - 1,   g-(x) = 1 - (1 - e^-x) / x   # pulled / released tendon

``s_j`` is the pair's slack (a dead-zone of half-width s_j in x_j), ``w_j`` the seal play,
``kappa_j`` the growth of the band with tension, ``gamma_j`` the tension the other pair's bend
puts on one tendon of this pair (signed: which tendon is stretched depends on where the
tendons are routed), ``wrap`` the capstan exponent of the straight catheter (mu times the
shaft's curvature) and ``friction`` (mu) its growth per rad of bend. The effective knobs
``z`` are what an elasticity map F built on them sees.

Identification (:func:`identify_transmission`) uses only motor commands and the EM-tracked tip:
the model is simulated along the commanded calibration paths (the dense raster, knob circles
of a few radii in both directions, :func:`circle_path`), the tracked tip is turned into model
knob angles (:func:`observed_knobs`, position only), and a static map ``G`` (a bivariate
polynomial, fitted by linear least squares for each parameter vector: variable projection)
from ``z`` to them closes the residual that :func:`scipy.optimize.least_squares` minimises.

Compensation (:class:`TendonCompensator`): for a wanted effective knob pair ``z*`` the motor
knobs ``x`` are found by a 1-D root search per knob (``z_j`` is non-decreasing in ``x_j``)
inside Gauss-Seidel sweeps over the pair (coupled through the bend and the tensions), from
the model's current state, which is then advanced; inside the dead-zone (``|z*_j| < eps``)
the command is interpolated between the solutions for ``+-eps`` (no jump across it). The
roll and the distal twist keep the per-joint models of :mod:`icenav.compensation.hysteresis`.
:func:`transmission_commands` composes it with F; it is the ``dense+hysteresis`` condition of
:mod:`icenav.eval.spin`::

    model path -> [tracker-bias shift] -> preshape_model (twist) -> F_eff -> Savitzky-Golay
               -> TendonCompensator -> motors

Calibration (:func:`calibrate_transmission`): knob circles at 25 / 50 / 75 deg, both ways
(~740 moves), with the dense raster; F_eff is a smoothed thin-plate RBF over the raster and
circle samples relabelled with the identified model's effective knobs
(:func:`build_transmission`). Before a procedure in a curved vessel, :func:`reidentify_in_situ`
refits the plays from the circles alone there (F and G kept).

Measured on the twin's development catheters 50-52 (the spin protocol of ``icenav eval spin``,
EM-tracked, mean; calibrated in the straight vessel; before the tracker-bias separation of
:mod:`icenav.compensation.tracker_bias`): 2.1 / 2.2 / 2.3 mm and 2.2 / 2.7 / 3.4 deg at 20 / 40 /
60 deg in
the straight vessel, against 2.7 / 3.0 / 3.6 mm and 3.2 / 4.0 / 5.0 deg for the per-knob model
(``dense+knob-hysteresis``); lower than it in the curved vessels too. Re-identified in the
curved vessel (:func:`reidentify_in_situ` with the roll sweeps there), the curved vessels added
at most +1.0 mm / +1.4 deg to the straight result (steep, 60 deg; on the twin before its
vessel review, docs/digital-twin.md section 2.2). With the tracker bias separated: 1.5 / 1.5 /
1.8 mm (same catheters; held-out results, in every vessel, in docs/results.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq, least_squares

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.calibration.plans import MotionPlan, Recording, execute_plan
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.compensation.hysteresis import HysteresisCompensator
from icenav.compensation.tracker_bias import TrackerBias
from icenav.errors import ConfigurationError, ShapeError, TrackerError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry
from icenav.geometry.trajectories import savgol_smooth

__all__ = [
    "CalibrationMotion",
    "F_SMOOTHING",
    "KNOB_CIRCLES",
    "PairTransmission",
    "TendonCompensator",
    "TendonTransmission",
    "TransmissionCalibration",
    "TransmissionFit",
    "build_transmission",
    "calibrate_transmission",
    "circle_path",
    "circle_plan",
    "g_minus",
    "g_plus",
    "identify_transmission",
    "motion_from",
    "observed_knobs",
    "record_motion",
    "reidentify_in_situ",
    "transmission_commands",
]

_MAX_PLAY = math.radians(20.0)
_PARAM_NAMES = (
    "ap.slack",
    "ap.seal_play",
    "ap.tension_play",
    "ap.coupling",
    "rl.slack",
    "rl.seal_play",
    "rl.tension_play",
    "rl.coupling",
    "wrap",
    "friction",
)


def g_plus(x: float) -> float:
    """(e^x - 1)/x - 1: extra lag factor of a pulled tendon for capstan exponent x >= 0."""
    if x < 1e-6:
        return 0.5 * x
    return math.expm1(x) / x - 1.0


def g_minus(x: float) -> float:
    """1 - (1 - e^-x)/x: lead factor of a released tendon for capstan exponent x >= 0."""
    if x < 1e-6:
        return 0.5 * x
    return 1.0 + math.expm1(-x) / x


def _check_range(name: str, v: float, lo: float, hi: float, unit: str) -> float:
    f = float(v)
    if not math.isfinite(f) or f < lo or f > hi:
        raise ConfigurationError(f"{name} must be in [{lo:.4g}, {hi:.4g}] {unit}, got {v!r}")
    return f


@dataclass(frozen=True)
class PairTransmission:
    """One antagonistic tendon pair (angles as knob rotation, rad)."""

    slack: float = 0.0
    """s: slack of each tendon at the knob's centre (rad of knob): dead-zone half-width."""
    seal_play: float = 0.0
    """w: tension-independent half-width of each tendon's friction band (rad)."""
    tension_play: float = 0.0
    """kappa: band half-width per rad of tendon tension per unit of g+- (rad/rad)."""
    coupling: float = 0.0
    """gamma: tension put on this pair's tendon (sigma gamma z_other > 0) per rad of the other
    knob's effective angle (rad/rad, signed)."""

    def __post_init__(self) -> None:
        _check_range("slack", self.slack, 0.0, _MAX_PLAY, "rad")
        _check_range("seal_play", self.seal_play, 0.0, _MAX_PLAY, "rad")
        _check_range("tension_play", self.tension_play, 0.0, 2.0, "rad/rad")
        _check_range("coupling", self.coupling, -2.0, 2.0, "rad/rad")


@dataclass(frozen=True)
class TendonTransmission:
    """The per-tendon transmission of both knobs (see the module docstring)."""

    ap: PairTransmission = field(default_factory=PairTransmission)
    """Tendons A, B driven by the AP knob (phi1)."""
    rl: PairTransmission = field(default_factory=PairTransmission)
    """Tendons C, D driven by the RL knob (phi2)."""
    wrap: float = 0.0
    """Capstan exponent mu Theta of the straight catheter with the section straight (>= 0)."""
    friction: float = 0.0
    """mu: growth of the capstan exponent per rad of bend of the section (>= 0)."""
    max_substep: float = math.radians(2.0)
    """Largest knob change per substep of :meth:`step` (rad), > 0."""

    def __post_init__(self) -> None:
        for name in ("ap", "rl"):
            if not isinstance(getattr(self, name), PairTransmission):
                raise ConfigurationError(f"{name} must be a PairTransmission")
        _check_range("wrap", self.wrap, 0.0, 10.0, "(dimensionless)")
        _check_range("friction", self.friction, 0.0, 5.0, "per rad")
        _check_range("max_substep", self.max_substep, 1e-4, 0.5, "rad")

    # --- parameter vector (identification) -------------------------------------------------

    def to_vector(self) -> Array:
        """The 10 parameters in the order of ``PARAM_NAMES``."""
        a, r = self.ap, self.rl
        return np.array(
            [
                a.slack,
                a.seal_play,
                a.tension_play,
                a.coupling,
                r.slack,
                r.seal_play,
                r.tension_play,
                r.coupling,
                self.wrap,
                self.friction,
            ]
        )

    @classmethod
    def from_vector(
        cls, v: ArrayLike, max_substep: float = math.radians(2.0)
    ) -> TendonTransmission:
        """Inverse of :meth:`to_vector`."""
        x = check_finite(v, "parameter vector").ravel()
        if x.size != len(_PARAM_NAMES):
            raise ShapeError(f"parameter vector must have {len(_PARAM_NAMES)} values, got {x.size}")
        return cls(
            ap=PairTransmission(*(float(t) for t in x[0:4])),
            rl=PairTransmission(*(float(t) for t in x[4:8])),
            wrap=float(x[8]),
            friction=float(x[9]),
            max_substep=max_substep,
        )

    def with_vessel(self, vessel_curvature: float) -> TendonTransmission:
        """The same transmission with the shaft laid through a vessel that turns by
        ``vessel_curvature`` (rad, the sum of its arcs' turning angles, e.g. from imaging):
        every tendon's wrap grows by it, so the capstan exponent grows by mu times it::

            wrap' = wrap + friction * vessel_curvature          # (TR2) Theta_i + Theta_vessel
        """
        t = _check_range("vessel_curvature", vessel_curvature, 0.0, 4.0 * math.pi, "rad")
        return replace(self, wrap=min(self.wrap + self.friction * t, 10.0))

    # --- simulation ------------------------------------------------------------------------

    def relaxed_state(self, x: ArrayLike = (0.0, 0.0)) -> Array:
        """Distal pulls (4,) of a relaxed transmission at motor knobs x (2,): d_i = p_i."""
        xx = check_finite(x, "x", "rad").ravel()
        if xx.size != 2:
            raise ShapeError(f"x must have 2 knob angles, got {xx.size}")
        s1, s2 = self.ap.slack, self.rl.slack
        return np.array([xx[0] - s1, -xx[0] - s1, xx[1] - s2, -xx[1] - s2])

    def step(
        self, d: Sequence[float], x_from: Sequence[float], x_to: Sequence[float]
    ) -> list[float]:
        """Advance the distal pulls ``d`` (4,) while the knobs move from ``x_from`` to ``x_to``
        (2,) along a straight line, in substeps of at most ``max_substep``. Returns the new d
        (a list; the input is not modified). Pure float math (hot loop)."""
        a0, b0 = float(x_from[0]), float(x_from[1])
        a1, b1 = float(x_to[0]), float(x_to[1])
        n = max(1, math.ceil(max(abs(a1 - a0), abs(b1 - b0)) / self.max_substep))
        dA, dB, dC, dD = (float(t) for t in d)
        ap, rl = self.ap, self.rl
        s1, w1, k1, c1 = ap.slack, ap.seal_play, ap.tension_play, ap.coupling
        s2, w2, k2, c2 = rl.slack, rl.seal_play, rl.tension_play, rl.coupling
        wrap, mu = self.wrap, self.friction
        for i in range(1, n + 1):
            f = i / n
            x1 = a0 + f * (a1 - a0)
            x2 = b0 + f * (b1 - b0)
            z1 = (dA if dA > 0.0 else 0.0) - (dB if dB > 0.0 else 0.0)
            z2 = (dC if dC > 0.0 else 0.0) - (dD if dD > 0.0 else 0.0)
            e = wrap + mu * math.hypot(z1, z2)  # (TR2) capstan exponent
            gp, gm = g_plus(e), g_minus(e)
            # tensions (rad of pull): own stretch + the other pair's bend (signed coupling)
            cz = c1 * z2
            tA = (dA if dA > 0.0 else 0.0) + (cz if cz > 0.0 else 0.0)
            tB = (dB if dB > 0.0 else 0.0) + (-cz if cz < 0.0 else 0.0)
            cz = c2 * z1
            tC = (dC if dC > 0.0 else 0.0) + (cz if cz > 0.0 else 0.0)
            tD = (dD if dD > 0.0 else 0.0) + (-cz if cz < 0.0 else 0.0)
            # (TR1), (TR4): each distal pull sticks inside its friction band
            p = x1 - s1
            dA = min(max(dA, p - w1 - k1 * tA * gp), p + w1 + k1 * tA * gm)
            p = -x1 - s1
            dB = min(max(dB, p - w1 - k1 * tB * gp), p + w1 + k1 * tB * gm)
            p = x2 - s2
            dC = min(max(dC, p - w2 - k2 * tC * gp), p + w2 + k2 * tC * gm)
            p = -x2 - s2
            dD = min(max(dD, p - w2 - k2 * tD * gp), p + w2 + k2 * tD * gm)
        return [dA, dB, dC, dD]

    @staticmethod
    def effective(d: Sequence[float]) -> tuple[float, float]:
        """Effective knob angles (z1, z2) (rad) of distal pulls d (4,)."""
        dA, dB, dC, dD = d
        return max(dA, 0.0) - max(dB, 0.0), max(dC, 0.0) - max(dD, 0.0)

    def simulate(self, x_path: ArrayLike, x_start: ArrayLike | None = None) -> Array:
        """Effective knobs (n, 2) along motor knob commands ``x_path`` (n, 2) or (n, 4) (rad),
        from a relaxed transmission at ``x_start`` (2,) (default: the first command)."""
        x = check_finite(x_path, "x_path", "rad")
        if x.ndim != 2 or x.shape[1] not in (2, 4) or x.shape[0] < 1:
            raise ShapeError(f"x_path must have shape (n, 2) or (n, 4), got {x.shape}")
        x = x[:, :2]
        start = x[0] if x_start is None else check_finite(x_start, "x_start", "rad").ravel()[:2]
        d = self.relaxed_state(start).tolist()
        prev = [float(start[0]), float(start[1])]
        out = np.empty((x.shape[0], 2))
        for k, row in enumerate(x.tolist()):
            d = self.step(d, prev, row)
            prev = row
            out[k] = self.effective(d)
        return out


# --- observations ----------------------------------------------------------------------------


def observed_knobs(tip2base: ArrayLike, geometry: CatheterGeometry = DEFAULT_GEOMETRY) -> Array:
    """Model knob pairs (n, 2) (rad) whose model tip *position* is the tracked one.

    Position only (the roll and the image frame's twist do not enter): the bending plane is
    ``theta = atan2(y, x)`` and the bend alpha solves, by Gauss-Newton, the radial distance
    and height of the constant-curvature tip with the ultrasound offset (Eq. (2))::

        rho(alpha) = L (1 - cos alpha) / alpha + off sin alpha,  z(alpha) = L sin alpha / alpha
        + off cos alpha

    ``tip2base`` (n, 4, 4) in the base frame (mm), roll 0, d4 0; NaN poses give NaN rows.
    """
    t = np.asarray(tip2base, dtype=np.float64)
    if t.ndim != 3 or t.shape[1:] != (4, 4):
        raise ShapeError(f"tip2base must have shape (n, 4, 4), got {t.shape}")
    p = t[:, :3, 3]
    big_l, off = geometry.bending_length, geometry.us_offset
    theta = np.arctan2(p[:, 1], p[:, 0])
    rho = np.hypot(p[:, 0], p[:, 1])
    pz = p[:, 2]
    a = np.clip(rho / (0.5 * big_l + off), 1e-6, math.pi)  # small-angle start
    for _ in range(30):
        sa, ca = np.sin(a), np.cos(a)
        r1 = big_l * (1.0 - ca) / a + off * sa - rho
        r2 = big_l * sa / a + off * ca - pz
        j1 = big_l * (sa * a - (1.0 - ca)) / a**2 + off * ca
        j2 = big_l * (ca * a - sa) / a**2 - off * sa
        da = (j1 * r1 + j2 * r2) / (j1 * j1 + j2 * j2)
        a = np.clip(a - da, 1e-9, math.pi)
    k = geometry.knob_ratio
    return np.stack([a * np.cos(theta) / k, a * np.sin(theta) / k], axis=-1)


def circle_path(
    radii: Sequence[float] = (math.radians(25.0), math.radians(50.0), math.radians(75.0)),
    step: float = math.radians(3.0),
) -> Array:
    """Knob circles for identification: motor joint states (n, 4) (rad).

    From rest, for each radius r: a ray to (r, 0), one turn counter-clockwise, one turn
    clockwise, back to (0, 0); ``step`` (rad) is the largest knob change per sample.
    """
    rr = [float(r) for r in radii]
    if not rr or any(not (0.0 < r <= math.pi / 2) for r in rr):
        raise ConfigurationError(f"radii must be in (0, pi/2] rad, got {radii!r}")
    if not (0.0 < step <= math.radians(10.0)):
        raise ConfigurationError(f"step must be in (0, {math.radians(10):.4f}] rad, got {step}")
    rows: list[Array] = []
    for r in rr:
        n_ray = max(1, math.ceil(r / step))
        ray = np.linspace(0.0, r, n_ray + 1)[1:]
        n_turn = max(8, math.ceil(2.0 * math.pi * r / step))
        t = np.linspace(0.0, 2.0 * math.pi, n_turn + 1)[1:]
        ccw = np.stack([r * np.cos(t), r * np.sin(t)], axis=-1)
        cw = np.stack([r * np.cos(-t), r * np.sin(-t)], axis=-1)
        rows += [np.stack([ray, 0 * ray], -1), ccw, cw, np.stack([ray[::-1] - ray[0], 0 * ray], -1)]
    k2 = np.concatenate(rows)
    out = np.zeros((k2.shape[0], 4))
    out[:, :2] = k2
    return out


@dataclass(frozen=True)
class CalibrationMotion:
    """One continuous commanded motion and what the tracker saw (from a relaxed start)."""

    q_motor: Array
    """(n, 4) motor joint states commanded in order (rad, rad, rad, mm)."""
    observed: Array
    """(n, 2) model knob angles of the tracked tip after each command (rad); NaN = MISSING."""
    q_start: Array = field(default_factory=lambda: np.zeros(4))
    """(4,) motor joint state at which the transmission was relaxed before the motion."""
    tip2base: Array | None = None
    """(n, 4, 4) the tracked tip poses (mm, base frame; NaN = MISSING), if kept: they can
    join the samples of the elasticity map (:func:`build_transmission`)."""

    def __post_init__(self) -> None:
        q = check_finite(self.q_motor, "q_motor")
        y = np.asarray(self.observed, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != 4 or q.shape[0] < 1:
            raise ShapeError(f"q_motor must have shape (n, 4), got {q.shape}")
        if y.shape != (q.shape[0], 2):
            raise ShapeError(f"observed must have shape ({q.shape[0]}, 2), got {y.shape}")
        if np.any(np.isinf(y)):
            raise ConfigurationError("observed must be finite or NaN (missing), got inf")
        s = check_finite(self.q_start, "q_start").ravel()
        if s.size != 4:
            raise ShapeError(f"q_start must have 4 values, got {s.size}")
        object.__setattr__(self, "q_motor", q)
        object.__setattr__(self, "observed", y)
        object.__setattr__(self, "q_start", s)
        if self.tip2base is not None:
            t = np.asarray(self.tip2base, dtype=np.float64)
            if t.shape != (q.shape[0], 4, 4):
                raise ShapeError(f"tip2base must have shape ({q.shape[0]}, 4, 4), got {t.shape}")
            object.__setattr__(self, "tip2base", t)


KNOB_CIRCLES = "knob circles"
"""Segment name of the knob circles in a :class:`icenav.calibration.plans.MotionPlan`."""


def circle_plan(
    radii: Sequence[float] = (math.radians(25.0), math.radians(50.0), math.radians(75.0)),
    step: float = math.radians(3.0),
) -> MotionPlan:
    """The knob circles (:func:`circle_path`) as a plan from rest: one tracker sample per
    move, no retry (a MISSING sample is a gap), then back to rest at zeros."""
    return MotionPlan.concat(
        [
            MotionPlan.make(circle_path(radii, step), KNOB_CIRCLES, n_average=1, retries=0),
            MotionPlan.make(np.zeros((1, 4)), "to zero", n_average=0, retries=0),
        ]
    )


def motion_from(
    recording: Recording,
    phase: str = KNOB_CIRCLES,
    tracker_bias: TrackerBias | None = None,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> CalibrationMotion:
    """The recorded segment ``phase`` as a :class:`CalibrationMotion` (observed knobs from the
    tracked tips; NaN where MISSING), with ``tracker_bias`` removed from the tips if given."""
    q, poses = recording.part(phase)
    poses = np.array(poses)
    ok = np.all(np.isfinite(poses.reshape(q.shape[0], -1)), axis=1)
    if tracker_bias is not None and np.any(ok):
        poses[ok] = tracker_bias.correct_poses(poses[ok])
    obs = np.full((q.shape[0], 2), np.nan)
    if np.any(ok):
        obs[ok] = observed_knobs(poses[ok], geometry)
    return CalibrationMotion(q_motor=np.array(q), observed=obs, tip2base=poses)


def record_motion(
    move: Callable[[Array], object],
    tracker: object,
    q_path: ArrayLike,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> CalibrationMotion:
    """Drive ``q_path`` (n, 4) with ``move(q)`` and read ``tracker.measure_tip2base()`` after
    each command (None = MISSING -> NaN poses and knobs). The robot must start at rest at
    zeros (the motion's ``q_start``), e.g. right after a relaxation move."""
    q = check_finite(q_path, "q_path")
    if q.ndim != 2 or q.shape[1] != 4:
        raise ShapeError(f"q_path must have shape (n, 4), got {q.shape}")
    if not callable(getattr(tracker, "measure_tip2base", None)):
        raise TrackerError("tracker must have a measure_tip2base() method")
    plan = MotionPlan.make(q, KNOB_CIRCLES, n_average=1, retries=0)
    rec = execute_plan(move, tracker, plan, geometry=geometry)  # type: ignore[arg-type]
    return motion_from(rec, geometry=geometry)


# --- identification --------------------------------------------------------------------------


def _least_squares_fit(a: Array, y: Array) -> Array:
    """argmin_c |a c - y| for a small tall system (n, m), by the normal equations with the
    columns scaled to unit norm (a hot loop: LAPACK's lstsq costs ~20 ms per call with two
    BLAS threads on two cores, this ~0.2 ms)."""
    scale = np.sqrt(np.einsum("ij,ij->j", a, a))
    scale[scale == 0.0] = 1.0
    an = a / scale
    ata = an.T @ an
    ata[np.diag_indices_from(ata)] += 1e-12
    return np.asarray(np.linalg.solve(ata, an.T @ y) / scale[:, None], dtype=np.float64)


def _poly_basis(z: Array, degree: int) -> Array:
    """Bivariate monomials z1^a z2^b, a + b <= degree: (n, m)."""
    cols = [z[:, 0] ** a * z[:, 1] ** (n - a) for n in range(degree + 1) for a in range(n + 1)]
    return np.stack(cols, axis=-1)


@dataclass(frozen=True)
class TransmissionFit:
    """Result of :func:`identify_transmission`."""

    model: TendonTransmission
    """The identified transmission."""
    rms: float
    """RMS residual of the tracked model knobs (rad) with the identified model."""
    rms_without_play: float
    """The same residual with a play-free transmission (z = x) and the same static map (rad):
    what the play model explains."""
    static_coefficients: Array
    """(m, 2) coefficients of the static polynomial map G: z -> observed model knobs."""
    n_samples: int
    """Valid samples used."""
    n_evaluations: int
    """Model simulations made by the optimiser."""
    degree: int = 7
    """Total degree of the static map G (``static_coefficients`` has (degree+1)(degree+2)/2
    rows)."""


def _design(motions: Sequence[CalibrationMotion], weight_limit: float) -> tuple[list, Array, Array]:
    ys, masks = [], []
    for m in motions:
        ok = np.all(np.isfinite(m.observed), axis=1)
        ok &= np.max(np.abs(m.q_motor[:, :2]), axis=1) <= weight_limit + 1e-9
        masks.append(ok)
        ys.append(m.observed[ok])
    return masks, np.concatenate(ys), np.concatenate([np.flatnonzero(k) for k in masks])


def identify_transmission(
    motions: Sequence[CalibrationMotion],
    *,
    initial: TendonTransmission | None = None,
    degree: int = 7,
    fit_limit: float = math.radians(70.0),
    max_gain: float = 1.0,
    max_nfev: int = 60,
    static_coefficients: ArrayLike | None = None,
) -> TransmissionFit:
    """Identify a :class:`TendonTransmission` from commanded motions and the tracked tip.

    For a parameter vector the model is simulated along every motion (each from its relaxed
    start), a bivariate polynomial ``G`` of total ``degree`` from the effective knobs to the
    observed model knobs is fitted by linear least squares, and the residuals
    ``G(z_k) - y_k`` (rad) of all valid samples are minimised over the 10 parameters with
    :func:`scipy.optimize.least_squares` (trust-region reflective, bounds). Samples whose
    commanded knobs exceed ``fit_limit`` (rad) are left out of the residual (the workspace
    corners saturate) but still simulated.

    Parameters
    ----------
    motions : sequence of CalibrationMotion
        E.g. the dense raster (serpentine) and :func:`circle_path` recorded with
        :func:`record_motion`; at least 50 valid samples in all, with two-knob motion.
    initial : TendonTransmission, optional
        Start of the search (default: 1 deg slack and play, kappa 0.05, wrap 0.5, mu 0.5).
    degree, fit_limit : int, float
        Degree of ``G`` and the largest commanded knob angle (rad) of a sample in the fit.
    max_gain : float
        Bound of |kappa| and |gamma| (rad/rad).
    static_coefficients : array-like, shape (m, 2), optional
        Keep ``G`` fixed (e.g. a straight-vessel fit's ``static_coefficients``) instead of
        refitting it: for re-identifying the plays in situ (in a curved vessel) from knob
        circles alone, with the bending section's elasticity as calibrated.
    """
    if not motions or not all(isinstance(m, CalibrationMotion) for m in motions):
        raise ConfigurationError("motions must be a non-empty sequence of CalibrationMotion")
    if not (1 <= int(degree) <= 9):
        raise ConfigurationError(f"degree must be in [1, 9], got {degree}")
    if not (0.0 < float(max_gain) <= 2.0):
        raise ConfigurationError(f"max_gain must be in (0, 2] rad/rad, got {max_gain}")
    masks, y, _ = _design(motions, float(fit_limit))
    n_valid = y.shape[0]
    if n_valid < 50:
        raise ConfigurationError(f"only {n_valid} valid samples within fit_limit; need >= 50")
    one = math.radians(1.0)
    init = (
        TendonTransmission(
            ap=PairTransmission(one, one, 0.05, 0.0),
            rl=PairTransmission(one, one, 0.05, 0.0),
            wrap=0.5,
            friction=0.5,
        )
        if initial is None
        else initial
    )
    b = float(max_gain)
    lo = np.array([0, 0, 0, -b, 0, 0, 0, -b, 0, 0])
    hi = np.array([_MAX_PLAY, _MAX_PLAY, b, b, _MAX_PLAY, _MAX_PLAY, b, b, 5.0, 3.0])
    x0 = np.clip(init.to_vector(), lo, hi - 1e-9)
    step = init.max_substep
    count = [0]

    def effective(theta: Array) -> Array:
        model = TendonTransmission.from_vector(np.clip(theta, lo, hi), max_substep=step)
        count[0] += 1
        zs = [
            model.simulate(m.q_motor, m.q_start[:2])[k] for m, k in zip(motions, masks, strict=True)
        ]
        return np.concatenate(zs)

    fixed = None
    if static_coefficients is not None:
        fixed = check_finite(static_coefficients, "static_coefficients")
        m_terms = (int(degree) + 1) * (int(degree) + 2) // 2
        if fixed.shape != (m_terms, 2):
            raise ShapeError(
                f"static_coefficients must have shape ({m_terms}, 2) for degree {degree}, "
                f"got {fixed.shape}"
            )

    def resid_for(z: Array) -> tuple[Array, Array]:
        a = _poly_basis(z, int(degree))
        if fixed is not None:
            return np.asarray(a @ fixed - y, dtype=np.float64).ravel(), fixed
        coef = _least_squares_fit(a, y)
        return np.asarray(a @ coef - y, dtype=np.float64).ravel(), coef

    def resid(theta: Array) -> Array:
        return resid_for(effective(theta))[0]

    sol = least_squares(
        resid, x0, bounds=(lo, hi), x_scale="jac", diff_step=1e-3, max_nfev=max_nfev
    )
    model = TendonTransmission.from_vector(sol.x, max_substep=step)
    r, coef = resid_for(effective(sol.x))
    x_cmd = np.concatenate([m.q_motor[k, :2] for m, k in zip(motions, masks, strict=True)])
    r0, _ = resid_for(x_cmd)
    return TransmissionFit(
        model=model,
        rms=float(np.sqrt(np.mean(r**2) * 2.0)),
        rms_without_play=float(np.sqrt(np.mean(r0**2) * 2.0)),
        static_coefficients=coef,
        n_samples=n_valid,
        n_evaluations=count[0],
        degree=int(degree),
    )


# --- compensation ----------------------------------------------------------------------------


class TendonCompensator:
    """Stateful inverse of a :class:`TendonTransmission` (knobs), with the roll's and the
    twist's per-joint plays of :class:`icenav.compensation.hysteresis.HysteresisCompensator`.

    :meth:`command` takes the wanted *effective* joint state (z1, z2, phi3, d4) and returns the
    motor command; the model's tendon state is advanced as if that command were executed.
    """

    def __init__(
        self,
        model: TendonTransmission,
        roll: HysteresisCompensator | None = None,
        *,
        knob_limit: float = DEFAULT_GEOMETRY.knob_limit,
        dead_zone_ramp: float = math.radians(0.5),
        xtol: float = 1e-7,
    ) -> None:
        if not isinstance(model, TendonTransmission):
            raise ConfigurationError(f"model must be a TendonTransmission, got {type(model)}")
        self.model = model
        """The transmission being inverted."""
        self.roll = (
            None
            if roll is None
            else HysteresisCompensator(
                [None, None, roll.joints[2], roll.joints[3]],
                roll_play_per_bend=roll.roll_play_per_bend,
                twist_play_per_bend=roll.twist_play_per_bend,
                reversal_threshold=roll.reversal_threshold,
            )
        )
        """Per-joint compensator for phi3 and d4 (knobs pass through), or None."""
        self.knob_limit = _check_range("knob_limit", knob_limit, 1e-3, math.pi, "rad")
        """Motor knob limit (rad): commands are searched within +-knob_limit."""
        self.dead_zone_ramp = _check_range(
            "dead_zone_ramp", dead_zone_ramp, 1e-6, math.radians(5.0), "rad"
        )
        """eps (rad): |z*| below it is reached by interpolating the commands for +-eps."""
        self.xtol = float(xtol)
        self.reset()

    def reset(self, x_motor: ArrayLike = (0.0, 0.0, 0.0, 0.0)) -> None:
        """Relaxed state at motor joint state ``x_motor`` (4,) (default zeros)."""
        q = check_finite(x_motor, "x_motor").ravel()
        if q.size != 4:
            raise ShapeError(f"x_motor must have 4 values, got {q.size}")
        self._x = [float(q[0]), float(q[1])]
        self._d = self.model.relaxed_state(q[:2]).tolist()
        if self.roll is not None:
            self.roll.reset(np.array([0.0, 0.0, q[2], q[3]]))

    @property
    def effective_knobs(self) -> tuple[float, float]:
        """The model's current effective knob angles (rad)."""
        return self.model.effective(self._d)

    def _z_after(self, x: list[float]) -> tuple[float, float]:
        return self.model.effective(self.model.step(self._d, self._x, x))

    def _solve_knob(self, j: int, target: float, x: list[float]) -> float:
        lim = self.knob_limit

        def f(v: float) -> float:
            xx = list(x)
            xx[j] = v
            return self._z_after(xx)[j] - target

        here = x[j]
        fh = f(here)
        if fh == 0.0:
            return here
        sgn = -1.0 if fh > 0.0 else 1.0  # direction to move
        stepv = math.radians(2.0)
        a = here
        while True:
            b = min(max(a + sgn * stepv, -lim), lim)
            fb = f(b)
            if fb == 0.0:
                return b
            if (fb > 0.0) != (fh > 0.0):
                lo_, hi_ = (a, b) if a < b else (b, a)
                return float(brentq(f, lo_, hi_, xtol=self.xtol))
            if b in (-lim, lim):
                return b  # unreachable within the limits: the nearest reachable command
            a, fh = b, fb
            stepv *= 2.0

    def _solve(self, target: tuple[float, float]) -> list[float]:
        x = list(self._x)
        for _ in range(8):  # Gauss-Seidel over the pair (coupled through bend and tension)
            before = list(x)
            for j in (0, 1):
                x[j] = self._solve_knob(j, target[j], x)
            if max(abs(x[0] - before[0]), abs(x[1] - before[1])) < self.xtol:
                break
        return x

    def knob_command(self, z1: float, z2: float) -> tuple[float, float]:
        """Motor knobs (rad) that bring the model's effective knobs to (z1, z2) (rad) from its
        current state, which is *not* advanced (see :meth:`advance`)."""
        eps = self.dead_zone_ramp
        tz = (float(z1), float(z2))
        inside = [abs(t) < eps for t in tz]
        if not any(inside):
            x = self._solve(tz)
        else:
            # inside a dead-zone: interpolate the commands for +-eps (no jump across it),
            # then solve the other knob exactly with that one fixed
            xa = self._solve((-eps if inside[0] else tz[0], -eps if inside[1] else tz[1]))
            xb = self._solve((eps if inside[0] else tz[0], eps if inside[1] else tz[1]))
            x = []
            for j in (0, 1):
                w = (tz[j] + eps) / (2.0 * eps) if inside[j] else 0.5
                x.append(xa[j] + w * (xb[j] - xa[j]))
            for j in (0, 1):
                if not inside[j]:
                    x[j] = self._solve_knob(j, tz[j], x)
        return float(x[0]), float(x[1])

    def state(self) -> tuple[tuple[float, ...], tuple[float, float]]:
        """The knobs' state: distal pulls (4,) and motor knobs (2,), for :meth:`set_state`."""
        return tuple(self._d), (self._x[0], self._x[1])

    def set_state(self, state: tuple[tuple[float, ...], tuple[float, float]]) -> None:
        """Restore a state taken with :meth:`state`."""
        d, x = state
        self._d = [float(v) for v in d]
        self._x = [float(x[0]), float(x[1])]

    def advance(self, x1: float, x2: float) -> None:
        """Advance the model's tendon state as the knobs move to (x1, x2) (rad)."""
        x = [float(x1), float(x2)]
        self._d = self.model.step(self._d, self._x, x)
        self._x = x

    def command(self, q_effective: ArrayLike, bend: float | None = None) -> Array:
        """Motor command (4,) for the wanted effective joint state (4,) (z1, z2 rad, phi3 rad,
        d4 mm); ``bend`` (rad) is passed to the roll's play model. The state is advanced as if
        the command were executed."""
        z = check_finite(q_effective, "q_effective").ravel()
        if z.size != 4:
            raise ShapeError(f"q_effective must have 4 values, got {z.size}")
        x = self.knob_command(float(z[0]), float(z[1]))
        self.advance(*x)
        out = z.copy()
        out[0], out[1] = x
        if self.roll is not None:
            r = self.roll.command(np.array([z[0], z[1], z[2], z[3]]), bend)
            out[2], out[3] = r[2], r[3]
        return out

    def command_path(self, q_effective_path: ArrayLike, bends: ArrayLike | None = None) -> Array:
        """Motor commands (n, 4) for wanted effective joint states (n, 4); ``bends`` (n,) rad."""
        path = check_finite(q_effective_path, "q_effective_path")
        if path.ndim != 2 or path.shape[1] != 4:
            raise ShapeError(f"q_effective_path must have shape (n, 4), got {path.shape}")
        if bends is None:
            return np.array([self.command(row) for row in path])
        b = check_finite(bends, "bends", "rad").ravel()
        if b.size != path.shape[0]:
            raise ShapeError(f"bends must have {path.shape[0]} values, got {b.size}")
        return np.array([self.command(row, float(bi)) for row, bi in zip(path, b, strict=True)])


def transmission_commands(
    q_model: ArrayLike,
    effective_map: object,
    compensator: TendonCompensator,
    *,
    approach_steps: int = 20,
    savgol_window: int = 15,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    tracker_bias: TrackerBias | None = None,
) -> Array:
    """Motor commands (approach_steps + n, 4) for a model path (n, 4): the ``dense+hysteresis``
    condition of :mod:`icenav.eval.spin`::

        approach from rest -> twist pre-shape -> F_eff -> Savitzky-Golay -> TendonCompensator

    ``effective_map`` is F on effective knobs, normally ``TransmissionCalibration.
    effective_map`` (anything with ``model_to_motor(q, check=False)``); the compensator
    (``TransmissionCalibration.compensator``) is reset to rest first. Defaults match spin's
    constants (``APPROACH_STEPS`` 20, ``SAVGOL_WINDOW`` 15); the knob commands are clipped to
    the knob limits. In ``icenav.eval.spin._commands`` the condition is one line::

        return transmission_commands(q_model, cal.transmission.effective_map,
                                     cal.transmission.compensator)

    With a ``tracker_bias`` (the calibration's, :mod:`icenav.compensation.tracker_bias`) the model
    path is
    first shifted so the tracker reads the intended tip (F must then be built bias-free, as
    :func:`calibrate_transmission` does with the same bias).
    """

    qm = check_finite(q_model, "q_model")
    if qm.ndim != 2 or qm.shape[1] != 4:
        raise ShapeError(f"q_model must have shape (n, 4), got {qm.shape}")
    if tracker_bias is not None:
        qm = tracker_bias.shift_model_path(qm, geometry)
    n_app = int(approach_steps)
    if n_app < 1:
        raise ConfigurationError(f"approach_steps must be >= 1, got {approach_steps}")
    approach = np.linspace(np.zeros(4), qm[0], n_app + 1)[1:]
    path = np.vstack([approach, qm])
    lim = geometry.knob_limit
    model = path if compensator.roll is None else compensator.roll.preshape_model(path)
    model[:, :2] = np.clip(model[:, :2], -lim, lim)
    to_motor = getattr(effective_map, "model_to_motor", None)
    if not callable(to_motor):
        raise ConfigurationError("effective_map must have model_to_motor (an ElasticityMap)")
    eff = np.asarray(to_motor(model, check=False), dtype=np.float64)
    eff[n_app:] = savgol_smooth(eff[n_app:], savgol_window)
    eff[:n_app] = np.linspace(np.zeros(4), eff[n_app], n_app + 1)[1:]
    bends = geometry.knob_ratio * np.hypot(path[:, 0], path[:, 1])
    compensator.reset()
    cmd = compensator.command_path(eff, bends=bends)
    cmd[:, :2] = np.clip(cmd[:, :2], -lim, lim)
    return cmd


# --- calibration (identification + the elasticity map on effective knobs) --------------------


@dataclass(frozen=True)
class TransmissionCalibration:
    """Everything the tendon compensation needs, calibrated on one catheter."""

    fit: TransmissionFit
    """The identified transmission and its residuals."""
    effective_map: ElasticityMap
    """F on effective knobs: model knobs -> the effective knobs that put the real tip there
    (thin-plate RBF, smoothed, over the relabelled raster and circle samples)."""
    compensator: TendonCompensator
    """The stateful inverse (knobs), with the roll's per-joint play if given."""
    n_moves: int
    """Robot moves made by :func:`calibrate_transmission` (0 for :func:`build_transmission`)."""


F_SMOOTHING = 0.3
"""Smoothing of the thin-plate RBF of F on effective knobs (RBFInterpolator's ``smoothing``).
The relabelled samples are no longer a grid and include exact duplicates (saturated corners);
an exact interpolant (0) oscillates between them (spin errors up to 10 mm on catheter 50).
Measured on development catheters 50-52 (straight vessel, mean EM position at 20 / 40 / 60
deg): 0.1: 2.12 / 2.10 / 2.32 mm; 0.3: 2.11 / 2.15 / 2.31; 1: 2.13 / 2.20 / 2.35; 3: 2.17 /
2.27 / 2.44 (10 and more worse still, catheter 50); 0.3 keeps a margin from the exact fit."""


def build_transmission(
    dense: CalibrationSet,
    raster: ArrayLike,
    circles: CalibrationMotion | None = None,
    roll: HysteresisCompensator | None = None,
    *,
    smoothing: float = F_SMOOTHING,
    circles_in_map: bool = True,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    **identify_kwargs: Any,
) -> TransmissionCalibration:
    """Identify the tendon transmission and build F on its effective knobs.

    Parameters
    ----------
    dense : CalibrationSet
        The dense raster as measured (skipped samples missing).
    raster : array-like, shape (n, 4)
        The raster's full command path in the order driven, from rest at zeros
        (:func:`icenav.calibration.plans.raster_grid`); each sample of ``dense`` is matched to it.
    circles : CalibrationMotion, optional
        Knob circles (:func:`circle_path` recorded by :func:`record_motion`): the two-knob
        motions that identify the coupling. With ``circles_in_map`` and poses kept, their
        relabelled samples also join F.
    roll : HysteresisCompensator, optional
        The per-joint model whose roll and twist plays the compensator keeps.
    smoothing : float
        RBF smoothing of F (see :data:`F_SMOOTHING`).
    identify_kwargs
        Passed to :func:`identify_transmission` (degree, fit_limit, max_gain, max_nfev).
    """
    if not isinstance(dense, CalibrationSet):
        raise ConfigurationError(f"dense must be a CalibrationSet, got {type(dense).__name__}")
    path = check_finite(raster, "raster", "rad")
    if path.ndim != 2 or path.shape[1] != 4:
        raise ShapeError(f"raster must have shape (n, 4), got {path.shape}")
    gap = np.max(np.abs(path[None, :, :3] - dense.q_motor[:, None, :3]), axis=-1)
    keep = np.argmin(gap, axis=1)
    if float(np.max(gap[np.arange(keep.size), keep])) > 1e-6:
        raise ConfigurationError("the dense calibration's samples are not on the raster path")
    obs = np.full((path.shape[0], 2), np.nan)
    obs[keep] = observed_knobs(dense.tip2base, geometry)
    motions = [CalibrationMotion(q_motor=path, observed=obs)]
    if circles is not None:
        motions.append(circles)
    fit = identify_transmission(motions, **identify_kwargs)
    eff = fit.model.simulate(path, x_start=[0.0, 0.0])
    q_eff = np.zeros((keep.size, 4))
    q_eff[:, :2] = eff[keep]
    poses = [dense.tip2base]
    if circles is not None and circles_in_map and circles.tip2base is not None:
        zc = fit.model.simulate(circles.q_motor, x_start=circles.q_start[:2])
        ok = np.all(np.isfinite(circles.tip2base.reshape(zc.shape[0], -1)), axis=1)
        qc = np.zeros((int(ok.sum()), 4))
        qc[:, :2] = zc[ok]
        q_eff = np.vstack([q_eff, qc])
        poses.append(circles.tip2base[ok])
    lim = geometry.knob_limit
    q_eff[:, :2] = np.clip(q_eff[:, :2], -lim, lim)
    samples = CalibrationSet(
        q_motor=q_eff,
        tip2base=np.concatenate(poses),
        catheter_id=dense.catheter_id,
        vessel=dense.vessel,
        method="tendon-effective",
    )
    fmap = ElasticityMap.build(samples, geometry, interpolant="rbf", smoothing=float(smoothing))
    return TransmissionCalibration(
        fit=fit,
        effective_map=fmap,
        compensator=TendonCompensator(fit.model, roll, knob_limit=lim),
        n_moves=0,
    )


def calibrate_transmission(
    move: Callable[[Array], object],
    tracker: object,
    dense: CalibrationSet,
    raster: ArrayLike,
    roll: HysteresisCompensator | None = None,
    *,
    radii: Sequence[float] = (math.radians(25.0), math.radians(50.0), math.radians(75.0)),
    step: float = math.radians(3.0),
    tracker_bias: TrackerBias | None = None,
    **kwargs: Any,
) -> TransmissionCalibration:
    """Drive the knob circles (:func:`circle_path`, ~800 moves for the default radii) from
    rest at zeros, then :func:`build_transmission` with the dense raster. ``kwargs`` go to
    :func:`build_transmission`. With a ``tracker_bias`` the raster's and the circles' tracked
    tips are corrected for it first (then pass it to :func:`transmission_commands` too)."""
    if tracker_bias is not None:
        dense = tracker_bias.correct_calibration(dense)
        tracker = tracker_bias.corrected(tracker)  # type: ignore[arg-type]
    path = circle_path(radii, step)
    circles = record_motion(move, tracker, path)
    move(np.zeros(4))
    cal = build_transmission(dense, raster, circles, roll, **kwargs)
    return replace(cal, n_moves=path.shape[0] + 1)


def reidentify_in_situ(
    move: Callable[[Array], object],
    tracker: object,
    calibration: TransmissionCalibration,
    roll: HysteresisCompensator | None = None,
    *,
    radii: Sequence[float] = (math.radians(25.0), math.radians(50.0), math.radians(75.0)),
    step: float = math.radians(3.0),
    max_nfev: int = 60,
    tracker_bias: TrackerBias | None = None,
) -> TransmissionCalibration:
    """Re-identify the plays in the vessel of use (e.g. a curved one) from knob circles
    alone (~800 moves, no raster), before a procedure.

    The shaft's path through the vessel widens every tendon's friction band (capstan wrap);
    the bending section's elasticity -- the static map G and F -- stays as calibrated. So the
    10 parameters are refitted with G fixed to the calibration's (``static_coefficients``),
    starting from the calibrated model, and F is kept. ``roll``: the per-joint model for the
    roll and twist in that vessel (e.g. :func:`icenav.calibration.plans.identify_hysteresis` run
    there); default: the calibration's. The robot must start at rest at zeros. With the
    calibration's ``tracker_bias`` the circles' tracked tips are corrected for it (the bias
    belongs to the tracker's field, not to the vessel).
    """
    if not isinstance(calibration, TransmissionCalibration):
        raise ConfigurationError(
            f"calibration must be a TransmissionCalibration, got {type(calibration).__name__}"
        )
    if tracker_bias is not None:
        tracker = tracker_bias.corrected(tracker)  # type: ignore[arg-type]
    path = circle_path(radii, step)
    circles = record_motion(move, tracker, path)
    move(np.zeros(4))
    fit = identify_transmission(
        [circles],
        initial=calibration.fit.model,
        degree=calibration.fit.degree,
        static_coefficients=calibration.fit.static_coefficients,
        max_nfev=max_nfev,
    )
    old = calibration.compensator
    comp = TendonCompensator(
        fit.model,
        old.roll if roll is None else roll,
        knob_limit=old.knob_limit,
        dead_zone_ramp=old.dead_zone_ramp,
    )
    return TransmissionCalibration(
        fit=fit,
        effective_map=calibration.effective_map,
        compensator=comp,
        n_moves=path.shape[0] + 1,
    )
