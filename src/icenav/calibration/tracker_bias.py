"""Separation of the EM tracker's base-frame field bias
(:class:`icenav.compensation.tracker_bias.TrackerBias`) by roll circles (beyond the paper).

*Roll circles* (:func:`roll_circle_path`): at a few knob poses the roll is turned through a
full circle in one direction and the tip is tracked (averaged) at each stop. A roll moves the
bent tip on a circle in the base frame while the field stays put, so the part of ``b`` that
does not turn with the roll is separable from the bend. :func:`fit_tracker_bias` fits, by
linear least squares (Eq. TB1)::

    m_i = R_z(r_i) P_k + b0 + B R_z(r_i) P_k                            # (TB1)

with ``P_k`` the (knob-frame) tip of pose ``k`` (its roll lag is the same at every stop,
approached the same way, so it is absorbed in ``P_k``), and an affine field
``b(x) = b0 + B x`` (base frame, mm). The bilinear term is linearised around the first
estimate of ``P_k`` (two passes). Components that turn with the roll (``b0_z``, the parts of
``B`` that commute with ``R_z``) cannot be separated from ``P_k``, nor need they be: F absorbs
them correctly. A small ridge keeps them at their minimum norm.

A field that assumes less: ``quadratic=True`` adds the term ``Q u(x - c)`` of Eq. (TB2)
(:class:`~icenav.compensation.tracker_bias.TrackerBias`). :func:`choose_tracker_bias` (what
:func:`fit_tracker_bias_from` does by default) keeps it per catheter only where the inner
circles, each held out in turn, are predicted better (:func:`held_out_rms`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.calibration.plans import MotionPlan, Recording
from icenav.compensation.tracker_bias import TrackerBias, quadratic_terms
from icenav.errors import ConfigurationError, ShapeError, TrackerError

__all__ = [
    "DEFAULT_ROLLS",
    "DEFAULT_ROLL_BENDS",
    "QUADRATIC_MARGIN",
    "ROLL_CIRCLES",
    "choose_tracker_bias",
    "fit_tracker_bias",
    "fit_tracker_bias_from",
    "held_out_rms",
    "roll_circle_path",
    "roll_circle_plan",
]


DEFAULT_ROLL_BENDS = tuple(math.radians(a) for a in (0.0, 25.0, 50.0, 75.0))
"""AP knob angles (rad) of the roll circles: the straight tip and three bends spanning the
spin's workspace."""


DEFAULT_ROLLS = tuple(math.radians(a) for a in range(0, 360, 45))
"""Roll stops (rad) of each circle: 8, every 45 deg, always approached increasing."""


_PRE_ROLL = math.radians(45.0)


_RIDGE = 1e-3


def _rz(r: Array) -> Array:
    """(n, 3, 3) rotations about z by angles r (n,) (rad)."""
    c, s = np.cos(r), np.sin(r)
    out = np.zeros((r.size, 3, 3))
    out[:, 0, 0] = c
    out[:, 0, 1] = -s
    out[:, 1, 0] = s
    out[:, 1, 1] = c
    out[:, 2, 2] = 1.0
    return out


def roll_circle_path(
    bends: Sequence[float] = DEFAULT_ROLL_BENDS,
    rolls: Sequence[float] = DEFAULT_ROLLS,
) -> tuple[Array, NDArray[np.bool_]]:
    """Command path of the roll circles and which stops are measured.

    For each AP knob angle ``a`` of ``bends`` (rad): the knobs go to ``(a, 0)`` at roll
    ``rolls[0] - 45 deg``, then the roll visits each of ``rolls`` (rad, increasing), so every
    stop is approached in the same direction (the roll's play lags the same at each).
    Returns the path (m, 4) and a boolean mask (m,) of the stops to measure.
    """
    b = [float(x) for x in bends]
    r = sorted(float(x) for x in rolls)
    if not b or len(r) < 3:
        raise ConfigurationError(
            f"need at least one bend and three roll stops, got {len(b)} and {len(r)}"
        )
    if any(not math.isfinite(x) or abs(x) > math.pi / 2 for x in b):
        raise ConfigurationError(f"bends must be within +-90 deg, got {np.degrees(b).round(1)}")
    if r[-1] - r[0] >= 2.0 * math.pi:
        raise ConfigurationError("roll stops must span less than 360 deg")
    rows: list[tuple[float, float, float, float]] = []
    mask: list[bool] = []
    for a in b:
        rows.append((a, 0.0, r[0] - _PRE_ROLL, 0.0))
        mask.append(False)
        for ri in r:
            rows.append((a, 0.0, ri, 0.0))
            mask.append(True)
    return np.array(rows), np.array(mask)


