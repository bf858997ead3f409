"""A transmission model scored on the calibration's own spin circle (beyond the paper).

The per-tendon model (:mod:`icenav.compensation.transmission`) is fitted on the dense raster
and on knob circles about the centre turned with the roll at rest; its form is chosen by how
well a fit without one of those circles predicts it (:func:`~icenav.calibration.transmission.
identify_transmission_form`). An image spin moves otherwise: the knobs turn the bending plane
through every direction *while the roll turns against them*, at the pace of a spin. The
calibration records that motion anyway, coarsely, for the twist's play (the spin circle of
:func:`icenav.calibration.twist_circle.spin_circle_path`: knobs at 50 deg along direction
``t`` with the roll at ``-t``, up one turn and a lead and back). No fit uses it for the
knobs, so it is a second held-out path, and the one most like the product's spin.

Scored as a prediction of the tracked tip's *position* (as :func:`~icenav.calibration.
transmission.observed_knobs`: base-frame model knobs, roll 0). The model predicts the model
knobs in the rolled frame, ``g_k = G(z_k)`` with ``z`` the transmission simulated along the
commanded knobs from the state before the circle; the base frame turns them by the roll.
The roll's and the twist's plays are not the transmission's, and they lag the base-frame
direction by an amount that changes sign with the roll's sense of turning, so one angle
per sense ``c_s`` is removed by least squares before the residual is read (complex numbers
``u = k1 + i k2``)::

    p_k   = exp(i x3_k) (g1 + i g2)(z_k)                                        (SP1)
    c_s   = arg sum_{k in s} conj(p_k) o_k                                        (SP2)
    rms^2 = mean_k |o_k - p_k exp(i c_s(k))|^2     (settled samples of both senses)  (SP3)

``o`` the tracked base-frame knobs, ``x3`` the commanded roll, ``s`` its sense of turning;
a sample counts only after ``lead`` (rad of roll) of turning in its sense (the roll's band
crossed). What remains is the bend's size along the turn and the direction's variation
about its mean lag: what the transmission's form decides on a spin. What it assumes: the
roll's and twist's lag is one angle per sense (its variation over the directions, the
twist's law over the knob plane, is left in the residual and is the same for every form
scored, so it adds to every score alike).
"""

from __future__ import annotations

import math

import numpy as np

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.compensation.transmission import TransmissionFit, static_terms
from icenav.errors import ConfigurationError, ShapeError

__all__ = ["MIN_SETTLED", "SPIN_LEAD", "SPIN_SCORE", "scorable", "settled_mask", "spin_path_rms"]

SPIN_LEAD = math.radians(60.0)
"""Roll turned in the present sense before a spin-circle sample counts (rad): the roll's and
the twist's plays together are up to about 30 deg at the circle's bend on the development
catheters (as :data:`icenav.calibration.twist_circle.CIRCLE_LEAD`)."""

SPIN_SCORE = "spin circle: "
"""Prefix of a form's spin-circle score in :attr:`~icenav.compensation.transmission.
TransmissionFit.held_out_rms` (e.g. ``"spin circle: stretch"``)."""

MIN_SETTLED = 4
"""Fewest settled samples per sense for a score (fewer: no score)."""


def settled_mask(q_motor: Array, q_start: Array, lead: float = SPIN_LEAD) -> tuple[Array, Array]:
    """Sense of turning of the roll (n,) (+1 / -1, 0 if still) at each commanded state of
    ``q_motor`` (n, 4) (rad, rad, rad, mm) from ``q_start`` (4,), and which samples (n,) bool
    follow at least ``lead`` (rad) of roll turned in that sense."""
    x3 = np.asarray(q_motor, dtype=np.float64)[:, 2]
    dx = np.diff(np.concatenate([[float(q_start[2])], x3]))
    sense = np.sign(dx)
    run = np.zeros(x3.size)
    for k in range(x3.size):
        same = k > 0 and sense[k] == sense[k - 1]
        run[k] = (run[k - 1] if same else 0.0) + abs(dx[k])
    return sense, (run >= lead - 1e-9) & (sense != 0)


