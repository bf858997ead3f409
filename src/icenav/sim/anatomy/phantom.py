"""A beating heart phantom for the ICE twin (analytic shapes, evaluated as label fields).

Frames and units
----------------
``anatomy``: patient LPS axes (x = patient left, y = posterior, z = superior), mm, with its
origin at the centre of the junction of the inferior vena cava (IVC) and the right atrium
(RA). The robot ``base`` frame (bottom of the bending section at q = 0) lies on the IVC axis,
catheter axis (base z) pointing superior, up into the RA; base x (the image facing
direction at q = 0) points anterior and base y points to the patient's left::

    base2anatomy = [[0, 1, 0, 0],      # base x -> anatomy -y (anterior)
                    [-1, 0, 0, 0],     # base y -> anatomy +x (left)
                    [0, 0, 1, -40],    # base z -> anatomy +z (superior); base 40 mm below
                    [0, 0, 0, 1]]      #   the IVC-RA junction

(:data:`BASE2ANATOMY`). The bending section (60 mm) plus the image centre offset (10 mm)
put the image centre 70 mm above the base: were the base exactly at the junction, the
straight catheter's transducer would sit 70 mm up, above a normal RA (long axis 42-53 mm)
in the superior vena cava. With the base :data:`BASE_BELOW_JUNCTION_MM` below the junction
the straight catheter's transducer is in the mid RA for d4 in [-20, 20] mm (the ICE "home
view", looking anteriorly across the RA at the tricuspid valve and the right ventricle),
and the junction lies within the bending section.

Geometry
--------
Chambers are ellipsoids (blood inside, a myocardial shell of a given thickness around;
adjacent chambers share their walls), vessels are finite cylinders, the interatrial septum
is a disc, each valve is an annulus (torus) with thin hinged leaflets (2 for tricuspid and
mitral, 3 for aortic) that swing open over the cardiac cycle. The default heart adds the
right ventricular outflow tract, the pulmonary artery, a pericardium around the smooth
union of the chambers, and the lungs beside it. Dimensions are end-diastolic and documented
against typical adult values in ``docs/imaging.md``; acoustic properties of every label are
in :mod:`icenav.sim.anatomy.tissue`.

Motion
------
A spatial point ``x`` at time ``t`` holds the material (end-diastolic, end-expiratory)
point ``X = x - u(x, t)``; labels and the ultrasound speckle are evaluated at ``X``, so
tissue and its speckle move together. ``u`` is respiratory translation plus cardiac
contraction / expansion of each chamber about its centre (Gaussian weighted, smooth) and
the descent of the valve plane in systole. Heart rate 72 beats/min by default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_finite, check_positive
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward
from icenav.sim.anatomy.shapes import (
    _LANDMARK_NAMES,
    PATIENT_DIRECTIONS,
    BloodVessel,
    Chamber,
    Landmark,
    Region,
    Valve,
    _frame_from_axis,
    _unit,
)
from icenav.sim.anatomy.tissue import ECHOGENICITY, Tissue

__all__ = [
    "BASE2ANATOMY",
    "BASE_BELOW_JUNCTION_MM",
    "BloodVessel",
    "CardiacMotion",
    "Chamber",
    "EXAMPLE_VIEWS",
    "HeartPhantom",
    "Landmark",
    "PATIENT_DIRECTIONS",
    "Region",
    "Valve",
    "default_phantom",
    "tip2anatomy",
]


BASE_BELOW_JUNCTION_MM = 40.0
"""Distance (mm) of the robot base below the IVC-RA junction, along the IVC axis."""

BASE2ANATOMY: Array = np.array(
    [
        [0.0, 1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, -BASE_BELOW_JUNCTION_MM],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
"""Fixed registration of the robot base to the anatomy frame (see the module docstring)."""
BASE2ANATOMY.setflags(write=False)


EXAMPLE_VIEWS: dict[str, tuple[float, float, float, float]] = {
    "aortic_valve": (math.radians(-10.0), math.radians(20.0), math.radians(45.0), 0.0),
    "mitral_valve": (math.radians(10.0), math.radians(-20.0), math.radians(105.0), 0.0),
    "tricuspid_valve": (math.radians(-10.0), 0.0, math.radians(30.0), -15.0),
}
"""Model joint states (phi1 rad, phi2 rad, phi3 rad, d4 mm) of the default catheter
geometry from which each valve is seen in the default phantom, with the transducer in RA
blood at least 4 mm from any wall or leaflet over the whole beat (found by a grid search,
see ``docs/imaging.md``); starting views for the recovery evaluation."""


_BEATING_CHAMBERS = ("ra", "rv", "la", "lv")
"""Chambers whose contraction drives the motion field (the others move passively)."""
_SMOOTH_UNION_MM = 5.0  # smoothing length of the pericardial envelope (mm)
_MEDIASTINUM_MM = 3.0  # fat between the pericardium and the lungs (mm)
_ORIFICE_HALF_MM = 6.0  # half-length of the valve orifice cut through the walls (mm)


@dataclass(frozen=True)
class CardiacMotion:
    """Cardiac and respiratory motion of the phantom."""

    heart_rate_bpm: float = 72.0
    """Heart rate (beats/min); the paper's subjects and phantom are 60-80."""
    ventricular_contraction: float = 0.14
    """Peak fractional shrink of the ventricles about their centres in systole."""
    atrial_filling: float = 0.07
    """Peak fractional growth of the atria in ventricular systole (and the atrial kick)."""
    valve_plane_descent_mm: float = 7.0
    """Peak systolic descent of the valve plane towards the apex (mm)."""
    respiratory_amplitude_mm: tuple[float, float, float] = (0.0, 0.5, 2.0)
    """Peak respiratory displacement of the heart (anatomy x, y, z; mm)."""
    respiratory_period_s: float = 4.1
    """Breathing period (s); deliberately not a multiple of the heart period."""

    def __post_init__(self) -> None:
        hr = check_positive(self.heart_rate_bpm, "heart_rate_bpm", "beats/min")
        if not 30.0 <= hr <= 200.0:
            raise ConfigurationError(f"heart_rate_bpm must be in [30, 200] beats/min, got {hr}")
        check_positive(self.respiratory_period_s, "respiratory_period_s", "s")
        for name in ("ventricular_contraction", "atrial_filling"):
            v = float(getattr(self, name))
            if not 0.0 <= v < 0.5:
                raise ConfigurationError(f"{name} must be in [0, 0.5), got {v}")

    @property
    def period_s(self) -> float:
        """Duration of one heart beat (s)."""
        return 60.0 / self.heart_rate_bpm


