"""Identification of the per-tendon transmission (:mod:`icenav.compensation.transmission`)
from two-knob motions, and F on its effective knobs (beyond the paper).

Identification (:func:`identify_transmission`) uses only motor commands and the EM-tracked tip:
the model is simulated along the commanded calibration paths (the dense raster, knob circles
of a few radii in both directions, :func:`circle_path`), the tracked tip is turned into model
knob angles (:func:`observed_knobs`, position only), and a static map ``G`` (a bivariate
polynomial, fitted by linear least squares for each parameter vector: variable projection)
from ``z`` to them closes the residual that :func:`scipy.optimize.least_squares` minimises.

Calibration: knob circles at 25 / 50 / 75 deg, both ways (:func:`circle_plan`), with the
raster; the form is chosen on held-out paths (:func:`identify_transmission_form`), F_eff is a
smoothed thin-plate RBF over the samples relabelled with the model's effective knobs
(:func:`build_transmission`). :func:`reidentify_in_situ` refits the plays in a curved vessel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.calibration.knob_residual import circle_residual
from icenav.calibration.plans import MotionPlan, Recording
from icenav.calibration.spin_path import SPIN_SCORE, spin_path_rms
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.compensation.hysteresis import HysteresisCompensator
from icenav.compensation.section_length import SectionLength
from icenav.compensation.tracker_bias import TrackerBias
from icenav.compensation.transmission import (
    _MAX_PLAY,
    COUPLING_FORMS,
    EXTENSIONS,
    PairTransmission,
    TendonCompensator,
    TendonTransmission,
    TransmissionCalibration,
    TransmissionFit,
    g_plus,
    static_terms,
)
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry

__all__ = [
    "CalibrationMotion",
    "F_SMOOTHING",
    "FIT_LIMIT",
    "KNOB_CIRCLES",
    "FORM_MARGIN",
    "TRIED_EXTENSIONS",
    "TRIED_RESIDUAL",
    "TRIED_WRAPS",
    "build_transmission",
    "circle_blocks",
    "circle_path",
    "circle_plan",
    "identify_transmission",
    "identify_transmission_form",
    "motion_from",
    "observed_knobs",
    "reidentify_in_situ",
]


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
    section: SectionLength | None = None,
) -> CalibrationMotion:
    """The recorded segment ``phase`` as a :class:`CalibrationMotion` (observed knobs from the
    tracked tips; NaN where MISSING), with ``tracker_bias`` removed from the tips if given,
    then the ``section``'s axial excess (:meth:`SectionLength.correct_poses`) if given."""
    q, poses = recording.part(phase)
    poses = np.array(poses)
    ok = np.all(np.isfinite(poses.reshape(q.shape[0], -1)), axis=1)
    if tracker_bias is not None and np.any(ok):
        poses[ok] = tracker_bias.correct_poses(poses[ok])
    if section is not None and np.any(ok):
        poses[ok] = section.correct_poses(poses[ok])
    obs = np.full((q.shape[0], 2), np.nan)
    if np.any(ok):
        obs[ok] = observed_knobs(poses[ok], geometry)
    return CalibrationMotion(q_motor=np.array(q), observed=obs, tip2base=poses)


def _least_squares_fit(a: Array, y: Array) -> Array:
    """argmin_c |a c - y| for a small tall system (n, m), by the normal equations with the
    columns scaled to unit norm (a hot loop: ~0.2 ms against lstsq's ~20 ms on two cores)."""
    scale = np.sqrt(np.einsum("ij,ij->j", a, a))
    scale[scale == 0.0] = 1.0
    an = a / scale
    ata = an.T @ an
    ata[np.diag_indices_from(ata)] += 1e-12
    return np.asarray(np.linalg.solve(ata, an.T @ y) / scale[:, None], dtype=np.float64)


def _poly_basis(z: Array, degree: int) -> Array:
    """Bivariate monomials z1^a z2^b, a + b <= degree: (n, m)."""
    cols = [z[:, 0] ** a * z[:, 1] ** b for a, b in static_terms(degree)]
    return np.stack(cols, axis=-1)


_EXTRA_HIGH = {"none": (), "bend-tension": (2.0,), "two-play": (0.95, 5.0)}
"""Upper bounds of each extension's parameters (their lower bounds are 0)."""