def fit_tracker_bias(
    q_motor: ArrayLike,
    tip2base: ArrayLike,
    pose_index: ArrayLike,
    ridge: float = _RIDGE,
    *,
    quadratic: bool = False,
    fit_mask: ArrayLike | None = None,
) -> TrackerBias:
    """Fit Eq. (TB1) to tracked stops of roll circles.

    Parameters
    ----------
    q_motor : array-like, shape (n, 4)
        Commanded joint states of the stops (only the roll phi3 is used).
    tip2base : array-like, shape (n, 4, 4)
        Tracked tip poses (mm, base frame).
    pose_index : array-like of int, shape (n,)
        Which circle (knob pose) each stop belongs to; each needs >= 3 stops.
    ridge : float
        Weight of the minimum-norm regularisation of ``b0`` (mm), ``B`` (per 100 mm) and
        ``Q`` (per (100 mm)^2).
    quadratic : bool
        Also fit the quadratic term of Eq. (TB2) about the stops' mean position.
    fit_mask : array-like of bool, shape (n,), optional
        Stops the field is fitted on (default all); every circle keeps its ``P_k`` fitted on
        all its stops, so a circle left out of the mask is predicted by the others' field
        (:func:`held_out_rms`).
    """
    q = check_finite(q_motor, "q_motor")
    t = check_finite(tip2base, "tip2base", "mm")
    k = np.asarray(pose_index)
    if q.ndim != 2 or q.shape[1] != 4 or t.shape != (q.shape[0], 4, 4) or k.shape != (q.shape[0],):
        raise ShapeError(
            f"need q_motor (n, 4), tip2base (n, 4, 4), pose_index (n,); got {q.shape}, "
            f"{t.shape}, {k.shape}"
        )
    poses, kk = np.unique(k, return_inverse=True)
    counts = np.bincount(kk)
    if np.any(counts < 3):
        raise ConfigurationError(
            f"each roll circle needs >= 3 tracked stops, got {counts.min()} for pose "
            f"{poses[int(np.argmin(counts))]}"
        )
    mask = np.ones(q.shape[0], dtype=bool) if fit_mask is None else np.asarray(fit_mask, bool)
    if mask.shape != (q.shape[0],):
        raise ShapeError(f"fit_mask must have shape ({q.shape[0]},), got {mask.shape}")
    n, npose = q.shape[0], poses.size
    m = t[:, :3, 3]
    rot = _rz(q[:, 2])
    # first estimate of P_k: the measured tips turned back to roll 0, averaged per circle
    back = np.einsum("nji,nj->ni", rot, m)
    pk = np.zeros((npose, 3))
    np.add.at(pk, kk, back)
    pk /= counts[:, None]
    scale = 100.0  # B per 100 mm, Q per (100 mm)^2, so the ridge treats b0, B, Q alike
    centre = m[mask].mean(axis=0)
    nq = 6 if quadratic else 0
    nf = 12 + 3 * nq
    # the field's columns are zero on the stops outside the mask: those stops fit P_k only
    on = mask.astype(np.float64)
    for _ in range(3 if quadratic else 2):
        x = np.einsum("nij,nj->ni", rot, pk[kk])  # R_i P_k, base frame
        u = quadratic_terms((x - centre) / scale)
        # unknowns: P (3 npose), b0 (3), B (9, scaled), Q (3 x 6, scaled); rows: 3 per stop
        a = np.zeros((3 * n, 3 * npose + nf))
        for c in range(3):
            rows = 3 * np.arange(n) + c
            for j in range(3):
                # (R_i P_k)_c = sum_j R_i[c, j] P_k[j] (the field's action linearised)
                a[rows, 3 * kk + j] = rot[:, c, j]
            a[rows, 3 * npose + c] = on
            for j in range(3):
                a[rows, 3 * npose + 3 + 3 * c + j] = on * x[:, j] / scale
            for j in range(nq):  # (TB2)
                a[rows, 3 * npose + 12 + nq * c + j] = on * u[:, j]
        y = m.reshape(-1)
        reg = np.zeros((nf, a.shape[1]))
        reg[:, 3 * npose :] = math.sqrt(float(ridge)) * np.eye(nf)
        sol, *_ = np.linalg.lstsq(
            np.vstack([a, reg]), np.concatenate([y, np.zeros(nf)]), rcond=None
        )
        pk = sol[: 3 * npose].reshape(npose, 3)
    b0 = sol[3 * npose : 3 * npose + 3]
    grad = sol[3 * npose + 3 : 3 * npose + 12].reshape(3, 3) / scale
    quad = sol[3 * npose + 12 :].reshape(3, nq) / scale**2 if quadratic else None
    # B and Q act on x, not on x - c: b0 + B x + Q u(x - c) with the fitted b0 (TB2)
    resid = (a @ sol - y).reshape(n, 3)[mask]
    return TrackerBias(
        offset_mm=b0,
        gradient=grad,
        rms_residual_mm=float(np.sqrt(np.mean(np.sum(resid**2, axis=1)))),
        n_samples=int(mask.sum()),
        quadratic=quad,
        centre_mm=centre if quadratic else None,
    )


