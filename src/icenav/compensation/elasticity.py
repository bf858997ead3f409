"""Elasticity compensation: the map F (model knobs -> motor knobs), built from a calibration set
(:mod:`icenav.compensation.calibration_set`, re-exported here).

The paper's Section III-C: the constant-curvature model (:mod:`icenav.geometry.kinematics`) assumes
that the bend is a linear function of the knob angles; a real catheter bends in another
plane and by another angle. F corrects the *model* knob angles (phi1, phi2) into the *motor*
knob angles (phi1', phi2') that put the real tip where the model expects it (Eq. (9)):

    phi1', phi2' = F(phi1, phi2)                                   # Eq. (9)

Building F (:meth:`ElasticityMap.build`), as the paper describes and with two additions:

1. Three 2-D interpolators of the measured tip x, y, z over the *motor* knob plane
   (the paper's P*): a smoothing bicubic spline (``RectBivariateSpline``) for a full grid,
   a thin-plate RBF (``RBFInterpolator``) for scattered or sparse sets (5, 9, 13 points).
   By default the interpolators fit the *deviation* of the measured tip from the model tip
   at the same knob angles (``relative_to_model=True``), so that a catheter that follows the
   model gives F = identity exactly and a sparse set only has to describe a smooth
   correction; ``relative_to_model=False`` interpolates the raw positions as the paper does.
2. For each model knob pair of a grid, the model tip position (``kinematics.forward``) is
   matched to the interpolated real geometry by nearest neighbour (``scipy.spatial.cKDTree``)
   to find the motor knob pair that puts the real tip there (the paper's registration).
3. Beyond the paper: a local Gauss-Newton refinement of each match on the interpolated real
   geometry (it removes the quantisation of the nearest-neighbour grid), then a cubic spline
   through the corrected table and a C1 bicubic Hermite table of it, so F is smooth enough to
   drive motors and one scalar evaluation costs a few microseconds (pure ``math``).

The inverse map (motor -> model) is built the same way in the other direction: the model
knob pair whose model tip is nearest to the interpolated real tip of a motor knob pair.
Inside a dead-zone several motor knob pairs give the same real tip, so the inverse map is
many-to-one there and its Jacobian determinant drops towards 0;
:meth:`ElasticityMap.inverse_jacobian` exposes it and :meth:`ElasticityMap.in_dead_zone`
flags the region explicitly (F itself stays single-valued and smooth: it picks the
nearest consistent motor pair, and the spline through it bounds its slope).

Roll (phi3) and translation (d4) pass through unchanged (the paper's assumption).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import (
    CloughTocher2DInterpolator,
    RBFInterpolator,
    RectBivariateSpline,
)
from scipy.spatial import cKDTree

from icenav._typing import Array
from icenav._validation import check_finite, check_joint_state
from icenav.compensation.calibration_set import (
    CALIBRATION_FORMAT,
    CALIBRATION_VERSION,
    CalibrationSet,
    grid_subset_indices,
)
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward
from icenav.geometry.kinematics import inverse as kin_inverse

__all__ = [
    "BuildReport",
    "CALIBRATION_FORMAT",
    "CALIBRATION_VERSION",
    "CalibrationSet",
    "ElasticityMap",
    "Interpolant",
    "TABLE_NODES",
    "grid_subset_indices",
    "table_nodes",
]

Interpolant = Literal["auto", "spline", "rbf", "clough-tocher"]


# --- the bicubic table (fast evaluation) -------------------------------------------------

_HERMITE = np.array(
    [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [-3.0, 3.0, -2.0, -1.0], [2.0, -2.0, 1.0, 1.0]]
)


class _BicubicTable:
    """A C1 bicubic Hermite interpolant of a smooth map R^2 -> R^2 on a uniform square grid.

    Built from values and derivatives of a smooth spline at the nodes; evaluated with plain
    ``math`` for one point (a few microseconds) and with numpy for batches.
    """

    def __init__(self, lo: float, hi: float, n: int, spline_x: Any, spline_y: Any) -> None:
        self.lo = lo
        self.hi = hi
        self.n = n
        self.h = (hi - lo) / (n - 1)
        nodes = np.linspace(lo, hi, n)
        coefs = np.empty((n - 1, n - 1, 2, 4, 4))
        for out, spl in enumerate((spline_x, spline_y)):
            f = spl(nodes, nodes)
            fx = spl(nodes, nodes, dx=1) * self.h
            fy = spl(nodes, nodes, dy=1) * self.h
            fxy = spl(nodes, nodes, dx=1, dy=1) * self.h * self.h
            m = np.empty((n - 1, n - 1, 4, 4))
            m[..., 0, 0], m[..., 0, 1] = f[:-1, :-1], f[:-1, 1:]
            m[..., 1, 0], m[..., 1, 1] = f[1:, :-1], f[1:, 1:]
            m[..., 0, 2], m[..., 0, 3] = fy[:-1, :-1], fy[:-1, 1:]
            m[..., 1, 2], m[..., 1, 3] = fy[1:, :-1], fy[1:, 1:]
            m[..., 2, 0], m[..., 2, 1] = fx[:-1, :-1], fx[:-1, 1:]
            m[..., 3, 0], m[..., 3, 1] = fx[1:, :-1], fx[1:, 1:]
            m[..., 2, 2], m[..., 2, 3] = fxy[:-1, :-1], fxy[:-1, 1:]
            m[..., 3, 2], m[..., 3, 3] = fxy[1:, :-1], fxy[1:, 1:]
            # p(u, v) = [1 u u^2 u^3] C [1 v v^2 v^3]^T with C = H M H^T
            coefs[:, :, out] = _HERMITE @ m @ _HERMITE.T
        self.coefs = coefs
        # nested tuples for the scalar path: cell -> 32 floats (x row-major, then y)
        self._cells = [
            [tuple(coefs[i, j].ravel().tolist()) for j in range(n - 1)] for i in range(n - 1)
        ]

    def eval_scalar(self, a: float, b: float) -> tuple[float, float]:
        u = (a - self.lo) / self.h
        v = (b - self.lo) / self.h
        last = self.n - 2
        i = int(u) if u > 0.0 else 0
        j = int(v) if v > 0.0 else 0
        if i > last:
            i = last
        if j > last:
            j = last
        u -= i
        v -= j
        c = self._cells[i][j]
        r0 = ((c[3] * v + c[2]) * v + c[1]) * v + c[0]
        r1 = ((c[7] * v + c[6]) * v + c[5]) * v + c[4]
        r2 = ((c[11] * v + c[10]) * v + c[9]) * v + c[8]
        r3 = ((c[15] * v + c[14]) * v + c[13]) * v + c[12]
        s0 = ((c[19] * v + c[18]) * v + c[17]) * v + c[16]
        s1 = ((c[23] * v + c[22]) * v + c[21]) * v + c[20]
        s2 = ((c[27] * v + c[26]) * v + c[25]) * v + c[24]
        s3 = ((c[31] * v + c[30]) * v + c[29]) * v + c[28]
        return ((r3 * u + r2) * u + r1) * u + r0, ((s3 * u + s2) * u + s1) * u + s0

    def eval_batch(self, a: Array, b: Array, chunk: int = 65536) -> tuple[Array, Array]:
        shape = np.broadcast_shapes(a.shape, b.shape)
        fa = np.broadcast_to(a, shape).ravel()
        fb = np.broadcast_to(b, shape).ravel()
        out = np.empty((fa.size, 2))
        last = self.n - 2
        for s in range(0, fa.size, chunk):
            u = (fa[s : s + chunk] - self.lo) / self.h
            v = (fb[s : s + chunk] - self.lo) / self.h
            i = np.clip(np.floor(u), 0, last).astype(np.intp)
            j = np.clip(np.floor(v), 0, last).astype(np.intp)
            u -= i
            v -= j
            c = self.coefs[i, j]  # (m, 2, 4, 4)
            vp = np.stack([np.ones_like(v), v, v * v, v * v * v], axis=-1)
            up = np.stack([np.ones_like(u), u, u * u, u * u * u], axis=-1)
            out[s : s + chunk] = np.einsum("mi,mkij,mj->mk", up, c, vp)
        return out[:, 0].reshape(shape), out[:, 1].reshape(shape)


# --- the real-geometry interpolant (P*) --------------------------------------------------


def _grid_axes(knobs: Array) -> tuple[Array, Array, NDArray[np.intp]] | None:
    """If the knob pairs lie on a rectangular grid of >= 4 x 4 with at least 90 % of its
    nodes present: the axes and each sample's flat node index (ix * ny + iy)."""
    xs = np.unique(np.round(knobs[:, 0], 9))
    ys = np.unique(np.round(knobs[:, 1], 9))
    if xs.size < 4 or ys.size < 4 or knobs.shape[0] < 0.9 * xs.size * ys.size:
        return None
    ix = np.searchsorted(xs, np.round(knobs[:, 0], 9))
    iy = np.searchsorted(ys, np.round(knobs[:, 1], 9))
    flat = ix * ys.size + iy
    if np.unique(flat).size != flat.size:
        return None
    return xs, ys, flat


