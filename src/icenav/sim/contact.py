"""Contact between the catheter and the anatomy, and the drag of the blood flow.

The catheter's bending section and its rigid transducer housing live inside the blood of
the inferior vena cava (IVC), the right atrium (RA) and the superior vena cava (SVC); the
walls move with the heart beat and with breathing (the phantom's displacement field).
Equations as in ``docs/digital-twin.md``, section 9:

* (C1) Shape: the free catheter is the constant-curvature arc that ends at the plant's tip
  pose (start tangent: base z), nodes ``P_i`` at arc lengths ``s_i`` along it, then the
  rigid housing along the tip axis.
* (C2) Walls: ``phi(x, t) = min(sdf_RA, sdf_IVC, sdf_SVC)(X)``, ``X = x - u(x, t)`` (the
  material point, so walls move as the heart does); penetration of node ``i``
  ``p_i = phi(P_i, t) + r_c``; the outward normal ``n_i = grad phi``.
* (C3) Compliance of the curved, linearly elastic section (small deflection, the housing
  rigid): a load ``F_j`` at ``P_j`` turns the section at arc length
  ``sigma < min(s_i, s_j, L)`` by ``dTheta = K (P_j - p(sigma)) x F_j dsigma`` with
  ``K = t t^T / GJ + (I - t t^T) / EI``, which moves node ``i`` by ``dTheta x (P_i - p)``;
  the base yields sideways with compliance ``c_b``:
  ``delta_i = sum_j (C_ij + c_b (I - z z^T)) F_j``.
* (C4) Contact forces: ``f >= 0``, ``p - M f <= 0``, ``f (p - M f) = 0`` with
  ``M_ij = n_i^T C_ij n_j + delta_ij / k_wall`` (tissue indentation in series with the
  catheter's deflection): a linear complementarity problem, solved as the non-negative
  least-squares problem of the equivalent quadratic program.
* (C5) Flow drag per unit length ``q = 1/2 rho C_d d |v_perp| v_perp``: the RA's inflow
  waves over the beat (systolic venous S, early diastolic E, atrial A), along the caval axis
  (S) and through the tricuspid valve (E, A), scaled by the beat's amplitude.
* (C6) The tip moves by ``delta_tip`` and turns by ``Theta = sum_j int K (P_j - p) x F_j``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg
import scipy.optimize

from icenav._typing import Array
from icenav._validation import check_positive
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry
from icenav.sim.anatomy import HeartPhantom

__all__ = [
    "ContactForce",
    "ContactModel",
    "ContactParams",
    "ContactSolution",
    "FlowParams",
    "STRUCTURES",
    "Walls",
    "catheter_nodes",
]

STRUCTURES = ("ivc", "ra_wall", "septum", "tricuspid_annulus", "svc")
"""Structures a contact is reported on."""


@dataclass(frozen=True)
class ContactParams:
    """Mechanics of the catheter against the walls (sources in ``docs/digital-twin.md``)."""

    catheter_radius_mm: float = 1.65
    """Outer radius r_c (mm): a 10 F ICE catheter (3.3 mm)."""
    bending_stiffness_nmm2: float = 500.0
    """EI of the bending section against a lateral load (N mm^2): between the plant's AP and
    RL stiffness (340, 700) and within 430-1080 N mm^2 measured on a steerable ablation
    catheter's tip (Khoshnam et al.)."""
    torsional_stiffness_nmm2: float = 380.0
    """GJ of the section (N mm^2): EI / (1 + nu) of a polymer tube, nu about 0.3."""
    wall_stiffness_n_per_mm: float = 0.12
    """Indentation stiffness of the wall under a catheter tip (N/mm): 10 g for 0.7 mm and
    80 g for 6.9 mm in porcine myocardium (Masnok et al.), secant 0.11-0.14 N/mm."""
    housing_mm: float = 6.0
    """Rigid transducer housing beyond the image centre (mm)."""
    base_compliance_mm_per_n: float = 100.0
    """Lateral compliance of the section's base (mm/N): the shaft below it lies free in
    the IVC's lumen (about 9 mm of clearance) and yields sideways, a cantilever of some
    100 mm with the shaft's EI of about 1000 N mm^2 (about 300 mm/N) until it meets the
    opposite wall; linearised here (tuned, see the docs)."""
    n_section_nodes: int = 6
    """Contact nodes along the bending section (C1)."""
    n_segments: int = 18
    """Integration segments of the compliance (C3)."""

    def __post_init__(self) -> None:
        check_positive(self.catheter_radius_mm, "catheter_radius_mm", "mm")
        check_positive(self.bending_stiffness_nmm2, "bending_stiffness_nmm2", "N mm^2")
        check_positive(self.torsional_stiffness_nmm2, "torsional_stiffness_nmm2", "N mm^2")
        check_positive(self.wall_stiffness_n_per_mm, "wall_stiffness_n_per_mm", "N/mm")
        if not (
            math.isfinite(self.base_compliance_mm_per_n) and self.base_compliance_mm_per_n >= 0
        ):
            raise ConfigurationError(
                f"base_compliance_mm_per_n must be >= 0 mm/N, got {self.base_compliance_mm_per_n}"
            )
        if self.housing_mm < 0:
            raise ConfigurationError(f"housing_mm must be >= 0 mm, got {self.housing_mm}")
        for name in ("n_section_nodes", "n_segments"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 2 <= v <= 64:
                raise ConfigurationError(f"{name} must be an int in [2, 64], got {v!r}")


@dataclass(frozen=True)
class FlowParams:
    """Blood flow in the right atrium over the beat (C5)."""

    systolic_inflow_m_s: float = 0.2
    """Peak venous inflow along the caval axis in ventricular systole (S wave, m/s)."""
    early_filling_m_s: float = 0.25
    """Peak flow towards the tricuspid valve in early diastole (E wave, m/s): a tricuspid E
    of about 0.5 m/s, halved by the RA's larger cross-section."""
    atrial_m_s: float = 0.15
    """Peak flow towards the tricuspid valve at the atrial kick (A wave, m/s)."""
    density_kg_m3: float = 1060.0
    """Blood density (kg/m^3)."""
    drag_coefficient: float = 1.1
    """Drag coefficient of a cylinder in cross-flow at Re about 200-300."""

    def __post_init__(self) -> None:
        for name in ("systolic_inflow_m_s", "early_filling_m_s", "atrial_m_s"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or not 0.0 <= v <= 2.0:
                raise ConfigurationError(f"{name} must be in [0, 2] m/s, got {v}")
        check_positive(self.density_kg_m3, "density_kg_m3", "kg/m^3")
        check_positive(self.drag_coefficient, "drag_coefficient", "")


@dataclass(frozen=True)
class ContactForce:
    """One contact of the catheter with a wall."""

    structure: str
    """Where (one of :data:`STRUCTURES`)."""
    force_n: float
    """Normal force (N)."""
    arc_length_mm: float
    """Where along the catheter, from the base of the bending section (mm)."""


@dataclass(frozen=True)
class ContactSolution:
    """The catheter under flow and contact at one instant."""

    tip2base: Array
    """(4, 4) deflected pose of the image centre frame (mm)."""
    contacts: tuple[ContactForce, ...] = ()
    """Contacts with a force > 0."""
    deflection_mm: float = 0.0
    """How far flow and contact moved the image centre (mm)."""

    @property
    def force_n(self) -> float:
        """Total normal contact force (N)."""
        return float(sum(c.force_n for c in self.contacts))


def _skew(v: Array) -> Array:
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def _rotvec(w: Array) -> Array:
    """Rodrigues: rotation matrix (3, 3) of the rotation vector ``w`` (rad)."""
    a = float(np.linalg.norm(w))
    if a < 1e-12:
        return np.eye(3) + _skew(w)
    k = _skew(w / a)
    return np.eye(3) + math.sin(a) * k + (1.0 - math.cos(a)) * (k @ k)


def catheter_nodes(
    tip2base: Array, s_mm: Array, geometry: CatheterGeometry = DEFAULT_GEOMETRY
) -> tuple[Array, Array]:
    """Points and tangents of the free catheter (C1) at arc lengths ``s_mm`` from the base
    of the bending section; beyond ``L`` along the rigid tip axis.

    Parameters
    ----------
    tip2base : ndarray, shape (..., 4, 4)
        Pose of the image centre frame (mm, base frame).
    s_mm : ndarray, shape (n,)
        Arc lengths (mm), ``0 <= s``.

    Returns
    -------
    points, tangents : ndarrays, shape (..., n, 3)
        In the base frame (mm; unit tangents).
    """
    t = np.asarray(tip2base, np.float64)
    s = np.asarray(s_mm, np.float64)
    L = geometry.bending_length
    z = t[..., :3, 2]
    end = t[..., :3, 3] - geometry.us_offset * z
    alpha = np.arccos(np.clip(z[..., 2], -1.0, 1.0))  # bend from base z
    lateral = np.hypot(z[..., 0], z[..., 1])
    safe = np.where(lateral > 1e-12, lateral, 1.0)
    bx = np.where(lateral > 1e-12, z[..., 0] / safe, 1.0)
    by = np.where(lateral > 1e-12, z[..., 1] / safe, 0.0)
    kappa = (alpha / L)[..., None]  # (..., 1)
    sf = np.minimum(s, L)  # (n,)
    a = kappa * sf  # (..., n)
    small = np.abs(a) < 1e-4
    sa = np.where(small, 1.0, a)
    s1 = np.where(small, 1.0 - a * a / 6.0, np.sin(sa) / sa)
    c2 = np.where(small, 0.5 - a * a / 24.0, (1.0 - np.cos(sa)) / (sa * sa))
    lat = sf * sf * kappa * c2  # r (1 - cos(kappa s))
    ax = sf * s1  # r sin(kappa s)
    aL = alpha[..., None]
    smallL = np.abs(aL) < 1e-4
    saL = np.where(smallL, 1.0, aL)
    latL = np.where(smallL, L * aL / 2.0, L * (1.0 - np.cos(saL)) / saL)
    axL = np.where(smallL, L * (1.0 - aL * aL / 6.0), L * np.sin(saL) / saL)
    base = end - latL * np.stack([bx, by, np.zeros_like(bx)], -1) - axL * np.array([0.0, 0, 1])
    b = np.stack([bx, by, np.zeros_like(bx)], -1)[..., None, :]  # (..., 1, 3)
    ez = np.array([0.0, 0.0, 1.0])
    pts = base[..., None, :] + lat[..., None] * b + ax[..., None] * ez
    tan = np.sin(a)[..., None] * b + np.cos(a)[..., None] * ez
    beyond = np.maximum(s - L, 0.0)  # rigid part along the tip axis
    pts = pts + beyond[:, None] * z[..., None, :]
    return pts, tan


_NORMAL_STEP_MM = 0.25
"""Step of the central differences of the walls' normals (mm)."""
_NORMAL_PROBES = np.concatenate([np.eye(3), -np.eye(3)]) * _NORMAL_STEP_MM
"""(6, 3) offsets of the probes of a normal: +h and -h along each axis (mm)."""
_NORMAL_PROBES.setflags(write=False)


class Walls:
    """The walls around the catheter (C2): blood of the RA, IVC and SVC, moving with the
    phantom's displacement field.

    Parameters
    ----------
    phantom : HeartPhantom
        Uses its chamber ``ra``, vessels ``ivc`` and ``svc``, the septum and the tricuspid
        valve (public attributes only).
    base2anatomy : ndarray, shape (4, 4)
        Registration of the robot base in the anatomy frame.
    """

    _NAMES = ("ra_wall", "ivc", "svc")

    def __init__(self, phantom: HeartPhantom, base2anatomy: Array) -> None:
        self.phantom = phantom
        self.base2anatomy = np.asarray(base2anatomy, np.float64)
        self._rot = self.base2anatomy[:3, :3]
        self._shapes: tuple[Any, ...] = (
            phantom.chamber("ra"),
            *(v for name in ("ivc", "svc") for v in phantom.vessels if v.name == name),
        )
        if len(self._shapes) != 3:
            raise ConfigurationError("the phantom needs an 'ra' chamber and 'ivc', 'svc' vessels")
        self._septum_c = np.asarray(phantom.septum_centre, np.float64)
        self._septum_n = np.asarray(phantom.septum_normal, np.float64)
        self._septum_r = float(phantom.septum_radius_mm)
        tv = [v for v in phantom.valves if v.name == "tricuspid_valve"]
        self._tv = (np.asarray(tv[0].centre), float(tv[0].radius_mm)) if tv else None

    def sdf_material(self, material: Array) -> tuple[Array, Array]:
        """Union signed distance (N,) of material points (N, 3) (mm, negative in blood) and
        the index (N,) of the nearest shape (0 RA, 1 IVC, 2 SVC)."""
        ra, ivc, svc = self._shapes
        d = np.stack([ra.sdf(material), ivc.sdf(material), svc.sdf(material)])
        idx = np.argmin(d, axis=0)
        out: Array = d[idx, np.arange(d.shape[1])]
        return out, idx

    def to_material(self, points_in_base: Array, t: float) -> Array:
        """Material points (N, 3) of spatial points given in the base frame at time ``t``."""
        x = points_in_base @ self._rot.T + self.base2anatomy[:3, 3]
        return self.phantom.material_points(x, t)

    def distance(self, points_in_base: Array, t: float) -> tuple[Array, Array, Array]:
        """Signed distance (N,) (mm) to the walls, the shape index (N,) and the material
        points (N, 3) of points (N, 3) given in the base frame at time ``t`` (C2)."""
        mat = self.to_material(points_in_base, t)
        d, idx = self.sdf_material(mat)
        return d, idx, mat

    def normals(self, material: Array) -> Array:
        """Outward unit normals (N, 3) of the walls at material points (N, 3), in the base
        frame (central differences of the union distance; the walls' small strain is
        neglected); zero where the distance has no slope."""
        h = _NORMAL_STEP_MM
        probe = (material[:, None, :] + _NORMAL_PROBES[None]).reshape(-1, 3)
        dp, _ = self.sdf_material(probe)
        dp = dp.reshape(-1, 6)
        g = (dp[:, :3] - dp[:, 3:]) / (2 * h)
        norm = np.linalg.norm(g, axis=1, keepdims=True)
        g = np.where(norm > 1e-9, g / np.maximum(norm, 1e-12), 0.0)
        out: Array = g @ self._rot  # anatomy -> base
        return out

    def query(self, points_in_base: Array, t: float) -> tuple[Array, Array, Array]:
        """Signed distance (N,), outward normal (N, 3) in the base frame and shape index (N,)
        of points (N, 3) in the base frame at time ``t``."""
        d, idx, mat = self.distance(points_in_base, t)
        return d, self.normals(mat), idx

    def structure(self, material_point: Array, shape_index: int) -> str:
        """Name (:data:`STRUCTURES`) of the wall at a material point next to shape
        ``shape_index``."""
        if shape_index == 1:
            return "ivc"
        if shape_index == 2:
            return "svc"
        rel = material_point - self._septum_c
        h = float(rel @ self._septum_n)
        if abs(h) < 8.0 and float(rel @ rel) - h * h < self._septum_r**2:
            return "septum"
        if self._tv is not None and float(np.linalg.norm(material_point - self._tv[0])) < (
            self._tv[1] + 5.0
        ):
            return "tricuspid_annulus"
        return "ra_wall"


def _bump(phase: float, start: float, end: float) -> float:
    """Raised-cosine bump over [start, end] of the beat (0 outside)."""
    if not start <= phase <= end:
        return 0.0
    return 0.5 * (1.0 - math.cos(2.0 * math.pi * (phase - start) / (end - start)))


_LATERAL = np.diag([1.0, 1.0, 0.0])
"""Sideways in the base frame: the directions the base yields in."""


@dataclass
class _Shape:
    """The free catheter's nodes and compliance in one pose (in the plant's base frame)."""

    s: Array
    """(n,) arc lengths of the nodes (mm)."""
    points: Array
    """(n, 3) node positions (mm)."""
    tangents: Array
    """(n, 3) unit tangents."""
    lever: Array
    """(n, m, 3, 3): cross-product matrices of node minus segment position, zero where the
    segment lies beyond the node (C3)."""
    turn: Array
    """(n, m, 3, 3): the section's turn at each segment per unit load at each node (C3)."""
    tip_index: int
    """Index of the image centre node."""
    in_atrium: Array
    """(n,) 1 for nodes above the IVC-RA junction (where the atrial flow acts), else 0."""
    base_compliance: float = 0.0
    """Lateral compliance of the base (mm/N), added to every pair of nodes (C3)."""
    _compliance: Array | None = None
    _tip_row: Array | None = None

    @property
    def compliance(self) -> Array:
        """(n, n, 3, 3): delta_i = C_ij F_j (mm/N), Eq. (C3): C_ij = -sum_k R_ik K_k R_jk ds."""
        if self._compliance is None:
            n, m = self.lever.shape[:2]
            a = self.lever.transpose(0, 2, 1, 3).reshape(3 * n, 3 * m)
            b = self.turn.transpose(1, 2, 0, 3).reshape(3 * m, 3 * n)
            c = -(a @ b).reshape(n, 3, n, 3).transpose(0, 2, 1, 3)
            self._compliance = c + self.base_compliance * _LATERAL
        return self._compliance

    @property
    def tip_row(self) -> Array:
        """(n, 3, 3): deflection of the image centre per unit load at each node."""
        if self._compliance is not None:
            return self._compliance[self.tip_index]
        if self._tip_row is None:
            rt = self.lever[self.tip_index]  # (m, 3, 3)
            self._tip_row = -np.einsum("kab,jkbc->jac", rt, self.turn) + (
                self.base_compliance * _LATERAL
            )
        return self._tip_row

    @property
    def tip_rotation(self) -> Array:
        """(n, 3, 3): turn of the tip per unit load at each node, Eq. (C6)."""
        out: Array = self.turn.sum(axis=1)
        return out


class ContactModel:
    """Flow and contact loads on the catheter and the deflected tip pose (C1)-(C6).

    Parameters
    ----------
    walls : Walls, optional
        The moving walls; None: flow only.
    params : ContactParams
    flow : FlowParams, optional
        None: no flow drag.
    phantom : HeartPhantom, optional
        Its ``cardiac_phase`` (and ``rhythm.amplitude`` when it has a rhythm) time the flow
        waves; its tricuspid valve sets the inflow direction (default: the walls').
    base2anatomy : ndarray (4, 4), optional
        Default: the walls'.
    geometry : CatheterGeometry
    """

    def __init__(
        self,
        walls: Walls | None,
        params: ContactParams | None = None,
        flow: FlowParams | None = None,
        *,
        phantom: HeartPhantom | None = None,
        base2anatomy: Array | None = None,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    ) -> None:
        self.walls = walls
        self.params = p = params if params is not None else ContactParams()
        self.flow = flow
        self.geometry = geometry
        L = geometry.bending_length
        self._s = np.concatenate(
            [
                L * np.arange(1, p.n_section_nodes + 1) / p.n_section_nodes,
                [L + geometry.us_offset, L + geometry.us_offset + p.housing_mm],
            ]
        )
        self._tip_index = p.n_section_nodes
        m = p.n_segments
        self._sigma = (np.arange(m) + 0.5) * L / m
        self._ds = L / m
        self._s_all = np.concatenate([self._s, self._sigma])
        self._mask = (self._sigma[None, :] < np.minimum(self._s, L)[:, None]).astype(np.float64)
        ph = phantom if phantom is not None else (walls.phantom if walls is not None else None)
        b2a = base2anatomy if base2anatomy is not None else (
            walls.base2anatomy if walls is not None else None
        )  # fmt: skip
        self._phantom = ph
        self._b2a = None if b2a is None else np.asarray(b2a, np.float64)
        self._flow_dirs: tuple[Array, Array] | None = None
        if flow is not None:
            if ph is None or self._b2a is None:
                raise ConfigurationError("flow drag needs the phantom and base2anatomy")
            rot = self._b2a[:3, :3]
            caval = np.array([0.0, 0.0, 1.0])  # up the IVC into the RA (anatomy z)
            tv = [v for v in ph.valves if v.name == "tricuspid_valve"]
            inflow = np.asarray(tv[0].normal, np.float64) if tv else caval
            inflow = inflow / np.linalg.norm(inflow)
            self._flow_dirs = (caval @ rot, inflow @ rot)  # anatomy -> base

    def set_registration(self, base2anatomy: Array) -> None:
        """Move the anatomy relative to the base by a translation (a patient shift): the
        walls and the atrium's entry plane follow (the flow directions, set by the rotation,
        stay)."""
        b2a = np.asarray(base2anatomy, np.float64)
        if b2a.shape != (4, 4):
            raise ConfigurationError(f"base2anatomy must have shape (4, 4), got {b2a.shape}")
        old = self._b2a if self._b2a is not None else (
            self.walls.base2anatomy if self.walls is not None else None
        )  # fmt: skip
        if old is not None and not np.allclose(old[:3, :3], b2a[:3, :3], atol=1e-12):
            raise ConfigurationError("a patient shift is a translation: the rotation must stay")
        if self.walls is not None:
            self.walls.base2anatomy = b2a.copy()
            self.walls._rot = self.walls.base2anatomy[:3, :3]  # noqa: SLF001 - same module
        if self._b2a is not None:
            self._b2a = b2a.copy()

    # --- shape and compliance ---------------------------------------------------------------

    def shape(self, tip2base: Array) -> _Shape:
        """Nodes (C1) and compliance (C3) of the free catheter ending at ``tip2base``."""
        p = self.params
        L = self.geometry.bending_length
        n = len(self._s)
        pts_all, tan_all = catheter_nodes(tip2base, self._s_all, self.geometry)
        pts, tan = pts_all[:n], tan_all[:n]
        sig_p, sig_t = pts_all[n:], tan_all[n:]
        tt = sig_t[:, :, None] * sig_t[:, None, :]
        K = tt / p.torsional_stiffness_nmm2 + (np.eye(3) - tt) / p.bending_stiffness_nmm2
        R = _skew(pts[:, None, :] - sig_p[None, :, :]) * self._mask[..., None, None]
        KR = np.matmul(K[None], R) * self._ds  # dTheta_k per unit load at node j
        inside = np.ones(n)
        if self._b2a is not None:
            inside = ((pts @ self._b2a[2, :3] + self._b2a[2, 3]) > 0.0).astype(np.float64)
        del L
        return _Shape(self._s, pts, tan, R, KR, self._tip_index, inside, p.base_compliance_mm_per_n)

    # --- loads ------------------------------------------------------------------------------

    def flow_speed(self, t: float) -> tuple[float, int]:
        """Speed (m/s) of the atrial flow at time ``t`` and which wave (0 caval, 1 tricuspid
        inflow) (C5)."""
        if self.flow is None or self._phantom is None:
            return 0.0, 0
        f = self.flow
        ph = self._phantom
        phase = float(ph.cardiac_phase(t))
        rhythm = getattr(ph, "rhythm", None)
        amp = float(rhythm.amplitude(t)) if rhythm is not None else 1.0
        s = f.systolic_inflow_m_s * _bump(phase, 0.05, 0.40)
        if s > 0.0:
            return amp * s, 0
        e = f.early_filling_m_s * _bump(phase, 0.45, 0.70) + f.atrial_m_s * _bump(phase, 0.82, 0.98)
        return amp * e, 1

    def flow_loads(self, shape: _Shape, t: float, frame2base: Array | None = None) -> Array | None:
        """Nodal drag loads (n, 3) (N, in the shape's frame) at time ``t`` (C5); None when
        there is no flow then. ``frame2base`` (4, 4) places the shape's frame in the base."""
        speed, wave = self.flow_speed(t)
        if speed == 0.0 or self._flow_dirs is None or self.flow is None:
            return None
        direction = self._flow_dirs[wave]
        if frame2base is not None:
            direction = direction @ np.asarray(frame2base)[:3, :3]  # base -> shape frame
        v = speed * direction
        tan = shape.tangents
        v_perp = v[None, :] - (tan @ v)[:, None] * tan  # (n, 3) m/s
        mag = np.sqrt(np.einsum("ij,ij->i", v_perp, v_perp))
        d_m = 2.0 * self.params.catheter_radius_mm * 1e-3
        k = 0.5 * self.flow.density_kg_m3 * self.flow.drag_coefficient * d_m * 1e-3  # per mm
        ell = np.diff(np.concatenate([[0.0], shape.s]))  # mm each node carries
        out: Array = (k * mag * ell * shape.in_atrium)[:, None] * v_perp  # Eq. (C5): N
        return out

    # --- solve ------------------------------------------------------------------------------

    def solve(
        self, shape: _Shape, tip2base: Array, t: float, frame2base: Array | None = None
    ) -> ContactSolution:
        """The catheter at time ``t`` under flow (C5) and contact (C4); returns the deflected
        pose (C6) in the base frame.

        ``shape`` is :meth:`shape` of ``tip2base``, both given in a frame that
        ``frame2base`` (4, 4; default identity) places in the base frame (the shaft's lost
        motion moves the whole section rigidly, so its compliance is computed once).
        """
        g = np.eye(4) if frame2base is None else np.asarray(frame2base, np.float64)
        loads = self.flow_loads(shape, t, g)
        total = np.zeros_like(shape.points) if loads is None else loads
        contacts: list[ContactForce] = []
        if self.walls is not None:
            f_n, normals, idx, mat = self._contact(shape, loads, g, t)
            if np.any(f_n > 0.0):
                total = total - f_n[:, None] * normals  # the wall pushes into the blood
                for j in np.flatnonzero(f_n > 1e-9):
                    contacts.append(
                        ContactForce(self.walls.structure(mat[j], int(idx[j])), float(f_n[j]),
                                     float(shape.s[j]))
                    )  # fmt: skip
        out = np.asarray(tip2base, np.float64).copy()
        if not np.any(total):
            return ContactSolution(g @ out)
        delta = np.einsum("jab,jb->a", shape.tip_row, total)  # Eq. (C6)
        theta = np.einsum("jab,jb->a", shape.tip_rotation, total)
        out[:3, :3] = _rotvec(theta) @ out[:3, :3]
        out[:3, 3] += delta
        return ContactSolution(g @ out, tuple(contacts), float(np.linalg.norm(delta)))

    def _contact(
        self, shape: _Shape, loads: Array | None, g: Array, t: float
    ) -> tuple[Array, Array, Array, Array]:
        """Eq. (C4): forces (n,) (N), wall normals (n, 3) in the shape frame, shape index (n,)
        and material points (n, 3) of the nodes, under the flow ``loads``."""
        assert self.walls is not None
        n = len(shape.s)
        r_c = self.params.catheter_radius_mm
        rot, off = g[:3, :3], g[:3, 3]
        f_n = np.zeros(n)
        normals = np.zeros((n, 3))
        free = shape.points
        if loads is None:
            d, idx, mat = self.walls.distance(free @ rot.T + off, t)
            if not np.any(d + r_c > -2.0):  # the flow moves a node by well under 2 mm
                return f_n, normals, idx, mat
        else:
            # the nodes of the catheter held straight and bent by the flow, in one call of
            # the walls (each row is evaluated on its own: the same numbers as two calls)
            free = free + np.einsum("ijab,jb->ia", shape.compliance, loads)
            d, idx, mat = self.walls.distance(np.concatenate([shape.points, free]) @ rot.T + off, t)
            if not np.any(d[:n] + r_c > -2.0):
                return f_n, normals, idx[:n], mat[:n]
            d, idx, mat = d[n:], idx[n:], mat[n:]
        pen = d + r_c
        cand = np.flatnonzero(pen > 0.0)
        if cand.size == 0:
            return f_n, normals, idx, mat
        normals[cand] = self.walls.normals(mat[cand]) @ rot  # base -> shape frame
        C = shape.compliance
        for _ in range(3):
            use = cand[np.any(normals[cand] != 0.0, axis=1)]
            f_n[:] = 0.0
            f_n[use] = self._lcp(C[np.ix_(use, use)], normals[use], pen[use])
            # a node the deflection pushed into a wall joins the problem (linearised at the
            # free shape, with the penetration the free catheter would have there)
            moved = free - np.einsum("ijab,jb->ia", C, f_n[:, None] * normals)
            d2, idx2, mat2 = self.walls.distance(moved @ rot.T + off, t)
            entered = d2 + r_c > 0.5
            entered[cand] = False
            new = np.flatnonzero(entered)  # np.setdiff1d's sorted indices, without sorting
            if new.size == 0:
                break
            idx[new], mat[new] = idx2[new], mat2[new]
            normals[new] = self.walls.normals(mat2[new]) @ rot
            pen[new] = d2[new] + r_c + np.einsum("ia,ia->i", normals[new], free[new] - moved[new])
            joined = np.zeros(n, dtype=bool)
            joined[cand] = True
            joined[new] = True
            cand = np.flatnonzero(joined)  # np.union1d's sorted indices
        return f_n, normals, idx, mat

    def _lcp(self, C: Array, normals: Array, pen: Array) -> Array:
        """Eq. (C4): non-negative normal forces (N) at nodes with compliance ``C`` (c, c, 3,
        3), wall normals (c, 3) and free penetrations (c,) (mm)."""
        if len(pen) == 0 or not np.any(pen > 0.0):
            return np.zeros(len(pen))
        M = np.einsum("ia,ijab,jb->ij", normals, C, normals)
        M = 0.5 * (M + M.T) + np.eye(len(pen)) / self.params.wall_stiffness_n_per_mm
        # finite by construction (compliances, unit normals, penetrations of a finite
        # catheter): scipy's finiteness checks are skipped (a hot path, same results)
        low = scipy.linalg.cholesky(M, lower=True, check_finite=False)
        rhs = scipy.linalg.solve_triangular(low, pen, lower=True, check_finite=False)
        f, _ = scipy.optimize.nnls(low.T, rhs)
        out: Array = f
        return out
