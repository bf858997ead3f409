"""How a play widens with the bend of the section: a law chosen by held-out residual.

The roll's play (the section turns behind the motor) and the distal twist play (the image
frame turns behind the section) widen as the section bends: a bent section presses on its
sheath and on its own wires. How they widen is a property of the catheter, not of our
model, so it is *measured*: the roll is swept at several bends ``b_i`` (rad, the tracked
bend) and the play's extra half-width over the straight one, ``e_i`` (rad), is read from
each sweep. Four forms are fitted to those points, every one through ``e(0) = 0``, never
negative and never decreasing with the bend (a bent section never rubs less than a
straighter one), so that below the smallest bend swept (the spins' 20-40 deg lie below
it) a law goes down to zero instead of extrapolating a fitted curve's dip::

    linear       e(b) = k b,                k >= 0                    (B1)
    quadratic    e(b) = k1 b + k2 b^2,      k1, k2 >= 0               (B2)
    power        e(b) = a b^p,              a >= 0, 1/2 <= p <= 4     (B4)
    table        e(b) = piecewise linear through (0, 0) and the points
                 made monotone (pool-adjacent-violators), continued past
                 the last point with the last (non-negative) slope    (B3)

and the form kept is the one with the smallest leave-one-out residual (each measured
point predicted by the form fitted to the others; :func:`select_bend_play`), the simpler
form on a tie. Every form is clipped to ``0 <= e <= MAX_EXTRA``. What each assumes:
(B1) the play grows in proportion to the bend (a friction that grows with the normal force
of a uniformly curved section, the default twin's law); (B2) a growth between linear and
quadratic (e.g. a play growing with bend and with the tendon tension that holds it, both
proportional to the bend); (B4) a growth of one power of the bend, from saturating
(p < 1) to steeper than the square (p > 2: a friction that grows with bend, tension and
wrap together), which (B2) with non-negative coefficients cannot follow; (B3) only that
the play is continuous and monotone in the bend and that it keeps its last measured slope
beyond the largest bend measured. The coefficients of (B1), (B2) and (B4) are fitted with
their bounds (non-negative least squares; a grid over p) rather than clipped afterwards:
an unconstrained quadratic through three points at 45-120 deg of bend can take a negative
linear term and give no play at all below about 40 deg.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import isotonic_regression, nnls

from icenav._typing import Array
from icenav.errors import ConfigurationError

__all__ = [
    "BEND_PLAY_FORMS",
    "BendPlay",
    "KnobPlanePlay",
    "MAX_EXTRA",
    "P_RANGE",
    "PlayLaw",
    "select_bend_play",
]

BEND_PLAY_FORMS = ("linear", "quadratic", "power", "table")
"""The forms, simplest first (the order that breaks a tie of residuals)."""
MAX_EXTRA = math.radians(60.0)
"""Largest extra play half-width any form returns (rad)."""
P_RANGE = (0.5, 4.0)
"""Exponents of the power form (B4) searched."""
_P_GRID = np.linspace(P_RANGE[0], P_RANGE[1], 141)


@dataclass(frozen=True)
class BendPlay:
    """The extra play half-width as a function of the bend, :math:`e(b)` (rad of rad).

    ``form`` is one of :data:`BEND_PLAY_FORMS`; ``coef`` holds ``(k,)`` for (B1), ``(k1,
    k2)`` for (B2), ``(a, p)`` for (B4); ``bends`` / ``extra`` are the measured points (rad),
    made monotone the knots of (B3). (Files written before the bounds may hold a (B2) with
    a negative coefficient: it still loads and is clipped at zero as it was.)
    """

    form: str
    """``linear``, ``quadratic``, ``power`` or ``table``."""
    coef: tuple[float, ...] = ()
    """Coefficients of (B1) (rad/rad), (B2) (rad/rad, rad/rad^2) or (B4) (``a`` in rad/rad^p,
    the exponent ``p``)."""
    bends: tuple[float, ...] = ()
    """Measured bends (rad), ascending, > 0."""
    extra: tuple[float, ...] = ()
    """Measured extra play at each (rad)."""
    loo_rms: float = math.nan
    """Leave-one-out RMS residual of this form on the measured points (rad); NaN when
    there were too few points to leave one out."""

    def __post_init__(self) -> None:
        if self.form not in BEND_PLAY_FORMS:
            raise ConfigurationError(
                f"bend-play form must be one of {BEND_PLAY_FORMS}, got {self.form!r}"
            )
        need = {"linear": 1, "quadratic": 2, "power": 2, "table": 0}[self.form]
        if len(self.coef) != need:
            raise ConfigurationError(
                f"a {self.form} bend play needs {need} coefficient(s), got {self.coef!r}"
            )
        b = np.asarray(self.bends, dtype=np.float64)
        e = np.asarray(self.extra, dtype=np.float64)
        if b.shape != e.shape or b.ndim != 1 or not np.all(np.isfinite(b)):
            raise ConfigurationError(
                f"bends and extra must be two equal-length lists of finite rad, got "
                f"{self.bends!r} and {self.extra!r}"
            )
        if b.size and (np.any(b <= 0.0) or np.any(np.diff(b) <= 0.0)):
            raise ConfigurationError(f"bends must be ascending and > 0 rad, got {self.bends!r}")
        if self.form == "power" and not (P_RANGE[0] <= self.coef[1] <= P_RANGE[1]):
            raise ConfigurationError(
                f"a power bend play's exponent must be in [{P_RANGE[0]}, {P_RANGE[1]}], got "
                f"{self.coef[1]!r}"
            )
        if self.form == "table" and b.size == 0:
            raise ConfigurationError("a table bend play needs at least one measured point")

    @classmethod
    def linear(cls, k: float) -> BendPlay:
        """(B1) with slope ``k`` (rad of play per rad of bend)."""
        return cls("linear", (float(k),))

    def __call__(self, bend: ArrayLike, direction: ArrayLike | None = None) -> Array:
        """Extra half-width (rad) at ``bend`` (rad, any shape; |bend| is used). ``direction``
        (the bend's direction in the knob plane) is ignored: a law of the bend alone is the
        same in every direction (:class:`KnobPlanePlay` is not)."""
        b = np.abs(np.asarray(bend, dtype=np.float64))
        if self.form == "linear":
            e = self.coef[0] * b  # (B1)
        elif self.form == "quadratic":
            e = self.coef[0] * b + self.coef[1] * b * b  # (B2)
        elif self.form == "power":
            e = self.coef[0] * np.power(b, self.coef[1])  # (B4)
        else:
            e = _table(np.asarray(self.bends), np.asarray(self.extra), b)  # (B3)
        return np.clip(e, 0.0, MAX_EXTRA)

    def at(self, bend: float, direction: float | None = None) -> float:
        """:meth:`__call__` of one bend (rad) as a float."""
        return float(self(bend))

    def scaled(self, factor: float) -> BendPlay:
        """The same form times ``factor`` (>= 0): coefficients ``k``, ``k1, k2``, ``a`` and
        the measured points' plays scaled, the exponent and the bends kept (still
        non-negative and non-decreasing in the bend)."""
        s = float(factor)
        if not math.isfinite(s) or s < 0.0:
            raise ConfigurationError(f"a bend play's scale must be finite and >= 0, got {factor!r}")
        coef = (
            (self.coef[0] * s, self.coef[1])
            if self.form == "power"
            else tuple(c * s for c in self.coef)
        )
        return BendPlay(
            self.form, coef, self.bends, tuple(e * s for e in self.extra), self.loo_rms * s
        )

    @property
    def slope(self) -> float:
        """Mean growth over the measured range (rad/rad): ``e(b_max) / b_max`` (the (B1)
        slope for a linear form without points)."""
        if not self.bends:
            return self.coef[0] if self.form == "linear" else math.nan
        b = self.bends[-1]
        return self.at(b) / b

    def describe(self) -> str:
        """One line: the form, and at each measured bend the measured extra play -> the
        law's (deg)."""
        pts = ", ".join(
            f"{math.degrees(e):.2f}->{math.degrees(self.at(b)):.2f} at {math.degrees(b):.0f}"
            for b, e in zip(self.bends, self.extra, strict=True)
        )
        loo = "" if math.isnan(self.loo_rms) else f", LOO {math.degrees(self.loo_rms):.2f} deg"
        return f"{self.form} ({pts} deg{loo})" if pts else f"{self.form} k={self.slope:.3f}"