def _bump(phase: Array | float, start: float, end: float) -> Array:
    """Raised-cosine bump: 0 outside [start, end], 1 at the middle (phase in beats)."""
    p = np.asarray(phase, dtype=np.float64)
    w = end - start
    s = np.mod(p - start, 1.0)
    out: Array = np.where(s < w, 0.5 * (1.0 - np.cos(2.0 * np.pi * s / w)), 0.0)
    return out


def _bump_at(phase: float, start: float, end: float) -> float:
    """:func:`_bump` of one phase, to the bit (the modulo of Python floats is numpy's; the
    cosine on numpy's scalar path as there), without its array set-up (the displacement
    field asks it twice a call; ``docs/digital-twin.md`` section 8)."""
    w = end - start
    s = (float(phase) - start) % 1.0
    if not s < w:
        return 0.0
    return float(0.5 * (1.0 - np.cos(2.0 * np.pi * s / w)))


def _plateau(phase: float, start: float, end: float, ramp: float = 0.04) -> float:
    """Smooth 0 -> 1 -> 0 window over [start, end] (phases, wrapping) with cosine ramps."""
    w = (end - start) % 1.0
    s = (phase - start) % 1.0
    if s >= w:
        return 0.0
    if s < ramp:
        return 0.5 * (1.0 - math.cos(math.pi * s / ramp))
    if s > w - ramp:
        return 0.5 * (1.0 - math.cos(math.pi * (w - s) / ramp))
    return 1.0