FIT_LIMIT = math.radians(70.0)
"""Default ``fit_limit`` (rad): commanded knobs beyond it stay out of the residual."""


def _pair_rms(r: Array) -> float:
    """RMS residual per knob pair (rad) of residuals ``r`` (n, 2) or flattened."""
    return float(np.sqrt(np.mean(np.asarray(r) ** 2) * 2.0))


def _design(
    motions: Sequence[CalibrationMotion],
    weight_limit: float,
    keep: Sequence[ArrayLike] | None = None,
) -> tuple[list, Array, Array]:
    if keep is not None and len(keep) != len(motions):
        raise ShapeError(f"masks must have one array per motion ({len(motions)}), got {len(keep)}")
    ys, masks = [], []
    for i, m in enumerate(motions):
        ok = np.all(np.isfinite(m.observed), axis=1)
        ok &= np.max(np.abs(m.q_motor[:, :2]), axis=1) <= weight_limit + 1e-9
        if keep is not None:
            k = np.asarray(keep[i], dtype=bool).ravel()
            if k.shape != ok.shape:
                raise ShapeError(f"masks[{i}] must have shape {ok.shape}, got {k.shape}")
            ok &= k
        masks.append(ok)
        ys.append(m.observed[ok])
    return masks, np.concatenate(ys), np.concatenate([np.flatnonzero(k) for k in masks])