def _monotone(e: Array) -> Array:
    """The non-decreasing, non-negative sequence nearest ``e`` in least squares (isotonic
    regression, pool-adjacent-violators, with the knot (0, 0) in front)."""
    fit = isotonic_regression(np.concatenate([[0.0], e]), increasing=True)
    return np.maximum(np.asarray(fit.x, dtype=np.float64)[1:], 0.0)


def _table(b: Array, e: Array, x: Array) -> Array:
    """(B3): piecewise linear through (0, 0) and (b, e) made monotone, the last slope
    beyond."""
    kb = np.concatenate([[0.0], b])
    ke = np.concatenate([[0.0], _monotone(e)])
    inside = np.interp(x, kb, ke)
    last = (ke[-1] - ke[-2]) / (kb[-1] - kb[-2])
    return np.where(x > kb[-1], ke[-1] + last * (x - kb[-1]), inside)


def _fit(form: str, b: Array, e: Array) -> BendPlay:
    """One form fitted to points (b, e) by least squares (B1, B2) or as knots (B3)."""
    if form == "linear":
        k = max(float(b @ e / (b @ b)), 0.0) if b.size else 0.0  # (B1), k >= 0
        return BendPlay("linear", (k,), tuple(b), tuple(e))
    if form == "quadratic":
        if b.size < 2:
            raise ConfigurationError("a quadratic bend play needs two points or more")
        coef, _ = nnls(np.stack([b, b * b], axis=-1), e)  # (B2), k1, k2 >= 0
        return BendPlay("quadratic", (float(coef[0]), float(coef[1])), tuple(b), tuple(e))
    if form == "power":
        if b.size < 2:
            raise ConfigurationError("a power bend play needs two points or more")
        basis = np.power(b[None, :], _P_GRID[:, None])  # (np, n): b^p for each p
        a = np.maximum((basis @ e) / np.einsum("pn,pn->p", basis, basis), 0.0)  # (B4)
        rss = np.sum((a[:, None] * basis - e[None, :]) ** 2, axis=1)
        k = int(np.argmin(rss))
        return BendPlay("power", (float(a[k]), float(_P_GRID[k])), tuple(b), tuple(e))
    return BendPlay("table", (), tuple(b), tuple(e))


