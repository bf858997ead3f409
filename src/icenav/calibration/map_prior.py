"""A prior of a catheter model's elasticity map F, for the short calibration (beyond the
paper; an explicit option, never a default).

The short calibration (:mod:`icenav.calibration.short`) builds F on the five points and a
few ring stops: between them a thin-plate interpolant guesses the tip, and on development
catheters most of its excess over the full calibration is there (docs/calibration.md
section 7). A lab that owns several catheters of one product line can run the full
calibration once on a few of them and store how the line's tip lies over the motor knob
plane. For each catheter ``j`` its full calibration's model (a *drive*: a motor knob path
from rest -> the tips along it, mm in the knob frame, tracker bias and section excess
removed) is read three ways, each averaged over the catheters on a grid of motor knob
pairs ``x`` (:func:`turned_positions`)::

    Pbar_s(x) = mean_j P_j,s(x)    s = +1 / -1: reached turning counter-clockwise /
                                   clockwise about the knob origin (a spin), 0: straight out
    sbar_i    = mean_j P_j(stop i as the short plan reaches it, from rest)           (M0)

(the knobs' lag on a spin's fine circle is not the lag at a stop reached by a 36 deg
chord, nor at a point reached straight out: each is read as it is met). A short
calibration of another catheter of the line, with samples ``(x_i, p_i)`` (the five points
and the ring stops of one sense ``s``, as :func:`~icenav.calibration.short.fit_short_rings`
builds F on), interpolates only its difference from the line's readings of the same
samples, ``e_i`` = ``sbar_i`` at a stored stop of that sense, ``Pbar_0(x_i)`` elsewhere (the
five points), with the thin-plate interpolant ``I[.]`` F uses on sparse samples::

    P_s(x) = Pbar_s(x) + I[p_i - e_i](x)                                            (M1)

Because ``I`` is linear in the values, (M1) is the short calibration's own interpolant plus
the product line's mean correction of it, ``P_s = I[p_i] + mean_j (P_j,s - I[e_j,i])``:
what the short interpolant of each prior catheter missed between (and at) the same stops
against a spin, averaged. With ``scaled`` the line's deviation from the model tip ``m(x)``
is first scaled by what the short samples show (least squares over the samples, clipped to
[0, 2])::

    a = sum_i <p_i - m(x_i), e_i - m(x_i)> / sum_i |e_i - m(x_i)|^2
    P_s(x) = m(x) + a (Pbar_s(x) - m(x)) + I[p_i - m(x_i) - a (e_i - m(x_i))](x)    (M2)

F is then built from ``P_s`` sampled on a grid of motor knobs (:meth:`MapPrior.build_map`:
the paper's matching of :class:`~icenav.compensation.elasticity.ElasticityMap`, on a
spline through the grid). What it assumes: the catheters of the line differ from their
mean smoothly enough that the short samples' difference interpolates (the difference, not
the map, is what ``I`` guesses between the stops), the short plan is the one the prior was
made for (a ring stop not stored is read as if reached straight out), and the line's model
predicts its catheters' lag (the full calibration's per-tendon transmission). What it does
not assume: any form of F (the prior is the full calibrations' tables), the new
catheter's level or offset (its samples' difference carries them). A catheter of another
line gets the line's bends and lags between its stops.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.interpolate import RBFInterpolator, RectBivariateSpline

from icenav._typing import Array
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.errors import ConfigurationError, FileFormatError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward

__all__ = [
    "MAP_GRID_STEP",
    "MapPrior",
    "TURN_RADIUS_STEP",
    "TURN_STEP",
    "make_map_prior",
    "map_prior_from_dict",
    "stop_senses",
    "turned_positions",
]

TURN_STEP = math.radians(5.0)
"""Angle step (rad) of the turned rings :func:`turned_positions` reads a catheter on."""
TURN_RADIUS_STEP = math.radians(2.5)
"""Radius step (rad) of those rings."""
MAP_GRID_STEP = math.radians(5.0)
"""Step (rad) of the grid of motor knobs the prior is tabulated on, and of the grid F is
built from (:meth:`MapPrior.build_map`): half the raster's 10 deg."""


