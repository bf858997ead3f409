"""Patients: heart size, position and orientation relative to the robot's base, heart rate
and breathing, drawn per patient seed; and the views an operator aims at in each.

A patient changes the anatomy only through the phantom's public constructor arguments
(every structure scaled about the IVC-RA junction, the origin of the anatomy frame) and
the registration ``base2anatomy`` (the heart turned about the catheter's base and shifted),
so the renderer and the contact model see the same heart. Distributions (sources in
``docs/digital-twin.md``, section 9.6); every draw is clipped to +-2 standard deviations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icenav._typing import Array
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward
from icenav.sim.anatomy import (
    BASE2ANATOMY,
    EXAMPLE_VIEWS,
    BloodVessel,
    Chamber,
    HeartPhantom,
    Valve,
    default_phantom,
)
from icenav.sim.contact import Walls, catheter_nodes

__all__ = ["PATIENT_SD", "Patient", "aim_views"]

PATIENT_SD: dict[str, float] = {
    "heart_scale": 0.08,
    "offset_mm": 2.0,
    "rotation_deg": 4.0,
    "heart_rate_bpm": 6.0,
    "breathing_period_s": 0.4,
    "breathing_scale": 0.39,
}
"""Standard deviations of the patient draws (heart scale is a fraction; breathing scale is
Shechter et al.'s 1.9 / 4.9 mm)."""


@dataclass(frozen=True)
class Patient:
    """One patient (or phantom build): anatomy and physiology parameters."""

    seed: int | None = None
    """The seed it was drawn from (None: the nominal patient)."""
    heart_scale: float = 1.0
    """Size of every structure relative to the default phantom (scaled about the IVC-RA
    junction)."""
    offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Shift of the heart relative to the robot's base (anatomy axes, mm)."""
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Turn of the heart about the catheter's base (anatomy x, y, z; deg, applied x then y
    then z)."""
    heart_rate_bpm: float = 72.0
    """Mean heart rate (beats/min)."""
    breathing_period_s: float = 4.1
    """Mean breath duration (s)."""
    breathing_scale: float = 1.0
    """Depth of breathing relative to Shechter et al.'s mean (4.9 mm caudal)."""

    def __post_init__(self) -> None:
        if not 0.5 <= self.heart_scale <= 1.5:
            raise ConfigurationError(f"heart_scale must be in [0.5, 1.5], got {self.heart_scale}")
        if not 0.0 <= self.breathing_scale <= 3.0:
            raise ConfigurationError(
                f"breathing_scale must be in [0, 3], got {self.breathing_scale}"
            )

    @classmethod
    def nominal(cls) -> Patient:
        """The default phantom, registered as :data:`BASE2ANATOMY`."""
        return cls()

    @classmethod
    def sample(cls, seed: int) -> Patient:
        """Patient ``seed`` (>= 0): every parameter drawn around the nominal."""
        if isinstance(seed, bool) or int(seed) != seed or seed < 0:
            raise ConfigurationError(f"patient seed must be an integer >= 0, got {seed!r}")
        rng = np.random.default_rng([int(seed), 0xA7])
        sd = PATIENT_SD

        def draw(n: int = 1) -> Array:
            out: Array = np.clip(rng.standard_normal(n), -2.0, 2.0)
            return out

        return cls(
            seed=int(seed),
            heart_scale=float(1.0 + sd["heart_scale"] * draw()[0]),
            offset_mm=tuple(float(x) for x in sd["offset_mm"] * draw(3)),  # type: ignore[arg-type]
            rotation_deg=tuple(float(x) for x in sd["rotation_deg"] * draw(3)),  # type: ignore[arg-type]
            heart_rate_bpm=float(72.0 + sd["heart_rate_bpm"] * draw()[0]),
            breathing_period_s=float(4.1 + sd["breathing_period_s"] * draw()[0]),
            breathing_scale=float(1.0 + sd["breathing_scale"] * draw()[0]),
        )

    # --- anatomy -------------------------------------------------------------------------

    def heart2world(self) -> Array:
        """(4, 4) rigid placement of the heart: turned about the base, then shifted
        (anatomy frame, mm)."""
        rx, ry, rz = (math.radians(a) for a in self.rotation_deg)
        cx, sx, cy, sy, cz, sz = (math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry),
                                  math.cos(rz), math.sin(rz))  # fmt: skip
        r = (
            np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1.0]])
            @ np.array([[cy, 0, sy], [0, 1.0, 0], [-sy, 0, cy]])
            @ np.array([[1.0, 0, 0], [0, cx, -sx], [0, sx, cx]])
        )
        pivot = BASE2ANATOMY[:3, 3]
        out = np.eye(4)
        out[:3, :3] = r
        out[:3, 3] = pivot - r @ pivot + np.asarray(self.offset_mm)
        return out

    def base2anatomy(self) -> Array:
        """(4, 4) registration of the robot base in this patient's anatomy frame."""
        h = self.heart2world()
        inv = np.eye(4)
        inv[:3, :3] = h[:3, :3].T
        inv[:3, 3] = -h[:3, :3].T @ h[:3, 3]
        out: Array = inv @ BASE2ANATOMY
        return out

    def phantom(self, base: HeartPhantom | None = None) -> HeartPhantom:
        """This patient's heart: ``base`` (default phantom) scaled by :attr:`heart_scale`
        about the IVC-RA junction (wall and leaflet thickness kept)."""
        b = base if base is not None else default_phantom()
        s = self.heart_scale
        if s == 1.0:
            return b

        def sc(v: tuple[float, ...] | Array) -> tuple[float, float, float]:
            x = np.asarray(v, np.float64) * s
            return float(x[0]), float(x[1]), float(x[2])

        chambers = tuple(
            Chamber(c.name, sc(c.centre), sc(c.semi_axes), c.wall_mm, c.blood, c.long_axis)
            for c in b.chambers
        )
        vessels = tuple(
            BloodVessel(v.name, sc(v.start), sc(v.end), v.radius_mm * s, v.wall_mm, v.blood)
            for v in b.vessels
        )
        valves = tuple(
            Valve(v.name, sc(v.centre), v.normal, v.radius_mm * s, v.n_leaflets, v.open_phase,
                  v.label, v.upstream, v.downstream, v.leaflet_mm, v.ring_mm, v.max_open_rad)
            for v in b.valves
        )  # fmt: skip
        return HeartPhantom(
            chambers,
            vessels,
            valves,
            septum_centre=sc(b.septum_centre),
            septum_normal=tuple(float(x) for x in b.septum_normal),  # type: ignore[arg-type]
            septum_radius_mm=b.septum_radius_mm * s,
            septum_mm=b.septum_mm,
            motion=b.motion,
        )