def _model_knob_positions(p1: Array, p2: Array, g: CatheterGeometry) -> Array:
    """Model tip positions (..., 3) in the knob frame for model knobs p1, p2 (rad)."""
    q = np.zeros((*np.broadcast_shapes(np.shape(p1), np.shape(p2)), 4))
    q[..., 0] = p1
    q[..., 1] = p2
    return forward(q, g, check=False)[..., :3, 3]


@dataclass(frozen=True)
class BuildReport:
    """How an :class:`ElasticityMap` was built, and how well it fits."""

    interpolant: str
    """Interpolant of the real geometry: ``spline``, ``rbf`` or ``clough-tocher``."""
    smoothing: float
    """Smoothing parameter used (spline: sum of squared residuals in mm^2; rbf: lambda)."""
    relative_to_model: bool
    """Whether the deviation from the model (True) or the raw position was interpolated."""
    n_samples: int
    """Number of calibration samples."""
    fit_rms_mm: float
    """RMS difference between the interpolated and the measured tip positions (mm)."""
    nn_match_rms_mm: float
    """RMS distance from each reachable model tip to its nearest-neighbour real tip (mm)."""
    refined_match_rms_mm: float
    """The same after the local refinement (mm); lower means the refinement helps."""
    unreachable_fraction: float
    """Fraction of model knob pairs whose model tip the real catheter cannot reach
    within the motor knob limits (match residual > 1 mm)."""


