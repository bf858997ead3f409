"""Shapes of the heart phantom: ellipsoidal chambers, cylindrical vessels, valves, regions,
and the labelled landmarks and patient directions of the anatomy frame (mm, LPS)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_positive
from icenav.errors import ConfigurationError
from icenav.sim.anatomy.tissue import Tissue

__all__ = [
    "BloodVessel",
    "Chamber",
    "Landmark",
    "PATIENT_DIRECTIONS",
    "Region",
    "Valve",
]


def _unit(v: ArrayLike) -> Array:
    a = np.asarray(v, dtype=np.float64)
    n = float(np.linalg.norm(a))
    if n == 0.0:
        raise ConfigurationError(f"direction must be non-zero, got {a.tolist()}")
    out: Array = a / n
    return out


def _frame_from_axis(axis: Array) -> Array:
    """Rotation (3, 3) whose third column is ``axis`` (unit); columns = local x, y, z."""
    z = _unit(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


@dataclass(frozen=True)
class Chamber:
    """A heart chamber: an ellipsoid of blood inside a myocardial shell."""

    name: str
    """Chamber name (``ra``, ``rv``, ``la``, ``lv``)."""
    centre: tuple[float, float, float]
    """Centre in the anatomy frame (mm)."""
    semi_axes: tuple[float, float, float]
    """Semi-axes (mm) along the local x, y, z axes of ``long_axis``'s frame."""
    wall_mm: float
    """Wall thickness (mm)."""
    blood: Tissue
    """Label of the cavity."""
    long_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """Direction (anatomy frame) of the local z axis (the third semi-axis)."""
    rotation: Array = field(init=False, repr=False, compare=False)
    """(3, 3) local-to-anatomy rotation, derived from ``long_axis``."""
    _axis_aligned: bool = field(init=False, repr=False, compare=False)
    """Whether ``rotation`` is the identity (skips a matrix product)."""
    _centre: Array = field(init=False, repr=False, compare=False)
    """``centre`` as an array (3,) (mm): the contact solve asks :meth:`sdf` at every
    solve, its constants are made once."""
    _axes: Array = field(init=False, repr=False, compare=False)
    """``semi_axes`` as an array (3,) (mm)."""
    _min_axis: float = field(init=False, repr=False, compare=False)
    """Smallest semi-axis (mm)."""

    def __post_init__(self) -> None:
        for a in self.semi_axes:
            check_positive(a, f"{self.name} semi-axis", "mm")
        check_positive(self.wall_mm, f"{self.name} wall_mm", "mm")
        if tuple(self.long_axis) == (0.0, 0.0, 1.0):
            rot = np.eye(3)
        else:
            rot = _frame_from_axis(np.asarray(self.long_axis))
        rot.setflags(write=False)
        object.__setattr__(self, "rotation", rot)
        object.__setattr__(self, "_axis_aligned", bool(np.array_equal(rot, np.eye(3))))
        for name, value in (("_centre", self.centre), ("_axes", self.semi_axes)):
            arr = np.asarray(value)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "_min_axis", float(np.min(self._axes)))

    def sdf(self, points: Array, *, beyond_mm: float = np.inf) -> Array:
        """Approximate signed distance (mm, negative inside) of ``points`` (N, 3).

        The bound ``k0 (k0 - 1) / k1`` (k0 = |p / a|, k1 = |p / a^2|) is exact on the
        surface. Points certainly farther than ``beyond_mm`` get ``beyond_mm`` (cheap).
        """
        local = points - self._centre
        if not self._axis_aligned:
            local = local @ self.rotation
        a = self._axes
        a_min = self._min_axis
        scaled = local / a
        k0 = np.sqrt(np.einsum("ij,ij->i", scaled, scaled))
        # sdf >= (k0 - 1) min(a): only points below the bound need the full formula
        below = (k0 - 1.0) * a_min < beyond_mm
        if beyond_mm == np.inf:
            # no bound (the contact solve's few points): every point, no subset copies
            s2 = scaled / a
            k1 = np.sqrt(np.einsum("ij,ij->i", s2, s2))
            safe = k1 > 1e-9
            full: Array = np.where(safe, k0 * (k0 - 1.0) / np.where(safe, k1, 1.0), -a_min)
            if not below.all():  # not finite
                full[~below] = beyond_mm
            return full
        out: Array = np.full(k0.shape, float(beyond_mm))
        near = np.flatnonzero(below)
        k0n = k0[near]
        s2 = scaled[near] / a
        k1 = np.sqrt(np.einsum("ij,ij->i", s2, s2))
        safe = k1 > 1e-9
        out[near] = np.where(safe, k0n * (k0n - 1.0) / np.where(safe, k1, 1.0), -a_min)
        return out