def _model_positions(a: Array, b: Array, geometry: CatheterGeometry) -> Array:
    """Model tip positions (..., 3) (mm, knob frame) at knobs ``a``, ``b`` (rad)."""
    q = np.zeros((*np.broadcast_shapes(np.shape(a), np.shape(b)), 4))
    q[..., 0] = a
    q[..., 1] = b
    return np.asarray(forward(q, geometry, check=False)[..., :3, 3])


def _axis(limit: float, step: float = MAP_GRID_STEP) -> Array:
    n = int(round(2.0 * limit / step))
    return np.linspace(-limit, limit, n + 1)


@dataclass(frozen=True, eq=False)
class MapPrior:
    """(M0) of one product line: the mean tip position over a grid of motor knob pairs."""

    product: str
    """The catheter model (product line) it describes."""
    catheters: tuple[str, ...]
    """The catheters whose full calibrations made it."""
    knobs: tuple[float, ...]
    """The grid's knob angles (rad, ascending), the same for phi1 and phi2."""
    positions: Array
    """(n, n, 3) the mean tip position (mm, knob frame) at (knobs[i], knobs[j]), the knobs
    turned counter-clockwise about the knob origin to get there (M0)."""
    reverse: Array
    """(n, n, 3) the same, the knobs turned clockwise."""
    radial: Array
    """(n, n, 3) the same, the knobs moved straight out from rest (as the five points)."""
    stops: Array
    """(m, 2) the short calibration's ring stops (motor knobs, rad, in the plan's order)."""
    stop_sense: Array
    """(m,) the sense each stop is reached in (+1 counter-clockwise, -1 clockwise, 0 a move
    onto a ring)."""
    stop_tips: Array
    """(m, 3) the line's mean tip (mm, knob frame) at each stop as the plan reaches it."""
    spread_mm: float = math.nan
    """The catheters' RMS distance from the mean (mm, over the grid and both senses)."""

    def __post_init__(self) -> None:
        k = np.asarray(self.knobs, dtype=np.float64)
        if k.ndim != 1 or k.size < 4 or np.any(np.diff(k) <= 0.0):
            raise ConfigurationError(f"map prior knobs must be >= 4 ascending angles, got {k!r}")
        object.__setattr__(self, "knobs", tuple(float(x) for x in k))
        splines = []
        for name in ("positions", "reverse", "radial"):
            p = np.array(getattr(self, name), dtype=np.float64)
            if p.shape != (k.size, k.size, 3) or not np.all(np.isfinite(p)):
                raise ConfigurationError(
                    f"map prior {name} must be {k.size} x {k.size} x 3 finite mm, got {p.shape}"
                )
            p.setflags(write=False)
            object.__setattr__(self, name, p)
            splines.append(tuple(RectBivariateSpline(k, k, p[..., c], s=0.0) for c in range(3)))
        object.__setattr__(self, "_splines", tuple(splines))
        st = np.array(self.stops, dtype=np.float64)
        sense = np.array(self.stop_sense, dtype=np.float64)
        tips = np.array(self.stop_tips, dtype=np.float64)
        m = st.shape[0] if st.ndim == 2 else -1
        if st.shape != (m, 2) or sense.shape != (m,) or tips.shape != (m, 3):
            raise ConfigurationError(
                f"map prior stops must be (m, 2), (m,) and (m, 3), got {st.shape}, "
                f"{sense.shape}, {tips.shape}"
            )
        if not (np.all(np.isfinite(st)) and np.all(np.isfinite(tips))):
            raise ConfigurationError("map prior stops and their tips must be finite")
        for name, a in (("stops", st), ("stop_sense", sense), ("stop_tips", tips)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def mean_position(self, a: Any, b: Any, sense: int = 1) -> Array:
        """(M0) ``Pbar`` (..., 3) (mm, knob frame) at motor knobs ``a``, ``b`` (rad, same
        shape) reached turning counter-clockwise (``sense`` +1), clockwise (-1) or straight
        out from rest (0); bicubic through the grid, clamped at its edge."""
        if sense not in (-1, 0, 1):
            raise ConfigurationError(f"sense must be +1, 0 or -1, got {sense!r}")
        lo, hi = self.knobs[0], self.knobs[-1]
        aa = np.clip(np.asarray(a, dtype=np.float64), lo, hi)
        bb = np.clip(np.asarray(b, dtype=np.float64), lo, hi)
        sp = self._splines[{1: 0, -1: 1, 0: 2}[sense]]  # type: ignore[attr-defined]
        return np.stack([s.ev(aa, bb) for s in sp], axis=-1)

    def expected(self, knobs: Any, sense: int) -> Array:
        """(M1)'s ``s_i`` (m, 3) (mm, knob frame): the line's mean reading of samples at
        motor ``knobs`` (m, 2) (rad) of an F of ``sense``: at a stored ring stop of that
        sense (within 1e-6 rad) the line's mean tip there as the plan reached it, elsewhere
        (the five points) the mean tip reached straight out from rest."""
        k = np.asarray(knobs, dtype=np.float64).reshape(-1, 2)
        out = self.mean_position(k[:, 0], k[:, 1], 0)
        mine = np.flatnonzero(self.stop_sense == sense)
        if mine.size:
            d = np.max(np.abs(k[:, None, :] - self.stops[mine][None, :, :]), axis=-1)
            j = np.argmin(d, axis=1)
            hit = d[np.arange(k.shape[0]), j] < 1e-6
            out[hit] = self.stop_tips[mine[j[hit]]]
        return out

    def position(
        self,
        samples: CalibrationSet,
        *,
        sense: int = 1,
        scaled: bool = False,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    ) -> Callable[[Array, Array], Array]:
        """(M1) (or (M2) with ``scaled``): the catheter's tip position (..., 3) (mm, knob
        frame) as a function of motor knobs (rad), from its short ``samples`` (>= 3) reached
        turning in ``sense`` (+1 counter-clockwise, -1 clockwise)."""
        knobs = samples.q_motor[:, :2]
        p = samples.positions_in_knob_frame()
        base = self.expected(knobs, sense)
        gain = 1.0
        if scaled:
            m = _model_positions(knobs[:, 0], knobs[:, 1], geometry)
            d = base - m
            den = float(np.sum(d * d))
            gain = float(np.clip(np.sum((p - m) * d) / den, 0.0, 2.0)) if den > 0.0 else 0.0
            base = m + gain * d  # (M2)
        uniq, inv = np.unique(np.round(knobs, 9), axis=0, return_inverse=True)
        inv = inv.ravel()
        resid = np.zeros((uniq.shape[0], 3))
        np.add.at(resid, inv, p - base)
        resid /= np.bincount(inv, minlength=uniq.shape[0])[:, None]
        rbf = RBFInterpolator(uniq, resid, kernel="thin_plate_spline", degree=1)

        def real_position(a: Array, b: Array) -> Array:
            shape = np.broadcast_shapes(np.shape(a), np.shape(b))
            aa = np.broadcast_to(np.asarray(a, np.float64), shape)
            bb = np.broadcast_to(np.asarray(b, np.float64), shape)
            line = self.mean_position(aa, bb, sense)
            if scaled:
                mm = _model_positions(aa, bb, geometry)
                line = mm + gain * (line - mm)
            pts = np.stack([aa.ravel(), bb.ravel()], axis=-1)
            return line + np.asarray(rbf(pts)).reshape(*shape, 3)  # (M1)

        return real_position

    def build_map(
        self,
        samples: CalibrationSet,
        *,
        sense: int = 1,
        scaled: bool = False,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    ) -> ElasticityMap:
        """F from :meth:`position` sampled on the :data:`MAP_GRID_STEP` grid of motor knobs
        (a spline through it, no smoothing); the map's ``calibration`` is that grid, its
        method ``"<samples' method>+map-prior"``."""
        ax = _axis(geometry.knob_limit)
        ga, gb = np.meshgrid(ax, ax, indexing="ij")
        at = self.position(samples, sense=sense, scaled=scaled, geometry=geometry)
        pos = at(ga.ravel(), gb.ravel())
        n = pos.shape[0]
        q = np.zeros((n, 4))
        q[:, 0], q[:, 1] = ga.ravel(), gb.ravel()
        t = np.tile(np.eye(4), (n, 1, 1))
        t[:, :3, 3] = pos
        grid = CalibrationSet(
            q_motor=q,
            tip2base=t,
            catheter_id=samples.catheter_id,
            vessel=samples.vessel,
            method=f"{samples.method}+map-prior",
        )
        return ElasticityMap.build(grid, geometry, interpolant="spline", smoothing=0.0)

    def to_dict(self) -> dict[str, Any]:
        """The JSON document (angles in deg, positions in mm, rounded to 1 um)."""
        return {
            "product": self.product,
            "catheters": list(self.catheters),
            "knobs_deg": [round(math.degrees(x), 9) for x in self.knobs],
            "positions_mm": np.round(self.positions, 3).tolist(),
            "reverse_mm": np.round(self.reverse, 3).tolist(),
            "radial_mm": np.round(self.radial, 3).tolist(),
            "stops_deg": np.round(np.degrees(self.stops), 9).tolist(),
            "stop_sense": [int(v) for v in self.stop_sense],
            "stop_tips_mm": np.round(self.stop_tips, 3).tolist(),
            "spread_mm": self.spread_mm,
        }


def map_prior_from_dict(doc: Any, where: str) -> MapPrior:
    """The :class:`MapPrior` of :meth:`MapPrior.to_dict`'s document; FileFormatError naming
    ``where`` (a file) on anything else."""
    try:
        return MapPrior(
            product=str(doc["product"]),
            catheters=tuple(str(c) for c in doc["catheters"]),
            knobs=tuple(math.radians(float(x)) for x in doc["knobs_deg"]),
            positions=np.asarray(doc["positions_mm"], dtype=np.float64),
            reverse=np.asarray(doc["reverse_mm"], dtype=np.float64),
            radial=np.asarray(doc["radial_mm"], dtype=np.float64),
            stops=np.radians(np.asarray(doc["stops_deg"], dtype=np.float64)),
            stop_sense=np.asarray(doc["stop_sense"], dtype=np.float64),
            stop_tips=np.asarray(doc["stop_tips_mm"], dtype=np.float64),
            spread_mm=float(doc["spread_mm"]),
        )
    except (KeyError, TypeError, ValueError, IndexError, ConfigurationError) as exc:
        raise FileFormatError(f"{where}: malformed map prior ({exc})") from exc


def _polar(radii: Array, theta: Array, table: Array) -> Callable[[Array, Array], Array]:
    """A bicubic spline (..., 3) over (radius, angle) of readings ``table`` (n_r, n_t, 3) at
    ``radii`` (ascending, the first 0) and ``theta`` (ascending in [0, 2 pi)), periodic in
    the angle; beyond the last radius, its ring's values."""
    th = np.concatenate([theta[-3:] - 2.0 * math.pi, theta, theta[:3] + 2.0 * math.pi])
    vals = np.concatenate([table[:, -3:], table, table[:, :3]], axis=1)
    splines = [RectBivariateSpline(radii, th, vals[..., c], s=0.0) for c in range(3)]

    def at(a: Array, b: Array) -> Array:
        aa, bb = np.asarray(a, np.float64), np.asarray(b, np.float64)
        r = np.minimum(np.hypot(aa, bb), radii[-1])
        t = np.mod(np.arctan2(bb, aa), 2.0 * math.pi)
        return np.stack([sp.ev(r, t) for sp in splines], axis=-1)

    return at


def turned_positions(
    drive: Callable[[Array], Array],
    sense: int,
    radius_step: float = TURN_RADIUS_STEP,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> Callable[[Array, Array], Array]:
    """One catheter's tip (..., 3) (mm, knob frame) at motor knobs (rad) reached turning in
    ``sense`` (+1 counter-clockwise, -1 clockwise) or straight out from rest (0):
    ``drive`` (a motor knob path (n, 2) rad, driven in order from rest -> the tips (n, 3)
    mm along it; e.g. the full calibration's model) is run once per ring of radius
    ``radius_step``, ``2 radius_step``, ... up to the knob limit, out to the ring and one
    turn in :data:`TURN_STEP` steps, then a second turn read at each step (sense 0: once
    per angle of :data:`TURN_STEP`, straight out in ``radius_step`` steps, read at each);
    a spline over (radius, angle) of the readings."""
    if sense not in (-1, 0, 1):
        raise ConfigurationError(f"sense must be +1, 0 or -1, got {sense!r}")
    radii = np.arange(radius_step, geometry.knob_limit + 1e-9, radius_step)
    n = int(round(2.0 * math.pi / TURN_STEP))
    theta = 2.0 * math.pi * np.arange(n) / n
    table = np.empty((radii.size + 1, n, 3))
    table[0] = np.asarray(drive(np.zeros((1, 2))), np.float64).reshape(1, 3)
    if sense == 0:
        for k, t in enumerate(theta):
            spoke = np.stack([radii * math.cos(t), radii * math.sin(t)], -1)
            table[1:, k] = np.asarray(drive(spoke), np.float64)
        return _polar(np.concatenate([[0.0], radii]), theta, table)
    for i, r in enumerate(radii):
        out = np.linspace(0.0, r, max(2, int(np.ceil(r / TURN_STEP)) + 1))[1:]
        turn = sense * np.concatenate([theta[1:], 2.0 * math.pi + theta[1:], [4.0 * math.pi]])
        path = np.vstack(
            [np.stack([out, 0.0 * out], -1), np.stack([r * np.cos(turn), r * np.sin(turn)], -1)]
        )
        tips = np.asarray(drive(path), np.float64)[-n:]  # angles 0, s step, ..., s (n-1) step
        # readings at turn 2 pi + s theta_k (k >= 1) and 4 pi: angle index k (sense +1) or
        # n - k (sense -1), the last one at angle 0
        idx = np.concatenate([np.arange(1, n), [0]])
        idx = idx if sense == 1 else np.mod(n - idx, n)
        table[i + 1, idx] = tips
    return _polar(np.concatenate([[0.0], radii]), theta, table)


def stop_senses(path: Any) -> Array:
    """(m,) the sense each stop of a motor knob ``path`` (m, 2) (rad, from rest) is reached
    in: the sign of the turn about the knob origin from the stop before (+1
    counter-clockwise, -1 clockwise, 0 a move along a radius or from rest)."""
    x = np.asarray(path, dtype=np.float64)[:, :2]
    prev = np.vstack([np.zeros((1, 2)), x[:-1]])
    cross = prev[:, 0] * x[:, 1] - prev[:, 1] * x[:, 0]
    scale = np.maximum(np.hypot(*prev.T) * np.hypot(*x.T), 1e-12)
    return np.where(np.abs(cross / scale) < 1e-9, 0.0, np.sign(cross))


def make_map_prior(
    drives: Sequence[Callable[[Array], Array]],
    product: str,
    catheters: Sequence[str],
    rings: Any,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    radius_step: float = TURN_RADIUS_STEP,
) -> MapPrior:
    """(M0) over the catheters' ``drives`` (one per catheter of ``catheters``: a motor knob
    path (n, 2) rad from rest -> tips (n, 3) mm in the knob frame, e.g. the full
    calibration's model of the transmission and F, bias- and section-free): each sense's
    :func:`turned_positions` on the :data:`MAP_GRID_STEP` grid, and the mean tips of the
    short calibration's ring stops ``rings`` ((m, 2+) motor knobs, rad, in the order
    driven from rest; :func:`icenav.calibration.short.ring_path`); the rings read every
    ``radius_step`` (rad)."""
    if len(drives) == 0 or len(drives) != len(catheters):
        raise ConfigurationError(
            f"need one or more catheter drives and one name each, got {len(drives)} and "
            f"{len(catheters)}"
        )
    stops = np.asarray(rings, dtype=np.float64)
    if stops.ndim != 2 or stops.shape[0] < 1 or stops.shape[1] < 2:
        raise ConfigurationError(f"rings must be (m, 2) knob pairs, got {stops.shape}")
    stops = stops[:, :2]
    ax = _axis(geometry.knob_limit)
    ga, gb = np.meshgrid(ax, ax, indexing="ij")
    means, dev = [], []
    for sense in (1, -1, 0):
        stack = np.stack(
            [turned_positions(d, sense, radius_step, geometry)(ga, gb) for d in drives]
        )
        if not np.all(np.isfinite(stack)):
            raise ConfigurationError("each catheter drive must give finite (n, 3) tips")
        mean = np.mean(stack, axis=0)  # (M0)
        means.append(mean)
        dev.append(np.sum((stack - mean) ** 2, axis=-1))
    tips = np.mean([np.asarray(d(stops), np.float64) for d in drives], axis=0)
    return MapPrior(
        product=str(product),
        catheters=tuple(str(c) for c in catheters),
        knobs=tuple(float(x) for x in ax),
        positions=means[0],
        reverse=means[1],
        radial=means[2],
        stops=stops,
        stop_sense=stop_senses(stops),
        stop_tips=tips,
        spread_mm=float(np.sqrt(np.mean(np.stack(dev)))),
    )