def select_bend_play(bends: ArrayLike, extra: ArrayLike) -> BendPlay:
    """The form of (B1)-(B4) with the smallest leave-one-out residual on the points.

    ``bends`` (rad, > 0, any order) and ``extra`` (rad) are the measured points. Each point
    is predicted by each form fitted to the other points (a form that cannot be fitted to
    them is not a candidate); the form with the smallest RMS of those predictions is fitted
    to every point and returned, with its residual in ``loo_rms``. With one point only
    (nothing to hold out) the linear form is returned.
    """
    b = np.asarray(bends, dtype=np.float64).ravel()
    e = np.asarray(extra, dtype=np.float64).ravel()
    if b.size != e.size or b.size == 0:
        raise ConfigurationError(
            f"need as many extra plays as bends (>= 1), got {b.size} bends, {e.size} plays"
        )
    if not (np.all(np.isfinite(b)) and np.all(np.isfinite(e))) or np.any(b <= 0.0):
        raise ConfigurationError(f"bends must be finite and > 0 rad, got {list(b)}")
    order = np.argsort(b)
    b, e = b[order], e[order]
    if np.any(np.diff(b) <= 0.0):
        raise ConfigurationError(f"bends must be distinct, got {list(b)}")
    if b.size == 1:
        return _fit("linear", b, e)
    best: BendPlay | None = None
    for form in BEND_PLAY_FORMS:
        minimum = {"linear": 1, "quadratic": 2, "power": 2, "table": 1}[form]
        if b.size - 1 < minimum:
            continue
        errors = []
        for i in range(b.size):
            keep = np.arange(b.size) != i
            errors.append(_fit(form, b[keep], e[keep]).at(float(b[i])) - e[i])
        rms = float(np.sqrt(np.mean(np.square(errors))))
        if best is None or rms < best.loo_rms - 1e-12:
            fitted = _fit(form, b, e)
            best = BendPlay(fitted.form, fitted.coef, fitted.bends, fitted.extra, rms)
    assert best is not None  # the linear form always qualifies with two points or more
    return best