def scorable(q_motor: Array, observed: Array, q_start: Array, lead: float = SPIN_LEAD) -> bool:
    """Whether a path (n, 4) with tracked knobs (n, 2) (NaN: missing) from ``q_start`` (4,)
    has at least :data:`MIN_SETTLED` settled, tracked samples in each sense of the roll's
    turning (:func:`spin_path_rms` scores it), e.g. not where a plan shortened the circle."""
    q = np.asarray(q_motor, dtype=np.float64)
    y = np.asarray(observed, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 4 or y.shape != (q.shape[0], 2):
        return False
    sense, settled = settled_mask(q, np.asarray(q_start, dtype=np.float64).ravel(), lead)
    ok = settled & np.all(np.isfinite(y), axis=1)
    return all(int(np.sum(ok & (sense == s))) >= MIN_SETTLED for s in (1.0, -1.0))


def spin_path_rms(
    fit: TransmissionFit,
    q_motor: Array,
    observed: Array,
    q_start: Array,
    *,
    fit_limit: float = math.radians(70.0),
    lead: float = SPIN_LEAD,
) -> float:
    """RMS miss (rad, per knob pair as :attr:`TransmissionFit.rms`) of ``fit`` on a path that
    turns the knobs and the roll together, (SP1)-(SP3).

    Parameters
    ----------
    fit : the transmission fit (its model, static map G and degree).
    q_motor : (n, 4) commanded motor states in order (rad, rad, rad, mm).
    observed : (n, 2) tracked base-frame model knobs (rad; NaN = missing), as
        :func:`~icenav.calibration.transmission.observed_knobs` of the tracked tips.
    q_start : (4,) the commanded state before the path (the model is relaxed there).
    fit_limit : samples whose commanded knobs exceed it (rad) do not count.
    lead : roll (rad) turned in a sense before a sample counts.

    Raises ConfigurationError where a sense has fewer than :data:`MIN_SETTLED` samples.
    """
    q = check_finite(q_motor, "q_motor", "rad")
    y = np.asarray(observed, dtype=np.float64)
    s0 = check_finite(q_start, "q_start", "rad").ravel()
    if q.ndim != 2 or q.shape[1] != 4 or y.shape != (q.shape[0], 2) or s0.size != 4:
        raise ShapeError(
            f"q_motor must be (n, 4), observed (n, 2), q_start (4,); got {q.shape}, {y.shape}, "
            f"{s0.shape}"
        )
    sense, settled = settled_mask(q, s0, lead)
    ok = settled & np.all(np.isfinite(y), axis=1)
    ok &= np.max(np.abs(q[:, :2]), axis=1) <= float(fit_limit) + 1e-9
    z = fit.model.simulate(q[:, :2], s0[:2])
    basis = np.stack([z[:, 0] ** a * z[:, 1] ** b for a, b in static_terms(fit.degree)], axis=-1)
    g = basis @ fit.static_coefficients
    p = (g[:, 0] + 1j * g[:, 1]) * np.exp(1j * q[:, 2])  # (SP1)
    o = np.where(ok, y[:, 0] + 1j * y[:, 1], 0.0)
    miss = []
    for s in (1.0, -1.0):
        m = ok & (sense == s)
        if int(m.sum()) < MIN_SETTLED:
            raise ConfigurationError(
                f"the spin path has {int(m.sum())} settled samples turning {s:+.0f}; "
                f"need >= {MIN_SETTLED}"
            )
        c = np.angle(np.sum(np.conj(p[m]) * o[m]))  # (SP2)
        miss.append(o[m] - p[m] * np.exp(1j * c))
    r = np.concatenate(miss)
    return float(np.sqrt(np.mean(np.abs(r) ** 2)))  # (SP3)
