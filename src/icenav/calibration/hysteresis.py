"""Identification of the per-joint dead-zone / backlash models
(:mod:`icenav.compensation.hysteresis`) from sweeps, and the sweeps as a motion plan.

:func:`identify` fits one joint from a short up/down sweep (:func:`sweep_path`): a grid
search over (r, d, c) with, for each, a linear least-squares fit of a static odd cubic from
``z`` to the observed output (the tip's bend measured by the tracker, which also carries the
elastic nonlinearity), then a local refinement. :func:`hysteresis_plan` is the sweeps of every
joint (the knobs straight and with the other knob bent, the roll straight and bent) as a
:class:`~icenav.calibration.plans.MotionPlan`; :func:`fit_hysteresis` turns its recording
into a :class:`~icenav.compensation.hysteresis.HysteresisCompensator` with the growth of the
plays with the bend.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.calibration.plans import MotionPlan, Recording, _check_counts
from icenav.calibration.twist_circle import (
    AGREEMENT,
    SPIN_CIRCLE,
    circle_twist_readings,
    spin_circle_path,
)
from icenav.compensation.bend_play import BendPlay, KnobPlanePlay, PlayLaw, select_bend_play
from icenav.compensation.hysteresis import HysteresisCompensator, JointHysteresis, _play
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry
from icenav.geometry.kinematics import inverse as kin_inverse

__all__ = [
    "HysteresisFit",
    "HysteresisIdentification",
    "HysteresisPlan",
    "DIRECTION_AMPLITUDE",
    "DIRECTION_STEP",
    "PLAY_DIRECTIONS",
    "fit_hysteresis",
    "hysteresis_plan",
    "identify",
    "short_hysteresis_plan",
    "sweep_path",
]


def sweep_path(amplitude: float, step: float = math.radians(1.0), cycles: int = 1) -> Array:
    """A short up/down sweep 0 -> +A -> -A -> +A ... -> 0 (rad), for :func:`identify`."""
    if not (0.0 < amplitude <= math.pi) or not (0.0 < step < amplitude):
        raise ConfigurationError(
            f"need 0 < step < amplitude <= pi rad, got amplitude={amplitude}, step={step}"
        )
    n = max(2, int(math.ceil(amplitude / step)))
    up = np.linspace(0.0, amplitude, n + 1)
    down = np.linspace(amplitude, -amplitude, 2 * n + 1)[1:]
    parts = [up]
    for _ in range(cycles):
        parts += [down, -down]
    parts.append(np.linspace(amplitude, 0.0, n + 1)[1:])
    return np.concatenate(parts)


@dataclass(frozen=True)
class HysteresisFit:
    """Result of :func:`identify`."""

    model: JointHysteresis
    """The identified transmission model."""
    gain: tuple[float, float, float]
    """(offset, linear, cubic) of the static map z -> observed output."""
    rms: float
    """RMS residual of the fit, in the unit of the observed output."""


def _static_fit(z: Array, y: Array, cubic: bool) -> tuple[Array, float]:
    cols = [np.ones_like(z), z, z**3] if cubic else [np.ones_like(z), z]
    a = np.stack(cols, axis=-1)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    r = a @ coef - y
    if not cubic:
        coef = np.append(coef, 0.0)
    return np.asarray(coef, dtype=np.float64), float(np.sqrt(np.mean(r * r)))


def _batched_static_fit(z: Array, y: Array, cubic: bool) -> tuple[Array, Array]:
    """Least-squares fits of y ~ a + b z (+ c z^3) for many z rows (m, n): coefs, rms.

    Normal equations from power sums (one pass per power over z), solved in a batch.
    """
    n = z.shape[-1]
    z2 = z * z
    z3 = z2 * z
    s1, s2, s3 = z.sum(-1), z2.sum(-1), z3.sum(-1)
    sy, szy, syy = float(y.sum()), z @ y, float(y @ y)
    if cubic:
        s4, s6 = (z2 * z2).sum(-1), (z3 * z3).sum(-1)
        sz3y = z3 @ y
        ata = np.stack(
            [
                np.stack([np.full_like(s1, n), s1, s3], -1),
                np.stack([s1, s2, s4], -1),
                np.stack([s3, s4, s6], -1),
            ],
            -2,
        )
        aty = np.stack([np.full_like(s1, sy), szy, sz3y], -1)
    else:
        ata = np.stack([np.stack([np.full_like(s1, n), s1], -1), np.stack([s1, s2], -1)], -2)
        aty = np.stack([np.full_like(s1, sy), szy], -1)
    k = ata.shape[-1]
    coef = np.linalg.solve(ata + 1e-12 * np.eye(k), aty[..., None])[..., 0]
    # residual sum of squares = y.y - 2 c.A^T y + c.A^T A c
    rss = syy - 2.0 * np.sum(coef * aty, -1) + np.einsum("mi,mij,mj->m", coef, ata, coef)
    return coef, np.sqrt(np.maximum(rss, 0.0) / n)


def identify(
    x: ArrayLike,
    y: ArrayLike,
    *,
    max_width: float = math.radians(10.0),
    resolution: float = math.radians(0.5),
    max_slope: float = 0.2,
    cubic: bool = True,
    with_dead_zone: bool = True,
) -> HysteresisFit:
    """Identify a joint's backlash + dead-zone from a sweep.

    Parameters
    ----------
    x : array-like, shape (n,)
        Commanded motor angles of the sweep (rad), starting from a relaxed state
        (e.g. :func:`sweep_path`).
    y : array-like, shape (n,)
        Observed output at each sample (e.g. the tip's bend in the knob's plane, rad).
        NaN marks a missing sample (skipped).
    max_width : float
        Largest backlash and dead-zone half-width searched (rad).
    max_slope : float
        Largest growth of the play with |x| searched (rad/rad); 0 for a constant play.
    cubic : bool
        Fit an odd cubic static map (for the elastic nonlinearity of the bend) or a line.
    with_dead_zone : bool
        Search a dead-zone (False: backlash only, e.g. for the roll joint).
    """
    xs = check_finite(x, "x", "rad").ravel()
    ys = np.asarray(y, dtype=np.float64).ravel()
    if xs.shape != ys.shape or xs.size < 10:
        raise ConfigurationError(
            f"x and y must have the same shape with >= 10 samples, got {xs.shape}, {ys.shape}"
        )
    ok = np.isfinite(ys)
    if ok.sum() < 10:
        raise ConfigurationError(f"only {int(ok.sum())} valid samples; need >= 10")
    yv = ys[ok]
    widths = np.arange(0.0, max_width + 0.5 * resolution, resolution)
    slopes = np.linspace(0.0, max_slope, 9) if max_slope > 0 else np.array([0.0])
    dzs = widths if with_dead_zone else np.array([0.0])
    centres = np.arange(-4, 5) * resolution if with_dead_zone else np.array([0.0])
    best = (math.inf, 0.0, 0.0, 0.0, 0.0)
    x0 = float(xs[0])
    for r in widths:
        for r1 in slopes:
            p = _play(xs, float(r), x0, float(r1))[ok]
            u = p[None, :] - centres[:, None]  # (nc, n)
            z = np.sign(u)[None] * np.maximum(np.abs(u)[None] - dzs[:, None, None], 0.0)
            _, rms = _batched_static_fit(z.reshape(-1, p.size), yv, cubic)
            k = int(np.argmin(rms))
            if rms[k] < best[0]:
                di, ci = divmod(k, centres.size)
                best = (float(rms[k]), float(r), float(r1), float(dzs[di]), float(centres[ci]))

    def resid(theta: Array) -> Array:
        r, r1, d, c = (float(v) for v in theta)
        p = _play(xs, max(r, 0.0), x0, max(r1, 0.0))[ok] - c
        z = np.sign(p) * np.maximum(np.abs(p) - max(d, 0.0), 0.0)
        coef, _ = _static_fit(z, yv, cubic)
        return np.asarray((coef[0] + coef[1] * z + coef[2] * z**3) - yv)

    theta0 = np.array(best[1:])
    lo = [0.0, 0.0, 0.0, -math.radians(10)]
    hi = [
        max_width,
        max(max_slope, 1e-9),
        max_width if with_dead_zone else 1e-9,
        math.radians(10) if with_dead_zone else 1e-9,
    ]
    theta0 = np.clip(theta0, lo, [h - 1e-12 for h in hi])
    sol = least_squares(resid, theta0, bounds=(lo, hi), diff_step=1e-3)
    theta = sol.x if float(np.sqrt(np.mean(sol.fun**2))) < best[0] else theta0
    r, r1, d, c = (float(v) for v in theta)
    if not with_dead_zone:
        d, c = 0.0, 0.0
    model = JointHysteresis(
        backlash=max(r, 0.0), backlash_slope=max(r1, 0.0), dead_zone=max(d, 0.0), centre=c
    )
    p = _play(xs, model.backlash, x0, model.backlash_slope)[ok]
    coef, fit_rms = _static_fit(model.dead_zone_out(p), yv, cubic)
    return HysteresisFit(
        model=model, gain=(float(coef[0]), float(coef[1]), float(coef[2])), rms=fit_rms
    )


@dataclass(frozen=True)
class HysteresisIdentification:
    """Result of :func:`fit_hysteresis`."""

    compensator: HysteresisCompensator
    """Compensator with the identified models (phi1, phi2, phi3; d4 passes through)."""
    fits: tuple[HysteresisFit, ...]
    """The fits of phi1, phi2 and phi3."""
    n_moves: int
    """Robot moves made."""


def _observe_sweep(
    x: Array, poses: Array, joint: int, base: Array, geometry: CatheterGeometry
) -> tuple[Array, Array]:
    """Observed output of a sweep of ``joint`` (values ``x`` (m,), tracked poses (m, 4, 4),
    NaN where missing) from ``base``: the bend in the knob's plane (knobs); for the roll,
    the azimuth of the tip about the base z axis when bent, else phi3 of the model inverse
    kinematics (rad). Also returns the image frame's roll (phi3 of the model inverse
    kinematics; NaN for the knobs)."""
    y = np.full(x.size, np.nan)
    y_frame = np.full(x.size, np.nan)
    valid = np.flatnonzero(np.all(np.isfinite(poses.reshape(x.size, -1)), axis=1))
    if valid.size == 0:
        return y, y_frame
    t = poses[valid]
    qm = kin_inverse(t, geometry, check=False)
    if joint == 2:
        y_frame[valid] = np.unwrap(qm[:, 2])  # the roll of the model for the image frame
        if math.hypot(base[0], base[1]) > 0.1:
            # bent: the azimuth of the tip about the base axis turns with the base roll only
            y[valid] = np.unwrap(np.arctan2(t[:, 1, 3], t[:, 0, 3]))
        else:
            y = y_frame.copy()
        return y, y_frame
    k2 = qm[:, :2]
    # principal direction of the tip's bend during the sweep
    _, _, vt = np.linalg.svd(k2 - k2.mean(axis=0), full_matrices=False)
    d = vt[0]
    if d[joint] < 0:
        d = -d
    y[valid] = k2 @ d
    return y, y_frame


@dataclass(frozen=True, eq=False)
class HysteresisPlan:
    """The sweeps of :func:`hysteresis_plan` as a :class:`MotionPlan`, with what the fit
    needs to read them."""

    plan: MotionPlan
    """Segments ``sweep phi1``, ``sweep phi1, phi2 bent``, ``sweep phi2``, ``sweep phi3``,
    ``sweep phi3, phi1 bent``, ``bend check`` (those of the joints asked for), the moves
    between them unread."""
    sweep: Array
    """(m,) joint values of one sweep (rad): 0 -> +A -> -A -> +A -> 0 of the knobs."""
    roll_sweep: Array
    """(m',) the same for the straight roll (the bent roll sweeps swing wider)."""
    joints: tuple[int, ...]
    """Joints swept (0, 1, 2: phi1, phi2, phi3)."""
    bend: float
    """Knob angle of the bent sweeps (rad; 0: none)."""
    more_bends: tuple[float, ...] = ()
    """Further AP knob angles (rad) of roll sweeps (segments ``sweep phi3, phi1 bent N``
    and ``bend check N``, N in deg), for the roll's and the twist's play against the bend
    (:func:`icenav.compensation.bend_play.select_bend_play`)."""
    play_directions: tuple[float, ...] = ()
    """Further directions of the bend in the knob plane (rad, in (0, pi)) of one roll sweep
    each at the knob angle ``bend`` (segments ``sweep phi3, bent N deg`` and ``bend check N
    deg``, N the direction in deg): the plays over the knob plane
    (:class:`icenav.compensation.bend_play.KnobPlanePlay`)."""
    spin_circle: bool = False
    """Whether the plan holds the spin circle (segment ``spin circle``,
    :mod:`icenav.calibration.twist_circle`): the twist's play over the whole knob plane."""


PLAY_DIRECTIONS = (math.pi / 4, math.pi / 2, 3 * math.pi / 4)
"""The directions of the bend (rad in the knob plane: the diagonal, the RL knob, the
anti-diagonal) swept besides the AP knob's in the full calibration's plan."""


DIRECTION_AMPLITUDE = math.radians(50.0)
"""Swing of the further directions' roll sweeps in the full calibration's plan (rad): wide
enough for the roll's play there (its reading's bound 40 deg); the twist's play over the knob
plane is read off the spin circle instead (:mod:`icenav.calibration.twist_circle`), whose robot
time this narrower swing pays for (docs/calibration.md section 7)."""


DIRECTION_STEP = math.radians(10.0)
"""Step of the further directions' roll sweeps (rad): twice the AP knob's, so that the plan
stays under 10 min of robot time (docs/calibration.md section 7)."""


def _direction_tag(psi: float) -> str:
    return f" {math.degrees(psi):.0f} deg"


def hysteresis_plan(
    *,
    amplitude: float = math.radians(60.0),
    step: float = math.radians(3.0),
    roll_amplitude: float = math.radians(30.0),
    roll_step: float = math.radians(5.0),
    roll_widening: float = 0.8,
    roll_bend: float = math.radians(50.0),
    more_roll_bends: Sequence[float] = (math.radians(25.0), math.radians(75.0)),
    joints: Sequence[int] = (0, 1, 2),
    retries: int = 10,
    play_directions: Sequence[float] | None = None,
    direction_step: float | None = None,
    bent_step: float | None = None,
    spin_circle: bool = False,
    direction_amplitude: float | None = None,
) -> HysteresisPlan:
    """The sweeps: each knob of ``joints`` 0 -> +A -> -A -> +A -> 0 (``amplitude``, in
    ``step``) with the others at 0, one tracker sample per step; phi1 again with phi2 at
    ``roll_bend``. The roll straight (``roll_amplitude``, in ``roll_step``), again with phi1
    at ``roll_bend`` and then a 5-sample reading of the bend there (0: no bent sweeps), and
    likewise at each of ``more_roll_bends`` (rad, AP knob; the play against the bend is
    measured at every bent sweep). A bent roll sweep at knob angle k swings
    ``roll_amplitude + roll_widening * k``: the plays widen with the bend, and a sweep
    narrower than the roll's and the twist's plays together leaves the image frame still
    (its reading saturates, :data:`SATURATION_MARGIN`). With ``play_directions`` (rad in (0,
    pi); default :data:`PLAY_DIRECTIONS` when ``more_roll_bends`` is not empty, else none)
    the roll is swept once more per direction with the knobs bent ``roll_bend`` along it
    (``phi1, phi2 = roll_bend (cos psi, sin psi)``; in ``direction_step``, default
    ``roll_step``), for the plays over the knob plane. The bent roll sweeps go in
    ``bent_step`` (default ``roll_step``). With ``spin_circle`` (and the roll among
    ``joints``), the spin circle of :func:`icenav.calibration.twist_circle.spin_circle_path`
    follows the roll's sweeps (the twist's play over the whole knob plane, read while
    turning). The further directions' sweeps swing ``direction_amplitude`` (rad; default
    that of the AP knob's sweep at ``roll_bend``). The robot starts and ends at zeros
    (unread moves)."""
    _check_counts(retries, 1)
    if not (0.0 <= roll_widening <= 2.0):
        raise ConfigurationError(f"roll_widening must be in [0, 2] rad/rad, got {roll_widening}")
    js = tuple(int(j) for j in joints)
    more = tuple(float(b) for b in more_roll_bends) if roll_bend > 0.0 else ()
    for b in more:
        if not (0.0 < b <= DEFAULT_GEOMETRY.knob_limit) or b == roll_bend:
            raise ConfigurationError(
                f"more_roll_bends must be in (0, {math.degrees(DEFAULT_GEOMETRY.knob_limit):.0f}]"
                f" deg and differ from roll_bend, got {math.degrees(b):.1f} deg"
            )
    dirs: tuple[float, ...]
    if play_directions is None:
        dirs = PLAY_DIRECTIONS if more else ()
    else:
        dirs = tuple(float(p) for p in play_directions) if roll_bend > 0.0 else ()
    for p in dirs:
        if not (0.0 < p < math.pi):
            raise ConfigurationError(
                f"play_directions must be in (0, 180) deg, got {math.degrees(p):.1f} deg"
            )
    if any(b <= a for a, b in zip(dirs, dirs[1:], strict=False)):
        raise ConfigurationError(f"play_directions must be ascending, got {dirs!r}")
    dstep = DIRECTION_STEP if direction_step is None else float(direction_step)
    for j in js:
        if j not in (0, 1, 2):
            raise ConfigurationError(f"joints must be among 0, 1, 2 (phi1..phi3), got {j}")
    sweep = sweep_path(amplitude, step)
    roll_sweep = sweep_path(roll_amplitude, roll_step)

    bstep = roll_step if bent_step is None else float(bent_step)

    def bent_roll_sweep(knob: float, step: float = bstep) -> Array:
        return sweep_path(min(roll_amplitude + roll_widening * knob, math.pi), step)

    if direction_amplitude is not None and not (0.0 < direction_amplitude <= math.pi):
        raise ConfigurationError(
            f"direction_amplitude must be in (0, 180] deg, got "
            f"{math.degrees(direction_amplitude):.1f} deg"
        )
    dpath = (
        bent_roll_sweep(roll_bend, dstep)
        if direction_amplitude is None
        else sweep_path(float(direction_amplitude), dstep)
    )

    zero = np.zeros((1, 4))
    parts: list[MotionPlan] = []

    def swept(path: Array, joint: int, base: Array, phase: str) -> MotionPlan:
        q = np.tile(base, (path.size, 1))
        q[:, joint] = path
        return MotionPlan.make(q, phase, n_average=1, retries=retries)

    def unread(q: Array, phase: str) -> MotionPlan:
        return MotionPlan.make(np.atleast_2d(q), phase, n_average=0, retries=0)

    for j in js:
        path = roll_sweep if j == 2 else sweep
        parts += [unread(zero, "to zero"), swept(path, j, np.zeros(4), f"sweep phi{j + 1}")]
        if j == 0 and roll_bend > 0.0:
            base = np.array([0.0, roll_bend, 0.0, 0.0])
            parts += [unread(base, "to zero"), swept(path, 0, base, "sweep phi1, phi2 bent")]
        if j == 2 and roll_bend > 0.0:
            base = np.array([roll_bend, 0.0, 0.0, 0.0])
            parts += [
                unread(base, "to zero"),
                swept(bent_roll_sweep(roll_bend), 2, base, "sweep phi3, phi1 bent"),
                MotionPlan.make(base[None, :], "bend check", n_average=5, retries=retries),
            ]
            for b in more:
                base = np.array([b, 0.0, 0.0, 0.0])
                tag = f"{math.degrees(b):.0f}"
                parts += [
                    unread(base, "to zero"),
                    swept(bent_roll_sweep(b), 2, base, f"sweep phi3, phi1 bent {tag}"),
                    MotionPlan.make(
                        base[None, :], f"bend check {tag}", n_average=5, retries=retries
                    ),
                ]
            for psi in dirs:
                base = np.array([roll_bend * math.cos(psi), roll_bend * math.sin(psi), 0.0, 0.0])
                tag = _direction_tag(psi)
                parts += [
                    unread(base, "to zero"),
                    swept(dpath, 2, base, f"sweep phi3, bent{tag}"),
                    MotionPlan.make(
                        base[None, :], f"bend check{tag}", n_average=5, retries=retries
                    ),
                ]
    circle = bool(spin_circle) and 2 in js
    if circle:
        path = spin_circle_path()
        parts += [
            unread(np.array([path[-1, 0], path[-1, 1], 0.0, 0.0]), "to zero"),
            MotionPlan.make(path, SPIN_CIRCLE, n_average=1, retries=retries),
        ]
    parts.append(unread(zero, "to zero"))
    return HysteresisPlan(
        plan=MotionPlan.concat(parts),
        sweep=sweep,
        roll_sweep=roll_sweep,
        joints=js,
        bend=float(roll_bend),
        more_bends=more,
        play_directions=dirs if 2 in js else (),
        spin_circle=circle,
    )


SATURATION_MARGIN = math.radians(10.0)
"""A bent roll sweep reads a play half-width only up to its amplitude less this margin (rad):
beyond, the output would swing less than twice the margin after a reversal, too little to
tell a wide play from a stalled tip; a width found at that bound is *saturated* and dropped."""


def _bent_roll_play(
    observed: Any,
    recording: Recording,
    straight_play: float,
    knob: float,
    tag: str,
    sweep: str = "sweep phi3, phi1 bent",
) -> tuple[float, float, float]:
    """One bent roll sweep (segment ``{sweep}{tag}``): the true bend there (rad, from the
    5-sample ``bend check{tag}``; the knob angle ``knob`` when it was not tracked), the roll
    play's extra half-width over the straight ``straight_play`` and the twist play's
    half-width (the image frame's extra lag over the section's) (rad).

    The play is searched up to the sweep's amplitude less :data:`SATURATION_MARGIN`; a width
    found at that bound is not a measurement (the plays together nearly fill the sweep, the
    tip hardly responds) and comes back NaN: the roll's extra play when the section's play
    saturates, the twist when the image frame's does."""
    x, y, y_frame = observed(f"{sweep}{tag}", 2)
    resolution = math.radians(0.5)
    wide = max(float(np.max(np.abs(x))) - SATURATION_MARGIN, 2.0 * resolution)
    kw: dict[str, Any] = {
        "cubic": False,
        "with_dead_zone": False,
        "max_slope": 0.0,
        "max_width": wide,
        "resolution": resolution,
    }
    bent = identify(x, y, **kw)
    frame = identify(x, y_frame, **kw)
    _, check = recording.part(f"bend check{tag}")
    pose = check[0]
    true_bend = (
        knob if not np.all(np.isfinite(pose)) else math.acos(max(-1.0, min(1.0, float(pose[2, 2]))))
    )
    true_bend = max(true_bend, math.radians(1.0))
    bound = wide - resolution
    roll_ok = bent.model.backlash < bound
    frame_ok = roll_ok and frame.model.backlash < bound
    return (
        true_bend,
        bent.model.backlash - straight_play if roll_ok else math.nan,
        frame.model.backlash - bent.model.backlash if frame_ok else math.nan,
    )


def _first_slope(points: Sequence[tuple[float, float, float]], k: int) -> float:
    """Play per rad of bend (clipped to [0, 0.5]) of the first bent sweep whose reading
    ``k`` (1: roll, 2: twist) is not saturated (the ``roll_bend`` sweep when it is not); 0
    when every reading is."""
    for p in points:
        if math.isfinite(p[k]):
            return min(max(0.0, p[k] / p[0]), 0.5)
    return 0.0


def _bend_law(points: Sequence[tuple[float, float, float]], k: int) -> BendPlay | None:
    """The law against the bend of reading ``k`` (1: roll, 2: twist) over the bent sweeps
    whose reading is not saturated (:func:`select_bend_play`); None when none is."""
    kept = [(p[0], p[k]) for p in points if math.isfinite(p[k])]
    if not kept:
        return None
    return select_bend_play([b for b, _ in kept], [e for _, e in kept])


SCALE_RANGE = (0.0, 4.0)
"""Bounds of a direction's scale of the AP knob's law (:func:`_direction_law`)."""


def _direction_law(ap: BendPlay | None, point: tuple[float, float, float], k: int) -> BendPlay:
    """The law of reading ``k`` (1: roll, 2: twist) in a direction swept at one bend: the
    AP knob's law ``ap`` scaled to pass through that sweep's reading ``e`` at its bend
    ``b``, ``e_psi(b') = e_AP(b') * e / e_AP(b)`` (B6; scale clipped to
    :data:`SCALE_RANGE`), the shape measured along the AP knob, the level in the direction.
    Without an AP law, or where the AP law is below 0.1 deg there, the line through the
    point; a saturated reading (NaN) keeps the AP law (or no play)."""
    b, e = point[0], point[k]
    if not math.isfinite(e):
        return ap if ap is not None else BendPlay.linear(0.0)
    e = max(e, 0.0)
    if ap is None or ap.at(b) < math.radians(0.1):
        return BendPlay("linear", (min(e / b, 0.5),), (b,), (e,))
    scale = min(max(e / ap.at(b), SCALE_RANGE[0]), SCALE_RANGE[1])
    return ap.scaled(scale)  # (B6)


def _knob_plane_law(
    ap: BendPlay | None, points: Sequence[tuple[float, float, float]], dirs: Sequence[float], k: int
) -> PlayLaw | None:
    """The AP knob's law and one law per further direction (:func:`_direction_law`) as a
    :class:`KnobPlanePlay`; the AP law alone without further directions."""
    if not dirs:
        return ap
    laws = [ap if ap is not None else BendPlay.linear(0.0)]
    laws += [_direction_law(ap, p, k) for p in points]
    return KnobPlanePlay((0.0, *dirs), tuple(laws))


def _circle_law(
    twist: PlayLaw | None, roll: PlayLaw | None, roll_base: float, recording: Recording
) -> PlayLaw | None:
    """The twist's law over the whole knob plane from the spin circle (TC1)-(TC2): in each
    direction read, the AP knob's law (the first of ``twist``) scaled to the reading (B6),
    period 360 deg. ``twist`` itself where the circle was not read in every direction, or
    where ``twist`` (the sweeps' law, which the circle did not fit) predicts its readings
    within :data:`~icenav.calibration.twist_circle.AGREEMENT` RMS (TC3)."""
    q, poses = recording.part(SPIN_CIRCLE)
    dirs, bends, extra = circle_twist_readings(q, poses, roll, roll_base)
    if not np.all(np.isfinite(extra)):
        return twist
    if twist is not None:
        predicted = np.array(
            [twist.at(float(b), float(d)) for b, d in zip(bends, dirs, strict=True)]
        )
        if math.sqrt(float(np.mean((predicted - extra) ** 2))) <= AGREEMENT:  # (TC3)
            return twist
    ap = twist.laws[0] if isinstance(twist, KnobPlanePlay) else twist
    laws = [
        _direction_law(ap, (float(b), math.nan, float(e)), 2)
        for b, e in zip(bends, extra, strict=True)
    ]
    return KnobPlanePlay(tuple(float(d) for d in dirs), tuple(laws), period=2.0 * math.pi)


def short_hysteresis_plan() -> HysteresisPlan:
    """The short calibration's sweeps (78 moves): the roll only, 0 -> +-30 deg in 5 deg
    steps, straight and with the AP knob at 50 deg (the roll's play and the twist's, as
    two-point lines; no knob sweeps, no further bends). With the 5-point search (11 moves)
    it stays within the 5 points plus 100 moves of a short calibration."""
    return hysteresis_plan(
        joints=(2,),
        roll_amplitude=math.radians(30.0),
        roll_step=math.radians(5.0),
        roll_widening=0.0,
        more_roll_bends=(),
        play_directions=(),
    )


def fit_hysteresis(
    hplan: HysteresisPlan,
    recording: Recording,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> HysteresisIdentification:
    """Fit the per-joint models to the recorded sweeps of ``hplan``.

    Each joint's sweep is fitted by :func:`identify` (knobs: the bend in the knob's plane from
    the model inverse kinematics, odd-cubic static map; roll: the tip roll, linear map, no
    dead-zone). The roll's second sweep with the AP knob bent gives ``roll_play_per_bend``
    (the growth of its play per rad of tracked bend) and, from the extra lag of the image
    frame over the base, ``twist_play_per_bend``; the AP knob's second sweep with the RL knob
    bent gives ``knob_play_per_bend``. With ``hplan.more_bends``, the roll's and the twist's
    play are measured at every bent sweep and their law against the bend is chosen by
    held-out residual (:func:`icenav.compensation.bend_play.select_bend_play`: linear,
    quadratic, power or a monotone table, each non-negative and non-decreasing in the bend);
    ``*_per_bend`` keep the slope of the ``roll_bend`` sweep. With ``hplan.play_directions``
    the roll's and the twist's plays become laws over the knob plane
    (:class:`~icenav.compensation.bend_play.KnobPlanePlay`): the AP knob's law, and in each
    further direction that law scaled to the direction's sweep (B6)."""
    if recording.plan is not hplan.plan and recording.plan.segments != hplan.plan.segments:
        raise ConfigurationError("the recording is not of this hysteresis plan")
    models: list[Any] = [None, None, None, None]
    fits: list[HysteresisFit] = []
    per_bend = 0.0
    knob_per_bend = 0.0
    twist_per_bend = 0.0
    roll_play: PlayLaw | None = None
    twist_play: PlayLaw | None = None
    bend = hplan.bend
    more = hplan.more_bends

    def observed(phase: str, joint: int) -> tuple[Array, Array, Array]:
        q, poses = recording.part(phase)
        x = q[:, joint].copy()
        y, y_frame = _observe_sweep(x, poses, joint, q[0], geometry)
        return x, y, y_frame

    for j in hplan.joints:
        roll = j == 2
        x, y, _ = observed(f"sweep phi{j + 1}", j)
        fit = identify(
            x, y, cubic=not roll, with_dead_zone=not roll, max_slope=0.0 if roll else 0.2
        )
        models[j] = fit.model
        fits.append(fit)
        if j == 0 and bend > 0.0:
            # the same sweep with the other knob bent: the play grows with the other bend
            x, y, _ = observed("sweep phi1, phi2 bent", 0)
            bent_fit = identify(x, y, cubic=True, with_dead_zone=True)
            mean_abs = float(np.mean(np.abs(x)))
            w_bent = bent_fit.model.backlash + bent_fit.model.backlash_slope * mean_abs
            w_straight = fit.model.backlash + fit.model.backlash_slope * mean_abs
            knob_per_bend = min(max(0.0, (w_bent - w_straight) / bend), 0.5)
        if roll and bend > 0.0:
            points = [
                _bent_roll_play(observed, recording, fit.model.backlash, knob, tag)
                for knob, tag in [(bend, ""), *((b, f" {math.degrees(b):.0f}") for b in more)]
            ]
            per_bend = _first_slope(points, 1)
            twist_per_bend = _first_slope(points, 2)
            if more:
                roll_play = _bend_law(points, 1)
                twist_play = _bend_law(points, 2)
            dirs = hplan.play_directions
            if dirs:
                ap_roll = roll_play if roll_play is not None else BendPlay.linear(per_bend)
                ap_twist = twist_play if twist_play is not None else BendPlay.linear(twist_per_bend)
                assert isinstance(ap_roll, BendPlay) and isinstance(ap_twist, BendPlay)
                tagged = [
                    _bent_roll_play(
                        observed,
                        recording,
                        fit.model.backlash,
                        bend,
                        _direction_tag(p),
                        sweep="sweep phi3, bent",
                    )
                    for p in dirs
                ]
                roll_play = _knob_plane_law(ap_roll, tagged, dirs, 1)
                twist_play = _knob_plane_law(ap_twist, tagged, dirs, 2)
            if hplan.spin_circle:
                twist_play = _circle_law(twist_play, roll_play, fit.model.backlash, recording)
    return HysteresisIdentification(
        compensator=HysteresisCompensator(
            models,
            roll_play_per_bend=per_bend,
            knob_play_per_bend=knob_per_bend,
            twist_play_per_bend=twist_per_bend,
            roll_play=roll_play,
            twist_play=twist_play,
        ),
        fits=tuple(fits),
        n_moves=hplan.plan.n,
    )