_QUERY_STEP = math.radians(0.5)  # nearest-neighbour grid of motor knobs
_TABLE_NODES = 91  # bicubic table nodes per axis (2 deg over +-90 deg)
TABLE_NODES = _TABLE_NODES
"""Nodes per axis of F's two bicubic tables (:func:`table_nodes`)."""


def table_nodes(geometry: CatheterGeometry) -> Array:
    """(TABLE_NODES,) the knob angles (rad) of F's tables on each axis, over the knob range."""
    lim = geometry.knob_limit
    return np.linspace(-lim, lim, _TABLE_NODES)


_GN_STEP = 1e-4  # rad, finite-difference step of the refinement
_UNREACHABLE_MM = 1.0


class ElasticityMap:
    """The compensation map F (model knobs -> motor knobs) and its inverse.

    Build with :meth:`build`. Evaluate with :meth:`model_to_motor` (full joint vectors) or
    :meth:`model_to_motor_knobs` (knob pairs; the scalar fast path for one pair of floats).
    """

    def __init__(
        self,
        geometry: CatheterGeometry,
        real_position: Callable[[Array, Array], Array],
        forward_table: _BicubicTable,
        inverse_table: _BicubicTable,
        report: BuildReport,
        calibration: CalibrationSet,
        dead_zone_det: float,
    ) -> None:
        self.geometry = geometry
        self._lim = geometry.knob_limit
        self._real_position = real_position
        self._fwd = forward_table
        self._inv = inverse_table
        self.report = report
        """How the map was built (:class:`BuildReport`)."""
        self.calibration = calibration
        """The calibration set the map was built from."""
        self.dead_zone_det = dead_zone_det
        """|det| of the inverse map's Jacobian below which a motor pair is in a dead-zone."""

    # --- construction --------------------------------------------------------------------

    @classmethod
    def from_tables(
        cls,
        geometry: CatheterGeometry,
        real_position: Callable[[Array, Array], Array],
        model_to_motor: Array,
        motor_to_model: Array,
        report: BuildReport,
        calibration: CalibrationSet,
        dead_zone_det: float,
    ) -> ElasticityMap:
        """F from the values of its two tables at the nodes ``table_nodes(geometry)`` x
        ``table_nodes(geometry)`` ((TABLE_NODES**2, 2) knob pairs, rad, row-major as the
        nodes), as a calibration file stores them: the same bicubic tables :meth:`build`
        makes, without re-fitting (milliseconds instead of tens of seconds)."""
        nodes = table_nodes(geometry)
        return cls(
            geometry,
            real_position,
            _table_from_values(nodes, np.asarray(model_to_motor, np.float64)),
            _table_from_values(nodes, np.asarray(motor_to_model, np.float64)),
            report,
            calibration,
            dead_zone_det,
        )

    @classmethod
    def build(
        cls,
        calibration: CalibrationSet,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
        *,
        interpolant: Interpolant = "auto",
        smoothing: float | None = None,
        relative_to_model: bool = True,
        refine: bool = True,
    ) -> ElasticityMap:
        """Build F and its inverse from a calibration set (paper Sec. III-C).

        Parameters
        ----------
        calibration : CalibrationSet
            Motor joint states and tracked tip poses (>= 3 samples; 5 for a useful map).
        interpolant : {"auto", "spline", "rbf", "clough-tocher"}
            Interpolant of the real tip over the motor knobs. ``auto``: a smoothing bicubic
            spline if the samples form a grid of >= 4 x 4 knob pairs (up to 10 % of the
            nodes may be missing, e.g. skipped samples; they are filled from their
            neighbours), else thin-plate RBF (see docs/calibration.md for the measured
            comparison).
        smoothing : float, optional
            Spline: the ``s`` of RectBivariateSpline (mm^2, sum over samples; default
            ``n * (0.7 mm)^2``, chosen by measurement). RBF: its ``smoothing`` (default 0).
        relative_to_model : bool
            Interpolate the deviation of the real tip from the model tip (default), or the
            raw real tip position as the paper does.
        refine : bool
            Refine each nearest-neighbour match by Gauss-Newton on the interpolated geometry.
        """
        g = geometry
        knobs = calibration.q_motor[:, :2]
        lim = g.knob_limit
        if np.any(np.abs(knobs) > lim + 1e-9):
            raise ConfigurationError(
                f"calibration knob angles must be within +-{math.degrees(lim):.1f} deg, got "
                f"{math.degrees(float(np.max(np.abs(knobs)))):.2f} deg"
            )
        p_real = calibration.positions_in_knob_frame()
        target = (
            p_real - _model_knob_positions(knobs[:, 0], knobs[:, 1], g)
            if (relative_to_model)
            else p_real
        )
        grid = _grid_axes(knobs)
        kind = interpolant
        if kind == "auto":
            kind = "spline" if grid is not None else "rbf"
        n = calibration.n_samples
        fit: Callable[[Array, Array], Array]
        if kind == "spline":
            if grid is None:
                raise ConfigurationError(
                    "interpolant='spline' needs the samples on a rectangular knob grid of at "
                    f"least 4 x 4 (<= 10 % missing); got {n} scattered samples (use 'rbf')"
                )
            xs, ys, flat = grid
            s = n * 0.7**2 if smoothing is None else float(smoothing)
            vals = np.empty((xs.size * ys.size, 3))
            vals[flat] = target
            holes = np.setdiff1d(np.arange(vals.shape[0]), flat)
            if holes.size:  # skipped samples: fill from their neighbours (thin-plate RBF)
                gx, gy = np.meshgrid(xs, ys, indexing="ij")
                nodes_xy = np.stack([gx.ravel(), gy.ravel()], axis=-1)
                fill = RBFInterpolator(knobs, target, kernel="thin_plate_spline", neighbors=32)
                vals[holes] = fill(nodes_xy[holes])
            grid_vals = vals.reshape(xs.size, ys.size, 3)
            splines = [RectBivariateSpline(xs, ys, grid_vals[..., k], s=s) for k in range(3)]

            def fit(a: Array, b: Array, _sp: list[RectBivariateSpline] = splines) -> Array:
                return np.stack([sp.ev(a, b) for sp in _sp], axis=-1)

        elif kind == "rbf":
            s = 0.0 if smoothing is None else float(smoothing)
            degree = 1 if n >= 3 else 0
            # samples at the same knob pair (e.g. inside a dead-zone): average them
            uniq, inv = np.unique(np.round(knobs, 9), axis=0, return_inverse=True)
            inv = inv.ravel()
            mean_t = np.zeros((uniq.shape[0], 3))
            np.add.at(mean_t, inv, target)
            mean_t /= np.bincount(inv, minlength=uniq.shape[0])[:, None]
            try:
                rbf = RBFInterpolator(
                    uniq, mean_t, kernel="thin_plate_spline", smoothing=s, degree=degree
                )
            except np.linalg.LinAlgError:  # nearly coincident samples: regularise a little
                s = max(s, 1e-6 * uniq.shape[0])
                rbf = RBFInterpolator(
                    uniq, mean_t, kernel="thin_plate_spline", smoothing=s, degree=degree
                )

            def fit(a: Array, b: Array, _r: RBFInterpolator = rbf) -> Array:
                pts = np.stack([np.ravel(a), np.ravel(b)], axis=-1)
                return np.asarray(_r(pts)).reshape(*np.shape(a), 3)

        elif kind == "clough-tocher":
            s = 0.0
            ct = CloughTocher2DInterpolator(knobs, target, fill_value=np.nan)
            # outside the convex hull: fall back to the nearest sample's value
            near = cKDTree(knobs)

            def fit(a: Array, b: Array, _c: Any = ct) -> Array:
                pts = np.stack([np.ravel(a), np.ravel(b)], axis=-1)
                v = np.asarray(_c(pts))
                bad = ~np.isfinite(v[:, 0])
                if np.any(bad):
                    v[bad] = target[near.query(pts[bad])[1]]
                return v.reshape(*np.shape(a), 3)

        else:
            raise ConfigurationError(
                f"interpolant must be 'auto', 'spline', 'rbf' or 'clough-tocher', got {kind!r}"
            )

        if relative_to_model:

            def real_position(a: Array, b: Array) -> Array:
                return _model_knob_positions(a, b, g) + fit(a, b)

        else:
            real_position = fit

        fit_rms = float(
            np.sqrt(np.mean(np.sum((real_position(knobs[:, 0], knobs[:, 1]) - p_real) ** 2, -1)))
        )

        # --- F: model knobs -> motor knobs (nearest neighbour, then refinement) ----------
        qax = np.arange(-lim, lim + 0.5 * _QUERY_STEP, _QUERY_STEP)
        qa, qb = np.meshgrid(qax, qax, indexing="ij")
        cloud = real_position(qa.ravel(), qb.ravel())
        tree = cKDTree(cloud)
        nodes = np.linspace(-lim, lim, _TABLE_NODES)
        ma, mb = np.meshgrid(nodes, nodes, indexing="ij")
        p_model = _model_knob_positions(ma.ravel(), mb.ravel(), g)
        dist, idx = tree.query(p_model)
        start = np.stack([qa.ravel()[idx], qb.ravel()[idx]], axis=-1)
        nn_rms = float(np.sqrt(np.mean(dist**2)))
        if refine:
            sol, res = _refine(real_position, p_model, start, lim)
        else:
            sol, res = start, dist
        ok = res <= _UNREACHABLE_MM
        unreachable = float(np.mean(~ok))
        if np.any(ok):
            nn_rms = float(np.sqrt(np.mean(dist[ok] ** 2)))
            ref_rms = float(np.sqrt(np.mean(res[ok] ** 2)))
        else:
            ref_rms = float(np.sqrt(np.mean(res**2)))
        fwd_table = _table_from_values(nodes, sol)

        # --- inverse: motor knobs -> model knobs -----------------------------------------
        fine = np.arange(-lim, lim + 0.5 * _QUERY_STEP, _QUERY_STEP)
        fa, fb = np.meshgrid(fine, fine, indexing="ij")
        model_tree = cKDTree(_model_knob_positions(fa.ravel(), fb.ravel(), g))
        p_real_nodes = real_position(ma.ravel(), mb.ravel())
        _, midx = model_tree.query(p_real_nodes)
        mstart = np.stack([fa.ravel()[midx], fb.ravel()[midx]], axis=-1)

        def model_position(a: Array, b: Array) -> Array:
            return _model_knob_positions(a, b, g)

        if refine:
            msol, _ = _refine(model_position, p_real_nodes, mstart, lim)
        else:
            msol = mstart
        inv_table = _table_from_values(nodes, msol)

        # dead-zone threshold: the inverse Jacobian's |det| below 10 % of its median
        jinv = _table_jacobian(inv_table, ma.ravel(), mb.ravel())
        det = np.abs(np.linalg.det(jinv))
        dz = 0.1 * float(np.median(det))

        report = BuildReport(
            interpolant=kind,
            smoothing=float(s),
            relative_to_model=relative_to_model,
            n_samples=n,
            fit_rms_mm=fit_rms,
            nn_match_rms_mm=nn_rms,
            refined_match_rms_mm=ref_rms,
            unreachable_fraction=unreachable,
        )
        return cls(g, real_position, fwd_table, inv_table, report, calibration, dz)

    # --- evaluation ----------------------------------------------------------------------

    def _check_knobs(self, phi1: ArrayLike, phi2: ArrayLike, name: str) -> tuple[Array, Array]:
        a = check_finite(phi1, f"{name} phi1", "rad")
        b = check_finite(phi2, f"{name} phi2", "rad")
        lim = self.geometry.knob_limit
        for arr, joint in ((a, "phi1"), (b, "phi2")):
            if np.any(np.abs(arr) > lim + 1e-9):
                v = float(np.ravel(arr)[np.argmax(np.abs(np.ravel(arr)))])
                raise ConfigurationError(
                    f"{name} {joint} = {v:.6g} rad ({math.degrees(v):.2f} deg) is outside the "
                    f"map's range [-{lim:.6g}, {lim:.6g}] rad (+-{math.degrees(lim):.1f} deg)"
                )
        return a, b

    def model_to_motor_knobs(
        self, phi1: ArrayLike, phi2: ArrayLike, *, check: bool = True
    ) -> tuple[Any, Any]:
        """F: model knob angles -> motor knob angles (Eq. (9)).

        Parameters
        ----------
        phi1, phi2 : float or array-like (same shape)
            Model knob angles (rad), within the knob limits.
        check : bool
            Validate the input; ``False`` skips it (hot loops). Python floats with
            ``check=False`` take the scalar fast path.

        Returns
        -------
        phi1_motor, phi2_motor : float or ndarray
            Motor knob angles (rad), clipped to the knob limits (an explicit safety limit:
            where the real catheter cannot reach the model tip within them, F returns the
            nearest reachable pair; see ``report.unreachable_fraction``).
        """
        return self._eval(self._fwd, phi1, phi2, check, "model")

    def motor_to_model_knobs(
        self, phi1: ArrayLike, phi2: ArrayLike, *, check: bool = True
    ) -> tuple[Any, Any]:
        """F^-1: motor knob angles -> the model knob angles the real tip corresponds to."""
        return self._eval(self._inv, phi1, phi2, check, "motor")

    def _eval(
        self, table: Any, phi1: ArrayLike, phi2: ArrayLike, check: bool, space: str
    ) -> tuple[Any, Any]:
        """Evaluate F (``self._fwd``) or F^-1 (``self._inv``), clipped to the knob limits;
        Python floats that pass (or skip) the check take the scalar fast path."""
        lim = self._lim
        if (
            type(phi1) is float
            and type(phi2) is float
            and (
                not check
                or (
                    math.isfinite(phi1)
                    and math.isfinite(phi2)
                    and abs(phi1) <= lim + 1e-9
                    and abs(phi2) <= lim + 1e-9
                )
            )
        ):
            x, y = table.eval_scalar(phi1, phi2)
            return min(max(x, -lim), lim), min(max(y, -lim), lim)
        a, b = (
            self._check_knobs(phi1, phi2, space)
            if check
            else (np.asarray(phi1, np.float64), np.asarray(phi2, np.float64))
        )
        if a.ndim == 0 and b.ndim == 0:
            x, y = table.eval_scalar(float(a), float(b))
            return min(max(x, -lim), lim), min(max(y, -lim), lim)
        xa, ya = table.eval_batch(a, b)
        return np.clip(xa, -lim, lim), np.clip(ya, -lim, lim)

    def model_to_motor(self, q_model: ArrayLike, *, check: bool = True) -> Array:
        """Model joint state(s) (..., 4) -> motor joint state(s); phi3 and d4 unchanged."""
        q = (
            check_joint_state(q_model, self.geometry.joint_limits, name="q_model")
            if check
            else np.asarray(q_model, np.float64)
        )
        out = q.copy()
        a, b = self.model_to_motor_knobs(q[..., 0], q[..., 1], check=False)
        out[..., 0] = a
        out[..., 1] = b
        return out

    def motor_to_model(self, q_motor: ArrayLike, *, check: bool = True) -> Array:
        """Motor joint state(s) (..., 4) -> model joint state(s); phi3 and d4 unchanged."""
        q = (
            check_joint_state(q_motor, self.geometry.joint_limits, name="q_motor")
            if check
            else np.asarray(q_motor, np.float64)
        )
        out = q.copy()
        a, b = self.motor_to_model_knobs(q[..., 0], q[..., 1], check=False)
        out[..., 0] = a
        out[..., 1] = b
        return out

    def forward(self, q_motor: ArrayLike, *, check: bool = True) -> Array:
        """Compensated forward kinematics: motor joint state -> expected tip2base (..., 4, 4)."""
        return forward(self.motor_to_model(q_motor, check=check), self.geometry, check=False)

    def inverse(self, tip2base: ArrayLike, **kwargs: Any) -> Array:
        """Compensated inverse kinematics: tip2base -> motor joint state (..., 4).

        ``kwargs`` go to :func:`icenav.geometry.kinematics.inverse` (``unreachable``,
        ``phi3_near``).
        """
        q_model = kin_inverse(tip2base, self.geometry, **kwargs)
        lim = self.geometry.knob_limit
        q_model[..., :2] = np.clip(q_model[..., :2], -lim, lim)
        return self.model_to_motor(q_model, check=False)

    def real_position(self, phi1_motor: ArrayLike, phi2_motor: ArrayLike) -> Array:
        """Interpolated real tip position (..., 3) in the knob frame for motor knobs (mm)."""
        a, b = self._check_knobs(phi1_motor, phi2_motor, "motor")
        return self._real_position(a, b)

    def jacobian(self, phi1: ArrayLike, phi2: ArrayLike) -> Array:
        """d(motor knobs)/d(model knobs) of F, shape (..., 2, 2) (rad/rad)."""
        a, b = self._check_knobs(phi1, phi2, "model")
        return _table_jacobian(self._fwd, a, b)

    def inverse_jacobian(self, phi1_motor: ArrayLike, phi2_motor: ArrayLike) -> Array:
        """d(model knobs)/d(motor knobs) of F^-1, shape (..., 2, 2); singular in a dead-zone."""
        a, b = self._check_knobs(phi1_motor, phi2_motor, "motor")
        return _table_jacobian(self._inv, a, b)

    def in_dead_zone(self, phi1_motor: ArrayLike, phi2_motor: ArrayLike) -> NDArray[np.bool_]:
        """True where the motor knobs lie in a dead-zone (the real tip barely moves:
        |det dF^-1| below 10 % of its median over the workspace)."""
        det = np.abs(np.linalg.det(self.inverse_jacobian(phi1_motor, phi2_motor)))
        return np.asarray(det < self.dead_zone_det)