class HeartPhantom:
    """The beating heart: label field, echogenicity, motion and ROIs.

    Parameters
    ----------
    chambers, vessels, valves :
        The structures, painted in this order: the lungs (outside the pericardium), the
        pericardium, every chamber wall, every chamber cavity (so adjacent chambers share
        their walls: the interventricular septum), vessels (wall then lumen), the septum,
        the valves, then the inclusions.
    septum_centre, septum_normal, septum_radius_mm, septum_mm :
        The interatrial septum disc (anatomy frame, mm).
    motion : CardiacMotion
        Cardiac and respiratory motion.
    pericardium_mm : float, optional
        Thickness (mm) of the pericardium, a shell around the smooth union of the chambers
        (``pericardium_gap_mm`` of epicardial fat between); None: no pericardium.
    lungs, inclusions : tuple of Region
        Lungs (painted only outside the pericardium and its mediastinal margin) and solid
        inclusions (painted over everything, e.g. a calcified nodule).
    """

    def __init__(
        self,
        chambers: tuple[Chamber, ...],
        vessels: tuple[BloodVessel, ...],
        valves: tuple[Valve, ...],
        *,
        septum_centre: tuple[float, float, float] = (20.5, 8.0, 30.0),
        septum_normal: tuple[float, float, float] = (1.0, 0.0, 0.0),
        septum_radius_mm: float = 17.0,
        septum_mm: float = 3.5,
        motion: CardiacMotion | None = None,
        pericardium_mm: float | None = None,
        pericardium_gap_mm: float = 4.0,
        lungs: tuple[Region, ...] = (),
        inclusions: tuple[Region, ...] = (),
    ) -> None:
        self.chambers = chambers
        self.pericardium_mm = (
            None
            if pericardium_mm is None
            else check_positive(pericardium_mm, "pericardium_mm", "mm")
        )
        self.pericardium_gap_mm = check_positive(pericardium_gap_mm, "pericardium_gap_mm", "mm")
        self.lungs = lungs
        self.inclusions = inclusions
        self.vessels = vessels
        self.valves = valves
        self.septum_centre = np.asarray(septum_centre, dtype=np.float64)
        self.septum_normal = _unit(septum_normal)
        self.septum_radius_mm = check_positive(septum_radius_mm, "septum_radius_mm", "mm")
        self.septum_mm = check_positive(septum_mm, "septum_mm", "mm")
        self.motion = motion or CardiacMotion()
        self._valve_frames = {v.name: _frame_from_axis(np.asarray(v.normal)) for v in valves}
        self._centres = {
            c.name: np.asarray(c.centre, dtype=np.float64)
            for c in chambers
            if c.name in _BEATING_CHAMBERS
        }
        self._sigmas = {c.name: max(c.semi_axes) for c in chambers}
        valve_centres = [np.asarray(v.centre) for v in valves if v.name != "tricuspid_valve"]
        self._base_centre = (
            np.mean(valve_centres, axis=0) if valve_centres else np.zeros(3, dtype=np.float64)
        )
        # In systole the atrioventricular plane descends towards the apex (the long-axis
        # shortening of the ventricles; mitral annular plane systolic excursion 12-15 mm,
        # tricuspid 20-25 mm in adults: Hu et al., Clin Physiol Funct Imaging 33:250, 2013;
        # Rudski et al., J Am Soc Echocardiogr 23:685, 2010): the direction from the valve
        # plane towards the LV centre along the LV's long axis, whichever way it is given.
        lv = [c for c in chambers if c.name == "lv"]
        apex = _unit(lv[0].long_axis) if lv else np.array([0.0, 0.0, -1.0])
        if lv and float(apex @ (np.asarray(lv[0].centre) - self._base_centre)) < 0.0:
            apex = -apex
        self._apex_dir = apex

    # --- time ---------------------------------------------------------------------------
    def cardiac_phase(self, t: float) -> float:
        """Phase in the beat at time ``t`` (s): fraction in [0, 1), 0 = R wave."""
        return float((t / self.motion.period_s) % 1.0)

    def valve_opening(self, name: str, t: float) -> float:
        """Opening of valve ``name`` at time ``t`` (s): 0 closed, 1 fully open."""
        valve = self._valve(name)
        return _plateau(self.cardiac_phase(t), *valve.open_phase)

    def _valve(self, name: str) -> Valve:
        for v in self.valves:
            if v.name == name:
                return v
        raise ConfigurationError(
            f"unknown valve {name!r}; known: {sorted(v.name for v in self.valves)}"
        )

    # --- motion ---------------------------------------------------------------------------
    def displacement(self, points: Array, t: float) -> Array:
        """Displacement u(x, t) (mm) at spatial ``points`` (N, 3), anatomy frame."""
        m = self.motion
        phase = self.cardiac_phase(t)
        systole = _bump_at(phase, 0.0, 0.45)
        atrial_kick = _bump_at(phase, 0.82, 0.98)
        u = np.zeros_like(points)
        for name, c in self._centres.items():
            if name in ("lv", "rv"):
                scale = -m.ventricular_contraction * systole
            else:
                scale = m.atrial_filling * (systole - atrial_kick)
            if scale == 0.0:
                continue
            rel = points - c
            sig = self._sigmas[name]
            w = np.exp(-np.einsum("ij,ij->i", rel, rel) / (2.0 * sig * sig))
            u += (scale * w)[:, None] * rel
        descent = m.valve_plane_descent_mm * systole
        if descent != 0.0:
            rel = points - self._base_centre
            w = np.exp(-np.einsum("ij,ij->i", rel, rel) / (2.0 * 30.0**2))
            u += (descent * w)[:, None] * self._apex_dir
        resp = np.asarray(m.respiratory_amplitude_mm) * math.sin(
            2.0 * math.pi * t / m.respiratory_period_s
        )
        u += resp
        return u

    def material_points(self, points: ArrayLike, t: float) -> Array:
        """Material (end-diastolic, end-expiratory) points X = x - u(x, t) of ``points``.

        Parameters
        ----------
        points : array-like, shape (..., 3)
            Spatial points in the anatomy frame (mm) at time ``t`` (s).

        Returns
        -------
        ndarray, shape (..., 3)
        """
        p = np.asarray(points, dtype=np.float64)
        flat = p.reshape(-1, 3)
        out: Array = (flat - self.displacement(flat, t)).reshape(p.shape)
        return out

    def spatial_point(self, material_point: ArrayLike, t: float) -> Array:
        """Where the material point ``X`` (3,) is at time ``t``: solves x - u(x, t) = X."""
        xm = np.asarray(material_point, dtype=np.float64).reshape(1, 3)
        x = xm.copy()
        for _ in range(20):
            x_new = xm + self.displacement(x, t)
            if float(np.max(np.abs(x_new - x))) < 1e-6:
                x = x_new
                break
            x = x_new
        out: Array = x[0]
        return out

    # --- labels ---------------------------------------------------------------------------
    def labels_at(self, points: ArrayLike, t: float) -> NDArray[np.int8]:
        """Tissue label of each spatial point at time ``t``.

        Parameters
        ----------
        points : array-like, shape (..., 3)
            Points in the anatomy frame (mm).
        t : float
            Time (s); sets the cardiac and respiratory phase.

        Returns
        -------
        labels : ndarray of int8, shape (...)
            :class:`Tissue` values.
        """
        p = check_finite(points, "points", "mm")
        if p.ndim == 0 or p.shape[-1] != 3:
            raise ShapeError(f"points must have shape (..., 3) in mm, got {p.shape}")
        flat = p.reshape(-1, 3)
        return self.labels_of_material(self.material_points(flat, t), t).reshape(p.shape[:-1])

    def labels_of_material(self, material: Array, t: float) -> NDArray[np.int8]:
        """Labels of material points ``material`` (N, 3) (no validation; hot path)."""
        n = material.shape[0]
        lab = np.full(n, int(Tissue.SURROUNDING), dtype=np.int8)
        reach = 0.0 if self.pericardium_mm is None else self.pericardium_gap_mm
        reach += (self.pericardium_mm or 0.0) + 4.0 * _SMOOTH_UNION_MM
        dists = [ch.sdf(material, beyond_mm=ch.wall_mm + reach) for ch in self.chambers]
        if self.pericardium_mm is not None or self.lungs:
            # Smooth union of the epicardial surfaces: d = -k log sum exp(-d_i / k)
            k = _SMOOTH_UNION_MM
            acc = np.zeros(n)
            for ch, d in zip(self.chambers, dists, strict=True):
                acc += np.exp(-(d - ch.wall_mm) / k)
            envelope = -k * np.log(np.maximum(acc, 1e-300))
            outer = self.pericardium_gap_mm + (self.pericardium_mm or 0.0)
            for lung in self.lungs:
                lab[lung.contains(material) & (envelope > outer + _MEDIASTINUM_MM)] = int(
                    lung.label
                )
            if self.pericardium_mm is not None:
                shell = (envelope > self.pericardium_gap_mm) & (envelope <= outer)
                lab[shell] = int(Tissue.PERICARDIUM)
        for ch, d in zip(self.chambers, dists, strict=True):
            lab[d < ch.wall_mm] = int(Tissue.MYOCARDIUM)
        for ch, d in zip(self.chambers, dists, strict=True):
            lab[d < 0.0] = int(ch.blood)
        vessel_d = [v.sdf(material) for v in self.vessels]
        for v, d in zip(self.vessels, vessel_d, strict=True):
            if v.wall_mm > 0.0:
                wall = (d < v.wall_mm) & (d >= 0.0) & (lab != int(Tissue.RA_BLOOD))
                lab[wall] = int(Tissue.VESSEL_WALL)
        for v, d in zip(self.vessels, vessel_d, strict=True):
            lab[d < 0.0] = int(v.blood)
        # interatrial septum: a disc slab
        rel = material - self.septum_centre
        h = rel @ self.septum_normal
        r2 = np.einsum("ij,ij->i", rel, rel) - h * h
        lab[(np.abs(h) < 0.5 * self.septum_mm) & (r2 < self.septum_radius_mm**2)] = int(
            Tissue.SEPTUM
        )
        phase = self.cardiac_phase(t)
        for valve in self.valves:
            self._paint_valve(valve, material, lab, _plateau(phase, *valve.open_phase))
        for inclusion in self.inclusions:
            lab[inclusion.contains(material)] = int(inclusion.label)
        return lab

    def _paint_valve(self, valve: Valve, material: Array, lab: NDArray[np.int8], op: float) -> None:
        c = np.asarray(valve.centre)
        rel_all = material - c
        reach = max(valve.radius_mm + valve.ring_mm, _ORIFICE_HALF_MM) * 1.5
        near = np.flatnonzero(np.einsum("ij,ij->i", rel_all, rel_all) < reach * reach)
        if near.size == 0:
            return
        rel = rel_all[near]
        frame = self._valve_frames[valve.name]
        e1, e2, n = frame[:, 0], frame[:, 1], frame[:, 2]
        r = valve.radius_mm
        h = rel @ n
        radial = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - h * h, 0.0))
        # orifice: blood through the walls within the annulus, a few mm either side
        orifice = (radial < r) & (np.abs(h) < _ORIFICE_HALF_MM)
        sub = lab[near]
        sub[orifice & (h < 0.0)] = int(valve.upstream)
        sub[orifice & (h >= 0.0)] = int(valve.downstream)
        lab[near] = sub
        # annulus: torus of major radius r in the valve plane
        hit = (radial - r) ** 2 + h * h < valve.ring_mm**2
        beta = op * valve.max_open_rad
        for k in range(valve.n_leaflets):
            ang = 2.0 * math.pi * k / valve.n_leaflets
            radial_dir = math.cos(ang) * e1 + math.sin(ang) * e2
            inward = -radial_dir
            width_dir = np.cross(n, inward)
            d = math.cos(beta) * inward + math.sin(beta) * n
            m = np.cross(d, width_dir)
            lr = rel - r * radial_dir  # relative to the hinge
            a = lr @ d
            b = np.abs(lr @ width_dir)
            cc = np.abs(lr @ m)
            along = np.clip(a, 0.0, r)
            half = np.sqrt(np.maximum(r * r - (r - along) ** 2, 0.0))
            if valve.n_leaflets == 3:
                half = np.minimum(half, (r - along) * math.tan(math.pi / 3.0) + valve.leaflet_mm)
            hit |= (a >= 0.0) & (a <= r) & (b <= half) & (cc <= 0.5 * valve.leaflet_mm)
        lab[near[hit]] = int(valve.label)

    # --- echogenicity and ROIs ------------------------------------------------------------
    @staticmethod
    def echogenicity(labels: ArrayLike) -> Array:
        """Backscatter amplitude of each label (same shape as ``labels``)."""
        table = np.zeros(max(int(t) for t in Tissue) + 1)
        for tissue, value in ECHOGENICITY.items():
            table[int(tissue)] = value
        out: Array = table[np.asarray(labels, dtype=np.intp)]
        return out

    @property
    def roi_names(self) -> tuple[str, ...]:
        """Names of the ROIs :meth:`roi_centroid` knows."""
        return tuple(sorted(v.name for v in self.valves)) + ("interatrial_septum",)

    def roi_centroid(self, name: str, t: float) -> Array:
        """Centre (3,) of the named structure at time ``t`` (s), anatomy frame (mm).

        ``name`` is one of :attr:`roi_names` (valve annulus centres and the septum centre).
        """
        if name == "interatrial_septum":
            ref = self.septum_centre
        else:
            ref = np.asarray(self._valve(name).centre, dtype=np.float64)
        return self.spatial_point(ref, t)

    def chamber(self, name: str) -> Chamber:
        """The chamber called ``name``."""
        for c in self.chambers:
            if c.name == name:
                return c
        raise ConfigurationError(
            f"unknown chamber {name!r}; known: {[c.name for c in self.chambers]}"
        )

    def landmarks(self) -> tuple[Landmark, ...]:
        """Labelled anchor points of the chambers, vessels, valves and septum (anatomy frame).

        Chambers: the cavity centre; vessels: the lumen's midpoint (the venae cavae: 15 mm
        from their atrial end); valves: the annulus centre; the septum: its centre.
        """
        out: list[Landmark] = []
        for c in self.chambers:
            out.append(self._landmark(c.name, c.centre))
        for v in self.vessels:
            a, b = np.asarray(v.start), np.asarray(v.end)
            if v.name == "ivc":
                p = b - 15.0 * _unit(b - a)
            elif v.name == "svc":
                p = a + 15.0 * _unit(b - a)
            else:
                p = 0.5 * (a + b)
            out.append(self._landmark(v.name, p))
        out.append(self._landmark("interatrial_septum", self.septum_centre))
        for valve in self.valves:
            out.append(self._landmark(valve.name, valve.centre))
        return tuple(out)

    @staticmethod
    def _landmark(key: str, point: ArrayLike) -> Landmark:
        label, name = _LANDMARK_NAMES.get(key, (key.upper(), key.replace("_", " ")))
        p = np.asarray(point, dtype=np.float64)
        return Landmark(key, label, name, (float(p[0]), float(p[1]), float(p[2])))