def aim_views(
    phantom: HeartPhantom,
    base2anatomy: Array,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    *,
    clearance_mm: float = 4.0,
    catheter_radius_mm: float = 1.65,
) -> dict[str, tuple[float, float, float, float]]:
    """The views an operator finds in this heart: for each valve of
    :data:`EXAMPLE_VIEWS`, the model joint state nearest to the example (knobs +-12 deg,
    roll +-24 deg, translation +-10 mm) whose image plane passes within 2.5 mm of the valve
    centre, within 25 deg of the sector's centre line, with the transducer (the
    image centre) at least ``clearance_mm`` from the walls and the bending section and
    housing clear of them (end-diastole,
    end-expiration). Falls back to the candidate nearest the valve plane when none
    qualifies. The nominal patient gets :data:`EXAMPLE_VIEWS` back.

    Returns
    -------
    dict name -> (phi1 rad, phi2 rad, phi3 rad, d4 mm)
    """
    walls = Walls(phantom, base2anatomy)
    b2a = np.asarray(base2anatomy, np.float64)
    deg = math.pi / 180.0
    g1 = np.arange(-12, 12.1, 3) * deg
    g3 = np.arange(-24, 24.1, 4) * deg
    g4 = np.arange(-10, 10.1, 2.5)
    grid = np.stack(np.meshgrid(g1, g1, g3, g4, indexing="ij"), -1).reshape(-1, 4)
    scale = np.array([10 * deg, 10 * deg, 20 * deg, 10.0])
    s_nodes = np.array([20.0, 35.0, 50.0, geometry.bending_length, geometry.bending_length + 15])
    s_tip = np.array([geometry.bending_length + geometry.us_offset])
    out: dict[str, tuple[float, float, float, float]] = {}
    valves = {v.name: v for v in phantom.valves}
    for name, q0 in EXAMPLE_VIEWS.items():
        q = np.asarray(q0) + grid
        lim = geometry.joint_limits
        q = q[np.all((q >= lim[:, 0]) & (q <= lim[:, 1]), axis=1)]
        tips = forward(q, geometry, check=False)
        t2a = b2a @ tips
        c = np.asarray(valves[name].centre)
        rel = np.einsum("nji,nj->ni", t2a[:, :3, :3], c - t2a[:, :3, 3])  # valve in tip frame
        oop = np.abs(rel[:, 1])
        angle = np.degrees(np.abs(np.arctan2(rel[:, 2], rel[:, 0])))
        body, _ = catheter_nodes(tips, s_nodes, geometry)
        tip, _ = catheter_nodes(tips, s_tip, geometry)
        d_body, _ = walls.sdf_material(_to_anatomy(body, b2a))
        d_tip, _ = walls.sdf_material(_to_anatomy(tip, b2a))
        clear = (d_body.reshape(len(q), -1).max(axis=1) < -catheter_radius_mm) & (
            d_tip.reshape(len(q), -1).max(axis=1) < -clearance_mm
        )
        ok = clear & (oop < 2.5) & (angle < 25.0) & (rel[:, 0] > 10.0)
        dist = np.sum(((q - np.asarray(q0)) / scale) ** 2, axis=1)
        if np.any(ok):
            pick = int(np.flatnonzero(ok)[np.argmin(dist[ok])])
        else:
            pool = np.flatnonzero(clear) if np.any(clear) else np.arange(len(q))
            pick = int(pool[np.argmin(oop[pool] + 0.05 * angle[pool] + 0.1 * dist[pool])])
        out[name] = tuple(float(x) for x in q[pick])  # type: ignore[assignment]
    return out


def _to_anatomy(points_in_base: Array, base2anatomy: Array) -> Array:
    out: Array = points_in_base.reshape(-1, 3) @ base2anatomy[:3, :3].T + base2anatomy[:3, 3]
    return out