def identify_transmission(
    motions: Sequence[CalibrationMotion],
    *,
    initial: TendonTransmission | None = None,
    degree: int = 7,
    fit_limit: float = FIT_LIMIT,
    max_gain: float = 1.0,
    max_nfev: int = 60,
    static_coefficients: ArrayLike | None = None,
    coupling_form: str | None = None,
    extension: str | None = None,
    masks: Sequence[ArrayLike] | None = None,
    wrap_range: tuple[float, float] | None = None,
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
        :func:`motion_from` of a recording; at least 50 valid samples in all, with two-knob motion.
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
    coupling_form : str, optional
        The tension form (:data:`~icenav.compensation.transmission.COUPLING_FORMS`); default:
        ``initial``'s (``"added"`` without ``initial``).
    extension : str, optional
        The model's extension (:data:`~icenav.compensation.transmission.EXTENSIONS`), whose
        parameters are fitted too; default: ``initial``'s (``"none"`` without ``initial``).
        Started from ``initial``'s values, or eta = 0.05, (a, rho) = (0.3, 0.5) where they
        are neutral.
    masks : sequence of bool arrays (n_i,), optional
        Per motion, the samples that may enter the residual (e.g. a held-out part left out);
        every motion is still simulated whole.
    wrap_range : (float, float), optional
        Bounds of the straight catheter's capstan exponent ``wrap`` (default [0, 5]); equal
        bounds hold it fixed (a profile of the fit along the wrap).
    """
    if not motions or not all(isinstance(m, CalibrationMotion) for m in motions):
        raise ConfigurationError("motions must be a non-empty sequence of CalibrationMotion")
    if not (1 <= int(degree) <= 9):
        raise ConfigurationError(f"degree must be in [1, 9], got {degree}")
    if not (0.0 < float(max_gain) <= 2.0):
        raise ConfigurationError(f"max_gain must be in (0, 2] rad/rad, got {max_gain}")
    masks, y, _ = _design(motions, float(fit_limit), masks)
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
    form = init.coupling_form if coupling_form is None else coupling_form
    if form not in COUPLING_FORMS:
        raise ConfigurationError(f"coupling_form must be one of {COUPLING_FORMS}, got {form!r}")
    ext = init.extension if extension is None else extension
    if ext not in EXTENSIONS:
        raise ConfigurationError(f"extension must be one of {EXTENSIONS}, got {ext!r}")
    start = init if init.extension == ext else init.with_extension(ext)
    x_extra = start.extra_vector()
    if ext == "bend-tension" and x_extra[0] == 0.0:
        x_extra = np.array([0.05])
    if ext == "two-play" and x_extra[0] == 0.0:
        x_extra = np.array([0.3, 0.5])
    b = float(max_gain)
    lo = np.array([0, 0, 0, -b, 0, 0, 0, -b, 0, 0] + [0.0] * x_extra.size)
    hi = np.array(
        [_MAX_PLAY, _MAX_PLAY, b, b, _MAX_PLAY, _MAX_PLAY, b, b, 5.0, 3.0] + list(_EXTRA_HIGH[ext])
    )
    if wrap_range is not None:
        w_lo, w_hi = (float(v) for v in wrap_range)
        if not (0.0 <= w_lo <= w_hi <= 5.0):
            raise ConfigurationError(
                f"wrap_range must satisfy 0 <= lo <= hi <= 5 (dimensionless), got {wrap_range}"
            )
        lo[8], hi[8] = w_lo, max(w_hi, w_lo + 1e-9)
    x0 = np.clip(np.concatenate([init.to_vector(), x_extra]), lo, hi - 1e-9)
    step = init.max_substep
    count = [0]

    def model_of(theta: Array) -> TendonTransmission:
        t = np.clip(theta, lo, hi)
        return TendonTransmission.from_vector(
            t[:10], max_substep=step, coupling_form=form, extension=ext, extra=t[10:]
        )

    def effective(theta: Array) -> Array:
        model = model_of(theta)
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
    model = model_of(sol.x)
    r, coef = resid_for(effective(sol.x))
    x_cmd = np.concatenate([m.q_motor[k, :2] for m, k in zip(motions, masks, strict=True)])
    r0, _ = resid_for(x_cmd)
    return TransmissionFit(
        model=model,
        rms=_pair_rms(r),
        rms_without_play=_pair_rms(r0),
        static_coefficients=coef,
        n_samples=n_valid,
        n_evaluations=count[0],
        degree=int(degree),
    )


def circle_blocks(q_motor: ArrayLike, rest: float = math.radians(0.5)) -> Array:
    """Label (n,) of each state of a knob-circle motion (n, >=2) (rad): 0 at rest before the
    first circle, then k for the k-th departure from rest (a ray, its circles, the way
    back); a state within ``rest`` (rad) of the knob origin keeps the current label."""
    q = check_finite(q_motor, "q_motor", "rad")
    if q.ndim != 2 or q.shape[1] < 2:
        raise ShapeError(f"q_motor must have shape (n, 2) or (n, 4), got {q.shape}")
    r = np.hypot(q[:, 0], q[:, 1])
    away = r > rest
    starts = away & ~np.concatenate([[False], away[:-1]])
    return np.cumsum(starts).astype(int)


FORM_MARGIN = 0.02
"""A form is kept over the one before it in the order tried (the added tension, TR3, then the
stretch form, TR3s, then each extension of the tension form kept) only where its held-out
residual is this fraction below the best so far: a tie keeps the simpler form."""

TRIED_WRAPS: tuple[float, ...] = ()
"""The capstan exponents ``wrap`` at which :func:`identify_transmission_form` holds the kept
tension form by default: none (0.3 / 0.6 tried, not adopted: docs/calibration.md 4c)."""

TRIED_EXTENSIONS = ("bend-tension", "two-play")
"""The extensions :func:`identify_transmission_form` tries by default on the tension form it
keeps (:data:`~icenav.compensation.transmission.EXTENSIONS`)."""

TRIED_RESIDUAL = False
"""Whether :func:`identify_transmission_form` tries the circle residual (KR1-KR3 of
:mod:`icenav.compensation.knob_residual`) on the form it keeps. Off by default: with it the
controller's own spin on development catheter 105 doubled its error, with one held-out path
or two (docs/calibration.md 4c, "the circle residual, switched off"); ``residual=True``."""


def identify_transmission_form(
    motions: Sequence[CalibrationMotion],
    held_out: Sequence[ArrayLike],
    *,
    forms: Sequence[str] = COUPLING_FORMS,
    extensions: Sequence[str] = TRIED_EXTENSIONS,
    residual: bool | None = None,
    train_nfev: int = 20,
    extension_nfev: int = 12,
    refit_nfev: int = 20,
    wraps: Sequence[float] | None = None,
    spin: CalibrationMotion | None = None,
    **identify_kwargs: Any,
) -> TransmissionFit:
    """Choose the transmission's form by held-out residual, then fit it on all the data.

    Each tension form of ``forms`` is identified (:func:`identify_transmission`) without the
    samples marked in ``held_out`` (one bool array (n_i,) per motion) and scored by the RMS
    residual of those samples, their static map G the training fit's; the tension form with
    the smallest residual (the first of ``forms`` unless another is :data:`FORM_MARGIN`
    lower) is kept. Then each of ``extensions`` is added to it, fitted the same way from the
    kept form's training solution (at most ``extension_nfev`` evaluations) and scored; an
    extension replaces the best so far only if its residual is :data:`FORM_MARGIN` lower.
    The winner is refitted on every sample from its training solution. ``train_nfev`` and
    ``refit_nfev`` bound the optimiser's evaluations of each tension form's training fit and
    of the refit (``max_nfev`` of :func:`identify_transmission`). The returned fit's
    ``held_out_rms`` lists each form's held-out residual (rad), named as
    :attr:`TendonTransmission.form`.

    Between the tension form and its extensions, the straight catheter's capstan exponent
    ``wrap`` may be held at each of ``wraps`` (default :data:`TRIED_WRAPS`, none): the kept
    form refitted without the held-out samples, the band's width kept at a 45-deg bend, and
    scored the same way; a held wrap that wins stays held (named ``form@wrap``).

    Last, with ``residual`` (default :data:`TRIED_RESIDUAL`) and the held-out samples in one
    motion of knob circles (:func:`circle_blocks`): the table of the kept form's miss on the
    other circles (:func:`~icenav.calibration.knob_residual.circle_residual`), interpolated
    in radius, is added to its effective knobs and scored on the held-out circle (not where
    the kept form has the ``"two-play"`` extension: docs/calibration.md, 4c); kept only
    if :data:`FORM_MARGIN` lower, and then refitted on every circle with the final model
    (named ``form+residual``).

    With ``spin`` (the spin circle recorded, :func:`motion_from` of its phase with its
    ``q_start``), every candidate is also scored on it (:func:`~icenav.calibration.spin_path.
    spin_path_rms`, named ``"spin circle: " + form``), and "lower" above means lower by
    :data:`FORM_MARGIN` on *both* held-out paths: a form or an extension or the table is
    kept only where it predicts the held-out knob circle and the spin better.
    """
    if len(held_out) != len(motions):
        raise ShapeError(f"held_out must have one array per motion ({len(motions)})")
    test = [np.asarray(h, dtype=bool).ravel() for h in held_out]
    if not any(np.any(t) for t in test):
        raise ConfigurationError("held_out marks no sample: nothing to choose the form by")
    bad = [e for e in extensions if e not in EXTENSIONS or e == "none"]
    if bad:
        raise ConfigurationError(f"extensions must be among {EXTENSIONS[1:]}, got {bad!r}")
    drop = ("coupling_form", "extension", "max_nfev")
    kwargs = {k: v for k, v in identify_kwargs.items() if k not in drop}
    limit = float(kwargs.get("fit_limit", FIT_LIMIT))
    train = [~t for t in test]
    fits: dict[str, TransmissionFit] = {}
    scores: list[tuple[str, float]] = []

    def score(fit: TransmissionFit, name: str) -> tuple[float, ...]:
        v = [_held_out_rms(fit, motions, test, limit)]
        scores.append((name, v[0]))
        if spin is not None:
            v.append(spin_path_rms(fit, spin.q_motor, spin.observed, spin.q_start, fit_limit=limit))
            scores.append((SPIN_SCORE + name, v[1]))
        return tuple(v)

    def wins(v: tuple[float, ...], than: tuple[float, ...]) -> bool:
        return all(a < b * (1.0 - FORM_MARGIN) for a, b in zip(v, than, strict=True))

    best_form, best = "", (math.inf,) * (1 if spin is None else 2)
    for form in forms:
        fit = identify_transmission(
            motions,
            coupling_form=form,
            extension="none",
            masks=train,
            max_nfev=int(train_nfev),
            **kwargs,
        )
        fits[form] = fit
        v = score(fit, form)
        if not best_form or wins(v, best):
            best_form, best = form, v
    base = fits[best_form].model
    ext_kwargs = {k: v for k, v in kwargs.items() if k not in ("initial", "wrap_range")}
    held: tuple[float, float] | None = None
    for w in TRIED_WRAPS if wraps is None else wraps:
        fit = identify_transmission(
            motions,
            initial=_with_wrap(base, float(w)),
            extension="none",
            masks=train,
            max_nfev=int(train_nfev),
            wrap_range=(float(w), float(w)),
            **ext_kwargs,
        )
        name = f"{base.form}@{float(w):g}"
        fits[name] = fit
        v = score(fit, name)
        if wins(v, best):
            best_form, best, held = name, v, (float(w), float(w))
    base = fits[best_form].model
    suffix = "" if held is None else f"@{held[0]:g}"
    for ext in extensions:
        fit = identify_transmission(
            motions,
            initial=base,
            extension=ext,
            masks=train,
            max_nfev=int(extension_nfev),
            wrap_range=held,
            **ext_kwargs,
        )
        name = fit.model.form + suffix
        fits[name] = fit
        v = score(fit, name)
        if wins(v, best):
            best_form, best = name, v
    table_from = None  # (motion index, circle labels) of the circle residual, if kept
    circ = [i for i, t in enumerate(test) if np.any(t)]
    two_play = fits[best_form].model.extension == "two-play"  # a fitted shape: not tried
    if (TRIED_RESIDUAL if residual is None else residual) and len(circ) == 1 and not two_play:
        m = motions[circ[0]]
        blocks = circle_blocks(m.q_motor)
        outer = sorted(set(range(1, int(blocks.max()) + 1)) - set(blocks[test[circ[0]]].tolist()))
        inside = np.max(np.abs(m.q_motor[:, :2]), axis=1) <= limit + 1e-9
        try:
            table = circle_residual(
                fits[best_form], m.q_motor, m.observed, blocks, outer,
                q_start=m.q_start[:2], keep=train[circ[0]] & inside,
            )  # fmt: skip
        except ConfigurationError:
            table = None  # too few settled samples on a circle: not tried
        if table is not None:
            fit = fits[best_form]
            fit = replace(fit, model=replace(fit.model, residual=table))
            if wins(score(fit, fit.model.form + suffix), best):
                table_from = (circ[0], list(range(1, int(blocks.max()) + 1)), inside, blocks)
    kwargs.pop("initial", None)
    kwargs["max_nfev"] = int(refit_nfev)
    if held is not None:
        kwargs["wrap_range"] = held
    final = identify_transmission(motions, initial=fits[best_form].model, **kwargs)
    if table_from is not None:
        i, every, inside, blocks = table_from
        m = motions[i]
        table = circle_residual(
            final, m.q_motor, m.observed, blocks, every, q_start=m.q_start[:2], keep=inside
        )
        final = replace(final, model=replace(final.model, residual=table))
    return replace(final, held_out_rms=tuple(scores))


_WRAP_BEND = math.radians(45.0)
"""The bend (rad) at which :func:`_with_wrap` keeps the band's width."""


def _with_wrap(model: TendonTransmission, wrap: float) -> TendonTransmission:
    """``model`` with its capstan exponent ``wrap`` set and each pair's band growth kappa
    rescaled so that kappa g+(wrap + mu b) is unchanged at b = 45 deg (TR2, TR4): a start
    whose band is the fitted one, the split between wrap and growth moved."""
    old = g_plus(model.wrap + model.friction * _WRAP_BEND)
    new = g_plus(wrap + model.friction * _WRAP_BEND)
    r = old / new if new > 0.0 else 1.0

    def pair(p: PairTransmission) -> PairTransmission:
        return replace(p, tension_play=min(p.tension_play * r, 1.0))

    return replace(model, wrap=wrap, ap=pair(model.ap), rl=pair(model.rl))


def _held_out_rms(
    fit: TransmissionFit,
    motions: Sequence[CalibrationMotion],
    test: Sequence[Array],
    fit_limit: float,
) -> float:
    """RMS residual (rad, per knob pair as ``TransmissionFit.rms``) of the ``test`` samples
    (valid, within ``fit_limit``) with the fit's model and static map."""
    masks, y, _ = _design(motions, fit_limit, test)
    if y.shape[0] == 0:
        raise ConfigurationError("no valid held-out sample within fit_limit")
    z = np.concatenate(
        [
            fit.model.simulate(m.q_motor, m.q_start[:2])[k]
            for m, k in zip(motions, masks, strict=True)
        ]
    )
    return _pair_rms(_poly_basis(z, fit.degree) @ fit.static_coefficients - y)


F_SMOOTHING = 0.1
"""Smoothing of the thin-plate RBF of F on effective knobs (RBFInterpolator's ``smoothing``):
the relabelled samples include exact duplicates (saturated corners), between which an exact
interpolant (0) oscillates; chosen on development catheters (docs/calibration.md, 4c)."""


def build_transmission(
    dense: CalibrationSet,
    raster: ArrayLike,
    circles: CalibrationMotion | None = None,
    roll: HysteresisCompensator | None = None,
    *,
    smoothing: float = F_SMOOTHING,
    circles_in_map: bool = True,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    section: SectionLength | None = None,
    choose_form: bool = True,
    spin: CalibrationMotion | None = None,
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
        Knob circles (:func:`circle_plan` recorded, :func:`motion_from`): the two-knob
        motions that identify the coupling. With ``circles_in_map`` and poses kept, their
        relabelled samples also join F.
    roll : HysteresisCompensator, optional
        The per-joint model whose roll and twist plays the compensator keeps.
    smoothing : float
        RBF smoothing of F (see :data:`F_SMOOTHING`).
    section : SectionLength, optional
        The section's identified length (:func:`~icenav.compensation.section_length.
        fit_section_length`): its axial excess is removed from ``dense`` here (``circles``
        must have it removed already, :func:`motion_from`) and the compensation sends it to
        the translation. None: the model's length.
    choose_form : bool
        With ``circles`` of at least three radii: the tension's form (TR3 or TR3s) is chosen
        by the residual of the middle circle predicted by a fit without it
        (:func:`identify_transmission_form`, whose own evaluation bounds then replace
        ``max_nfev``); otherwise, or if False, the form of ``identify_kwargs``' ``initial`` /
        ``coupling_form`` (default TR3).
    spin : CalibrationMotion, optional
        The spin circle as recorded (:func:`motion_from` of its phase, ``q_start`` the state
        before it): a second held-out path of the form's choice (``spin`` of
        :func:`identify_transmission_form`).
    identify_kwargs
        Passed to :func:`identify_transmission` (degree, fit_limit, max_gain, max_nfev).
    """
    if not isinstance(dense, CalibrationSet):
        raise ConfigurationError(f"dense must be a CalibrationSet, got {type(dense).__name__}")
    section = SectionLength.none() if section is None else section
    dense = section.correct(dense)
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
    blocks = None if circles is None else circle_blocks(circles.q_motor)
    if choose_form and blocks is not None and int(blocks.max()) >= 3:
        # the tension's form chosen by the middle circle's residual, predicted from the rest
        middle = blocks == (int(blocks.max()) + 1) // 2
        fit = identify_transmission_form(
            motions, [np.zeros(path.shape[0], dtype=bool), middle], spin=spin, **identify_kwargs
        )
    else:
        fit = identify_transmission(motions, **identify_kwargs)
    # the raster is labelled by the band alone: a circle residual is the circles' (KR3)
    eff = replace(fit.model, residual=None).simulate(path, x_start=[0.0, 0.0])
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
        section=section,
    )


def reidentify_in_situ(
    calibration: TransmissionCalibration,
    circles: CalibrationMotion,
    roll: HysteresisCompensator | None = None,
    *,
    max_nfev: int = 60,
) -> TransmissionCalibration:
    """Re-identify the plays in the vessel of use (e.g. a curved one) from knob circles
    recorded there alone (:func:`circle_plan`, ~800 moves, no raster), before a procedure.

    The shaft's path through the vessel widens every tendon's friction band (capstan wrap);
    the bending section's elasticity -- the static map G and F -- stays as calibrated. So the
    10 parameters are refitted with G fixed to the calibration's (``static_coefficients``),
    starting from the calibrated model, and F is kept. ``circles``: :func:`motion_from` of
    the recorded circles (with the calibration's tracker bias removed: the bias belongs to
    the tracker's field, not to the vessel). ``roll``: the per-joint model for the roll and
    twist in that vessel (:func:`icenav.calibration.hysteresis.fit_hysteresis` of sweeps
    there); default: the calibration's.
    """
    if not isinstance(calibration, TransmissionCalibration):
        raise ConfigurationError(
            f"calibration must be a TransmissionCalibration, got {type(calibration).__name__}"
        )
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
        n_moves=circles.q_motor.shape[0] + 1,
        section=calibration.section,
    )