_RVOT_AXIS = (0.45, 0.3, 0.84)
_PV_CENTRE = (45.0, -30.0, 48.0)
_PA_END = (60.75, -3.0, 80.4)  # 45 mm from the pulmonary valve along (0.35, 0.6, 0.72)


def default_phantom(motion: CardiacMotion | None = None) -> HeartPhantom:
    """The default adult heart (dimensions and sources in ``docs/imaging.md``)."""
    lv_axis = (0.5, -0.55, -0.65)
    chambers = (
        Chamber("rv", (24.0, -46.0, -4.0), (34.0, 20.0, 36.0), 4.0, Tissue.RV_BLOOD),
        Chamber("rvot", (36.0, -38.0, 26.0), (11.0, 11.0, 22.0), 3.0, Tissue.RV_BLOOD, _RVOT_AXIS),
        Chamber("lv", (68.0, -17.0, -13.0), (24.0, 24.0, 42.0), 9.0, Tissue.LV_BLOOD, lv_axis),
        Chamber("ra", (0.0, 0.0, 26.0), (20.0, 21.0, 26.0), 2.5, Tissue.RA_BLOOD),
        Chamber("la", (43.0, 14.0, 30.0), (22.0, 18.0, 20.0), 2.5, Tissue.LA_BLOOD),
    )
    av_normal = (-0.45, -0.45, 0.77)  # root angulation ~40 deg
    av_centre = (30.0, -10.0, 30.0)
    avn = _unit(av_normal)
    ac = np.asarray(av_centre)
    vessels = (
        BloodVessel("ivc", (0.0, 3.0, -70.0), (0.0, 3.0, 4.0), 11.0, 1.5, Tissue.CAVA_BLOOD),
        BloodVessel("svc", (0.0, 4.0, 44.0), (0.0, 4.0, 140.0), 9.5, 1.5, Tissue.CAVA_BLOOD),
        BloodVessel(
            "aorta",
            tuple(ac.tolist()),
            tuple((ac + 60.0 * avn).tolist()),
            14.0,
            2.5,
            Tissue.AORTA_BLOOD,
        ),
        BloodVessel(
            "lvot",
            (50.0, -16.0, 6.0),  # in the LV cavity, anterior to the mitral valve
            tuple(ac.tolist()),
            10.5,
            0.0,
            Tissue.LV_BLOOD,
        ),
        BloodVessel("pa", _PV_CENTRE, _PA_END, 12.0, 1.5, Tissue.PA_BLOOD),
    )
    valves = (
        Valve(
            "tricuspid_valve",
            (10.0, -17.0, 12.0),
            (0.35, -0.8, -0.45),
            14.0,
            2,
            (0.42, 0.98),
            Tissue.TRICUSPID_VALVE,
            Tissue.RA_BLOOD,
            Tissue.RV_BLOOD,
        ),
        Valve(
            "mitral_valve",
            (48.0, 5.0, 13.0),
            lv_axis,
            14.0,
            2,
            (0.42, 0.98),
            Tissue.MITRAL_VALVE,
            Tissue.LA_BLOOD,
            Tissue.LV_BLOOD,
        ),
        Valve(
            "aortic_valve",
            av_centre,
            av_normal,
            11.5,
            3,
            (0.06, 0.36),
            Tissue.AORTIC_VALVE,
            Tissue.LV_BLOOD,
            Tissue.AORTA_BLOOD,
        ),
    )
    lungs = (
        Region("right_lung", (-62.0, 15.0, 30.0), (40.0, 70.0, 95.0), Tissue.LUNG),
        Region("left_lung", (115.0, 25.0, 20.0), (45.0, 75.0, 90.0), Tissue.LUNG),
    )
    return HeartPhantom(chambers, vessels, valves, motion=motion, pericardium_mm=2.0, lungs=lungs)


def tip2anatomy(
    q: ArrayLike,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    base2anatomy: ArrayLike = BASE2ANATOMY,
) -> Array:
    """Pose of the image centre frame in the anatomy frame for model joint state ``q``.

    Parameters
    ----------
    q : array-like, shape (4,) or (..., 4)
        Model joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm).

    Returns
    -------
    ndarray, shape (4, 4) or (..., 4, 4)
        ``base2anatomy @ forward(q)`` (mm).
    """
    out: Array = np.asarray(base2anatomy, dtype=np.float64) @ forward(q, geometry)
    return out