@dataclass(frozen=True)
class KnobPlanePlay:
    """The extra play half-width over the knob plane, :math:`e(b, \\psi)` (rad).

    A bend ``b`` of the section has a direction ``psi`` in the knob plane (``atan2(phi2,
    phi1)``: 0 the AP knob, pi/2 the RL knob). Where a play grows with the *total* tendon
    tension, one bend pulls harder in some directions than in others, so the play is
    measured in several directions ``psi_i`` (rad, ascending in ``[0, P)``), each a law of
    the bend (:class:`BendPlay`), and interpolated between them linearly and periodically::

        e(b, psi) = (1 - w) e_i(b) + w e_{i+1}(b),   psi mod P in [psi_i, psi_{i+1}],
                    w = (psi - psi_i) / (psi_{i+1} - psi_i),  psi_{n} = psi_0 + P    (B5)

    with the period ``P`` pi (default) or 2 pi.

    A convex combination of non-negative laws non-decreasing in the bend is one too, for
    every direction. What it assumes beyond each law's: with ``P = pi``, the play depends on
    the axis of the bending plane, not on its sense (the two tendons of a pair are mirror
    images); with ``P = 2 pi`` on both; and it varies linearly in direction between the
    directions measured. One
    direction is a law of the bend alone (:meth:`uniform`).
    """

    directions: tuple[float, ...]
    """Directions measured (rad), ascending in [0, period)."""
    laws: tuple[BendPlay, ...]
    """The law of the bend in each direction."""
    period: float = math.pi
    """Period of the play in the direction (rad): pi (the axis of the bending plane, the
    default) or 2 pi (the axis *and* its sense: a play read over the whole knob plane, e.g.
    from the spin circle of :mod:`icenav.calibration.twist_circle`)."""

    def __post_init__(self) -> None:
        d = np.asarray(self.directions, dtype=np.float64)
        if d.ndim != 1 or d.size == 0 or d.size != len(self.laws):
            raise ConfigurationError(
                f"need one law per direction (>= 1), got {len(self.directions)} directions and "
                f"{len(self.laws)} laws"
            )
        if self.period not in (math.pi, 2.0 * math.pi):
            raise ConfigurationError(
                f"period must be pi or 2 pi rad (180 or 360 deg), got {self.period!r} rad"
            )
        if not np.all(np.isfinite(d)) or np.any(d < 0.0) or np.any(d >= self.period):
            raise ConfigurationError(
                f"directions must be in [0, {self.period:.4f}) rad "
                f"([0, {math.degrees(self.period):.0f}) deg), got {self.directions!r}"
            )
        if np.any(np.diff(d) <= 0.0):
            raise ConfigurationError(f"directions must be ascending, got {self.directions!r}")
        for law in self.laws:
            if not isinstance(law, BendPlay):
                raise ConfigurationError(f"laws must be BendPlay, got {type(law).__name__}")

    @classmethod
    def uniform(cls, law: BendPlay) -> KnobPlanePlay:
        """``law`` in every direction (a law of the bend alone)."""
        return cls((0.0,), (law,))

    def __call__(self, bend: ArrayLike, direction: ArrayLike | None = None) -> Array:
        """Extra half-width (rad) at ``bend`` (rad) in ``direction`` (rad; broadcast with
        ``bend``; None: the first direction measured), (B5)."""
        b = np.asarray(bend, dtype=np.float64)
        if len(self.laws) == 1:
            return self.laws[0](b)
        psi = self.directions[0] if direction is None else direction
        period = self.period
        t = np.mod(np.asarray(psi, dtype=np.float64), period)
        b, t = np.broadcast_arrays(b, t)
        knots = np.append(np.asarray(self.directions), self.directions[0] + period)
        t = np.where(t < knots[0], t + period, t)  # into [psi_0, psi_0 + period)
        i = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, len(self.laws) - 1)
        w = (t - knots[i]) / (knots[i + 1] - knots[i])
        values = np.stack([law(b) for law in (*self.laws, self.laws[0])])  # (n + 1, ...)
        lo = np.take_along_axis(values, i[None], axis=0)[0]
        hi = np.take_along_axis(values, (i + 1)[None], axis=0)[0]
        return (1.0 - w) * lo + w * hi  # (B5)

    def at(self, bend: float, direction: float | None = None) -> float:
        """:meth:`__call__` of one bend and direction (rad) as a float."""
        return float(self(bend, direction))

    def describe(self) -> str:
        """One line per direction: the direction (deg) and its law."""
        return "; ".join(
            f"{math.degrees(d):.0f} deg: {law.describe()}"
            for d, law in zip(self.directions, self.laws, strict=True)
        ) + ("" if self.period == math.pi else " (period 360 deg)")


PlayLaw = BendPlay | KnobPlanePlay
"""A play's law: of the bend alone (:class:`BendPlay`) or over the knob plane."""