def held_out_rms(
    q_motor: ArrayLike,
    tip2base: ArrayLike,
    pose_index: ArrayLike,
    *,
    quadratic: bool,
    ridge: float = _RIDGE,
) -> float:
    """RMS (mm) of the roll-circle stops of each inner circle predicted by the field fitted
    on the other circles (that circle's ``P_k`` fitted on its own stops): how well the
    field's form interpolates between circles, which is what the raster between them
    needs. The inner circles are all but the first and last (in ``pose_index`` order)."""
    q = np.asarray(q_motor, dtype=np.float64)
    t = np.asarray(tip2base, dtype=np.float64)
    k = np.asarray(pose_index)
    circles = np.unique(k)
    if circles.size < 3:
        raise ConfigurationError(f"a held-out check needs >= 3 roll circles, got {circles.size}")
    err: list[Array] = []
    for c in circles[1:-1]:
        out = k == c
        fit = fit_tracker_bias(q, t, k, ridge, quadratic=quadratic, fit_mask=~out)
        pred = _predict(fit, q[out], t[out])
        err.append(np.sum((pred - t[out, :3, 3]) ** 2, axis=1))
    return float(np.sqrt(np.mean(np.concatenate(err))))


def _predict(bias: TrackerBias, q: Array, t: Array) -> Array:
    """Tracked tips (n, 3) of one circle's stops predicted by a field: ``R_i P + b(R_i P)``
    with ``P`` the best knob-frame tip for that field (Gauss-Newton, 3 unknowns)."""
    rot = _rz(q[:, 2])
    m = t[:, :3, 3]
    p = np.mean(np.einsum("nji,nj->ni", rot, bias.correct_positions(m)), axis=0)
    for _ in range(3):
        x = np.einsum("nij,j->ni", rot, p)
        r = (m - x - bias.at(x)).reshape(-1)
        jac = rot.reshape(-1, 3)  # the field's slope (<< 1) left out of the Jacobian
        p = p + np.linalg.lstsq(jac, r, rcond=None)[0]
    x = np.einsum("nij,j->ni", rot, p)
    return np.asarray(x + bias.at(x), dtype=np.float64)


QUADRATIC_MARGIN = 0.9
"""The quadratic field (TB2) is kept only where its held-out RMS is below this fraction of
the affine field's."""


def choose_tracker_bias(
    q_motor: ArrayLike,
    tip2base: ArrayLike,
    pose_index: ArrayLike,
    ridge: float = _RIDGE,
) -> TrackerBias:
    """The affine field (TB1), or the quadratic one (TB2) where the inner roll circles held
    out (:func:`held_out_rms`) say it predicts better by the margin
    :data:`QUADRATIC_MARGIN`."""
    affine = fit_tracker_bias(q_motor, tip2base, pose_index, ridge)
    if np.unique(np.asarray(pose_index)).size < 3:
        return affine
    h1 = held_out_rms(q_motor, tip2base, pose_index, quadratic=False, ridge=ridge)
    h2 = held_out_rms(q_motor, tip2base, pose_index, quadratic=True, ridge=ridge)
    if h2 < QUADRATIC_MARGIN * h1:
        return fit_tracker_bias(q_motor, tip2base, pose_index, ridge, quadratic=True)
    return affine


ROLL_CIRCLES = "roll circles"
"""Segment name of the roll circles in a :class:`icenav.calibration.plans.MotionPlan`."""


def roll_circle_plan(
    bends: Sequence[float] = DEFAULT_ROLL_BENDS,
    rolls: Sequence[float] = DEFAULT_ROLLS,
    n_average: int = 8,
    retries: int = 10,
) -> MotionPlan:
    """The roll circles (:func:`roll_circle_path`) as a plan, every stop read (averaging
    ``n_average`` samples; the fit uses the roll stops, not the pre-roll moves), then back
    to rest at zeros."""
    path, _ = roll_circle_path(bends, rolls)
    return MotionPlan.concat(
        [
            MotionPlan.make(path, ROLL_CIRCLES, n_average=n_average, retries=retries),
            MotionPlan.make(np.zeros((1, 4)), "to zero", n_average=0, retries=0),
        ]
    )


def fit_tracker_bias_from(
    recording: Recording,
    bends: Sequence[float] = DEFAULT_ROLL_BENDS,
    rolls: Sequence[float] = DEFAULT_ROLLS,
    quadratic: bool | None = None,
) -> TrackerBias:
    """The field fitted to the recorded roll circles of :func:`roll_circle_plan` (the same
    ``bends`` and ``rolls``): chosen by held-out circles (:func:`choose_tracker_bias`) when
    ``quadratic`` is None, else the affine (False) or quadratic (True) field
    (:func:`fit_tracker_bias`)."""
    path, stops = roll_circle_path(bends, rolls)
    q, poses = recording.part(ROLL_CIRCLES)
    if q.shape != path.shape or not np.array_equal(q, path):
        raise ConfigurationError("the recording's roll circles are not those of these bends/rolls")
    # the tracked roll stops (the pre-roll moves are in the path, not in the fit)
    tracked = np.all(np.isfinite(poses.reshape(len(q), -1)), axis=1)
    keep = np.flatnonzero(stops & tracked)
    if keep.size < 6:
        raise TrackerError(f"only {keep.size} roll-circle stops were tracked; need >= 6")
    pose_of = np.cumsum(~stops) - 1  # which bend (circle) each state belongs to
    args = (q[keep], np.array(poses[keep]), pose_of[keep])
    if quadratic is None:
        return choose_tracker_bias(*args)
    return fit_tracker_bias(*args, quadratic=quadratic)