def _table_jacobian(table: _BicubicTable, a: Array, b: Array, eps: float = 1e-6) -> Array:
    """Central-difference Jacobian (..., 2, 2) of a bicubic table."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    xp = table.eval_batch(a + eps, b)
    xm = table.eval_batch(a - eps, b)
    yp = table.eval_batch(a, b + eps)
    ym = table.eval_batch(a, b - eps)
    jac = np.empty((*np.broadcast_shapes(a.shape, b.shape), 2, 2))
    for k in range(2):
        jac[..., k, 0] = (xp[k] - xm[k]) / (2 * eps)
        jac[..., k, 1] = (yp[k] - ym[k]) / (2 * eps)
    return jac


def _table_from_values(nodes: Array, values: Array) -> _BicubicTable:
    """Bicubic table through a (m*m, 2) table of values on nodes x nodes (interpolating)."""
    m = nodes.size
    vx = values[:, 0].reshape(m, m)
    vy = values[:, 1].reshape(m, m)
    sx = RectBivariateSpline(nodes, nodes, vx, s=0)
    sy = RectBivariateSpline(nodes, nodes, vy, s=0)
    return _BicubicTable(float(nodes[0]), float(nodes[-1]), m, sx, sy)


def _refine(
    surface: Callable[[Array, Array], Array],
    targets: Array,
    start: Array,
    lim: float,
    iterations: int = 8,
) -> tuple[Array, Array]:
    """Damped Gauss-Newton: knob pairs (m, 2) within +-lim minimising |surface(k) - target|.

    Returns the knob pairs and the remaining distances (mm).
    """
    k = start.copy()
    h = _GN_STEP
    for _ in range(iterations):
        p = surface(k[:, 0], k[:, 1])
        r = p - targets
        ja = (surface(k[:, 0] + h, k[:, 1]) - surface(k[:, 0] - h, k[:, 1])) / (2 * h)
        jb = (surface(k[:, 0], k[:, 1] + h) - surface(k[:, 0], k[:, 1] - h)) / (2 * h)
        jac = np.stack([ja, jb], axis=-1)  # (m, 3, 2)
        jt = np.swapaxes(jac, -1, -2)
        lhs = jt @ jac + 1e-3 * np.eye(2)
        step = -np.linalg.solve(lhs, (jt @ r[..., None]))[..., 0]
        k_new = np.clip(k + step, -lim, lim)
        r_new = np.linalg.norm(surface(k_new[:, 0], k_new[:, 1]) - targets, axis=-1)
        better = r_new < np.linalg.norm(r, axis=-1)
        k = np.where(better[:, None], k_new, k)
    res = np.linalg.norm(surface(k[:, 0], k[:, 1]) - targets, axis=-1)
    return k, res
