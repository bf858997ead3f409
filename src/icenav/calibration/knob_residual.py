"""Identification of the effective knobs' residual along the knob circles
(:class:`icenav.compensation.knob_residual.KnobResidual`, beyond the paper).

After the per-tendon transmission is fitted (:mod:`icenav.calibration.transmission`), each
knob-circle sample's tracked model knobs ``y`` are mapped back through the fit's static map G
(Gauss-Newton on the polynomial) to the effective knobs that explain them, and the model's
miss ``delta_k = G^-1(y_k) - z_k`` is fitted per circle and sense of turning by a Fourier
series of the azimuth (KR1) by linear least squares. Samples within :data:`SETTLE` of azimuth
after a change of the sense (the band crossing after a reversal, and the start of each circle)
stay out: the table is the settled turn's. :func:`circle_residual` returns the table of some
of the circles; :mod:`icenav.calibration.transmission` keeps it only where the table of the
outer circles, interpolated in radius, predicts the held-out middle circle better
(``FORM_MARGIN``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.compensation.knob_residual import KnobResidual, update_sense
from icenav.compensation.transmission import TransmissionFit, static_terms
from icenav.errors import ConfigurationError, ShapeError

__all__ = ["HARMONICS", "SETTLE", "circle_residual", "effective_miss"]

HARMONICS = 2
"""K of (KR1): on development catheters 211 / 213 / 214 of ``out-of-tolerance`` the outer
circles' tables with K = 2 predicted the middle circle best (K = 1 too smooth, K = 3-4
over-fitted the interpolation; docs/calibration.md section 4c)."""
SETTLE = math.radians(30.0)
"""Azimuth (rad) after a change of the sense of turning left out of the table's fit."""


def effective_miss(fit: TransmissionFit, z: ArrayLike, y: ArrayLike, iterations: int = 4) -> Array:
    """delta (n, 2) (rad): the effective knobs u with G(u) = y (the fit's static map, by
    Gauss-Newton from the model's ``z`` (n, 2)) minus ``z``; NaN where ``y`` (n, 2) is NaN."""
    zz = check_finite(z, "z", "rad")
    yy = np.asarray(y, dtype=np.float64)
    if zz.ndim != 2 or zz.shape[1] != 2 or yy.shape != zz.shape:
        raise ShapeError(f"z and y must have the same shape (n, 2), got {zz.shape}, {yy.shape}")
    coef = np.asarray(fit.static_coefficients, dtype=np.float64)
    terms = static_terms(fit.degree)
    u = zz.copy()
    for _ in range(int(iterations)):
        val = np.zeros_like(u)
        jac = np.zeros((u.shape[0], 2, 2))
        for t, (a, b) in enumerate(terms):
            val += np.outer(u[:, 0] ** a * u[:, 1] ** b, coef[t])
            if a:
                jac[:, :, 0] += np.outer(a * u[:, 0] ** (a - 1) * u[:, 1] ** b, coef[t])
            if b:
                jac[:, :, 1] += np.outer(b * u[:, 0] ** a * u[:, 1] ** (b - 1), coef[t])
        r = val - yy
        ok = np.all(np.isfinite(r), axis=1) & (np.abs(np.linalg.det(jac)) > 1e-9)
        u[ok] -= np.linalg.solve(jac[ok], r[ok][:, :, None])[:, :, 0]
    out = u - zz
    out[~np.all(np.isfinite(yy), axis=1)] = np.nan
    return out


def circle_residual(
    fit: TransmissionFit,
    q_motor: ArrayLike,
    observed: ArrayLike,
    blocks: ArrayLike,
    use: Sequence[int],
    *,
    q_start: ArrayLike = (0.0, 0.0),
    keep: ArrayLike | None = None,
    harmonics: int = HARMONICS,
) -> KnobResidual:
    """The residual table (KR1) of the circles ``use`` (labels of ``blocks`` (n,), as
    :func:`~icenav.calibration.transmission.circle_blocks`) of a knob-circle motion:
    ``q_motor`` (n, 2+) commanded from a relaxed start at ``q_start`` (2,), ``observed``
    (n, 2) its tracked model knobs (rad, NaN missing), ``keep`` (n,) the samples allowed in
    the fit (default all). The fit's model (its band alone) gives the effective knobs; per
    circle the settled samples on the circle (commanded radius within 1 % of the circle's)
    of each sense enter a Fourier fit of ``harmonics`` over the azimuth of the model's
    effective knobs; the circle's radius is their mean |z|."""
    q = check_finite(q_motor, "q_motor", "rad")
    lab = np.asarray(blocks).ravel()
    if q.ndim != 2 or q.shape[1] < 2 or lab.shape != (q.shape[0],):
        raise ShapeError(f"q_motor (n, 2+) and blocks (n,) must match, got {q.shape}, {lab.shape}")
    ok = np.ones(q.shape[0], dtype=bool) if keep is None else np.asarray(keep, dtype=bool).ravel()
    band = replace(fit.model, residual=None)
    start = check_finite(q_start, "q_start", "rad").ravel()[:2]
    z = band.simulate(q[:, :2], start)
    miss = effective_miss(fit, z, observed)
    # the sense of each sample as the model state carries it, and the azimuth since it changed
    z0 = band.effective(band.relaxed_state(start).tolist())
    senses, settled = np.zeros(q.shape[0]), np.zeros(q.shape[0], dtype=bool)
    s, prev, travel = 0.0, (float(z0[0]), float(z0[1])), 0.0
    for i, row in enumerate(z.tolist()):
        new = update_sense(s, prev, (row[0], row[1]))
        turn = math.atan2(prev[0] * row[1] - prev[1] * row[0], prev[0] * row[0] + prev[1] * row[1])
        travel = 0.0 if new != s else travel + abs(turn)
        s, prev = new, (row[0], row[1])
        senses[i], settled[i] = s, travel >= SETTLE
    psi = np.arctan2(z[:, 1], z[:, 0])
    k = int(harmonics)
    cols = [np.ones_like(psi)]
    for h in range(1, k + 1):
        cols += [np.cos(h * psi), np.sin(h * psi)]
    basis = np.stack(cols, axis=-1)
    qr = np.hypot(q[:, 0], q[:, 1])
    radii, coefs = [], []
    for c in sorted({int(v) for v in use}):
        on = (lab == c) & ok & settled & np.all(np.isfinite(miss), axis=1)
        if not np.any(lab == c):
            raise ConfigurationError(f"no sample of circle {c} in blocks")
        on &= qr >= 0.99 * float(np.max(qr[lab == c]))
        per_sense = []
        for sv in (1.0, -1.0):
            sel = on & (senses == sv)
            if int(sel.sum()) < 3 * (2 * k + 1):
                raise ConfigurationError(
                    f"circle {c}: {int(sel.sum())} settled samples turning {sv:+.0f}; need "
                    f"at least {3 * (2 * k + 1)} for {k} harmonics"
                )
            per_sense.append(np.linalg.lstsq(basis[sel], miss[sel], rcond=None)[0])
        radii.append(float(np.mean(np.hypot(z[on, 0], z[on, 1]))))
        coefs.append(np.stack(per_sense))
    order = np.argsort(radii)
    table = np.stack([coefs[i] for i in order])  # (m, 2, 2K + 1, 2)
    return KnobResidual(
        radii=tuple(radii[i] for i in order),
        harmonics=k,
        coefficients=tuple(np.clip(table, -1.0, 1.0).ravel().tolist()),
    )