@dataclass(frozen=True)
class BloodVessel:
    """A straight vessel: a finite cylinder of blood with a wall."""

    name: str
    """Vessel name (``ivc``, ``svc``, ``aorta``, ``lvot``)."""
    start: tuple[float, float, float]
    """Centre of one end (anatomy frame, mm)."""
    end: tuple[float, float, float]
    """Centre of the other end (anatomy frame, mm)."""
    radius_mm: float
    """Lumen radius (mm)."""
    wall_mm: float
    """Wall thickness (mm); 0 for a lumen without wall (an outflow tract)."""
    blood: Tissue
    """Label of the lumen."""
    _start: Array = field(init=False, repr=False, compare=False)
    """``start`` as an array (3,) (mm): the constants of :meth:`sdf`, made once."""
    _axis: Array = field(init=False, repr=False, compare=False)
    """Unit axis (3,) from ``start`` to ``end``."""
    _length: float = field(init=False, repr=False, compare=False)
    """Length (mm)."""

    def __post_init__(self) -> None:
        a = np.asarray(self.start)
        ax = np.asarray(self.end) - a
        length = float(np.linalg.norm(ax))
        ax = ax / length
        a.setflags(write=False)
        ax.setflags(write=False)
        object.__setattr__(self, "_start", a)
        object.__setattr__(self, "_axis", ax)
        object.__setattr__(self, "_length", length)

    def sdf(self, points: Array) -> Array:
        """Signed distance (mm) to the lumen of the capped cylinder, for ``points`` (N, 3)."""
        a, ax, length = self._start, self._axis, self._length
        rel = points - a
        s = rel @ ax
        radial = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - s * s, 0.0))
        d_rad = radial - self.radius_mm
        d_ax = np.abs(s - 0.5 * length) - 0.5 * length
        out: Array = np.maximum(d_rad, d_ax)
        return out


@dataclass(frozen=True)
class Valve:
    """A valve: an annulus ring in a plane and hinged leaflets that open downstream."""

    name: str
    """ROI name (``tricuspid_valve``, ``mitral_valve``, ``aortic_valve``)."""
    centre: tuple[float, float, float]
    """Annulus centre (anatomy frame, mm)."""
    normal: tuple[float, float, float]
    """Direction of forward flow through the valve (anatomy frame, unit after normalising)."""
    radius_mm: float
    """Annulus radius (mm)."""
    n_leaflets: int
    """2 (tricuspid and mitral are modelled as two main leaflets) or 3 (aortic cusps)."""
    open_phase: tuple[float, float]
    """Cardiac phases (fraction of the beat, 0 = R wave) at which it opens and closes."""
    label: Tissue
    """Label of annulus and leaflets."""
    upstream: Tissue
    """Blood label on the inflow side (the orifice is cut through the walls)."""
    downstream: Tissue
    """Blood label on the outflow side."""
    leaflet_mm: float = 1.6
    """Leaflet thickness (mm)."""
    ring_mm: float = 1.6
    """Minor radius of the annulus ring (mm)."""
    max_open_rad: float = math.radians(75.0)
    """Leaflet swing from the annulus plane when fully open (rad)."""

    def __post_init__(self) -> None:
        check_positive(self.radius_mm, f"{self.name} radius_mm", "mm")
        if self.n_leaflets not in (2, 3):
            raise ConfigurationError(
                f"{self.name}: n_leaflets must be 2 or 3, got {self.n_leaflets}"
            )


@dataclass(frozen=True)
class Region:
    """A solid ellipsoid of one tissue (a lung, a calcified nodule)."""

    name: str
    """Region name (``right_lung``, ``nodule``)."""
    centre: tuple[float, float, float]
    """Centre in the anatomy frame (mm)."""
    semi_axes: tuple[float, float, float]
    """Semi-axes along the anatomy x, y, z axes (mm)."""
    label: Tissue
    """Tissue of the region."""

    def __post_init__(self) -> None:
        for a in self.semi_axes:
            check_positive(a, f"{self.name} semi-axis", "mm")

    def contains(self, points: Array) -> NDArray[np.bool_]:
        """Whether each of ``points`` (N, 3) lies inside."""
        scaled = (points - np.asarray(self.centre)) / np.asarray(self.semi_axes)
        out: NDArray[np.bool_] = np.einsum("ij,ij->i", scaled, scaled) < 1.0
        return out


@dataclass(frozen=True)
class Landmark:
    """A labelled anchor point of a structure (for a 3-D scene's labels)."""

    key: str
    """Structure key (``ra``, ``tricuspid_valve``, ``interatrial_septum``...)."""
    label: str
    """Short label a clinician reads (``RA``, ``TV``, ``IAS``...)."""
    name: str
    """Full name (``right atrium``)."""
    point: tuple[float, float, float]
    """Anchor point (end-diastole, end-expiration; anatomy frame unless stated, mm)."""


PATIENT_DIRECTIONS: dict[str, tuple[float, float, float]] = {
    "L": (1.0, 0.0, 0.0),
    "R": (-1.0, 0.0, 0.0),
    "P": (0.0, 1.0, 0.0),
    "A": (0.0, -1.0, 0.0),
    "S": (0.0, 0.0, 1.0),
    "I": (0.0, 0.0, -1.0),
}
"""Orientation convention: patient directions (left, right, posterior, anterior, superior,
inferior) as unit vectors of the anatomy frame (LPS)."""

_LANDMARK_NAMES: dict[str, tuple[str, str]] = {
    "ra": ("RA", "right atrium"),
    "rv": ("RV", "right ventricle"),
    "rvot": ("RVOT", "right ventricular outflow tract"),
    "la": ("LA", "left atrium"),
    "lv": ("LV", "left ventricle"),
    "ivc": ("IVC", "inferior vena cava"),
    "svc": ("SVC", "superior vena cava"),
    "aorta": ("Ao", "aorta"),
    "lvot": ("LVOT", "left ventricular outflow tract"),
    "pa": ("PA", "pulmonary artery"),
    "interatrial_septum": ("IAS", "interatrial septum"),
    "tricuspid_valve": ("TV", "tricuspid valve"),
    "mitral_valve": ("MV", "mitral valve"),
    "aortic_valve": ("AV", "aortic valve"),
}
