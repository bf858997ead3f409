"""A transmission model per *tendon* (tendon-sheath capstan play) and its stateful inverse
(beyond the paper); its identification is :mod:`icenav.calibration.transmission`.

:mod:`icenav.compensation.hysteresis` gives each knob one play whose half-width grows with that
knob's own angle. The physics it stands for is per tendon (Kaneko et al. 1991; Palli &
Melchiorri 2006; Do et al. 2014; Kato et al. 2016): each knob pulls one tendon of an
antagonistic pair through a long sheath, and capstan friction lets the *distal* pull stick
inside a band around the *proximal* pull whose width grows with the tendon's tension and with
the total wrap angle of its path -- the shaft, the vessel and the bending section's own bend,
so the play of one knob widens when the *other* knob bends the section. Angles below are knob
angles (rad): a pull is expressed as the knob rotation that makes it (pull / handle radius).

Tendons A, B (AP knob x1) and C, D (RL knob x2), sign ``sigma = +1`` for A, C and ``-1`` for B,
D; pair j, other pair k. Per substep (knob change <= ``max_substep``; TR = this module's
equations, the capstan form of the tendon-sheath literature, not the paper's)::

    p_i = sigma_i x_j - s_j                                  # (TR1) proximal pull, slack s_j
    Theta = wrap + friction * hypot(z1, z2)                  # (TR2) capstan exponent mu Theta
    T_i = max(d_i, 0) + max(sigma_i gamma_j z_k, 0)          # (TR3) tension (rad of pull)
    T_i = max(d_i + sigma_i gamma_j z_k, 0)                  # (TR3s) the "stretch" form
    T_i <- T_i + eta hypot(z1, z2)                           # (TR3b) "bend-tension" only
    d_i = clip(d_i, p_i - w_j - kappa_j T_i g+(Theta),       # (TR4) friction band
                    p_i + w_j + kappa_j T_i g-(Theta))
    z_j = max(d_A, 0) - max(d_B, 0)                          # (TR5) effective knob

With the ``"two-play"`` extension each tendon has two play elements side by side (a
Prandtl-Ishlinskii operator of two elements), the second of band ``rho`` times the first's,
and its distal pull is their weighted mean::

    d'_i  = clip(d'_i,  p_i - b+_i, p_i + b-_i)              # (TR4) element 1, b the band above
    d''_i = clip(d''_i, p_i - rho b+_i, p_i + rho b-_i)      # (TR4b) element 2
    d_i = (1 - a) d'_i + a d''_i                             # (TR4c) the tendon's pull

    g+(x) = (e^x - 1) / x - 1,   g-(x) = 1 - (1 - e^-x) / x   # pulled / released tendon

``s_j`` is the pair's slack (a dead-zone of half-width s_j in x_j), ``w_j`` the seal play,
``kappa_j`` the growth of the band with tension, ``gamma_j`` the tension the other pair's bend
puts on one tendon of this pair (signed: which tendon is stretched depends on where the
tendons are routed), ``wrap`` the capstan exponent of the straight catheter (mu times the
shaft's curvature) and ``friction`` (mu) its growth per rad of bend. The effective knobs
``z`` are what an elasticity map F built on them sees.

Two forms of the tension (``coupling_form``): ``"added"`` (TR3) adds the other pair's share to
the tendon's own pull, so it never relieves a tendon; ``"stretch"`` (TR3s) reads the tension
as the tendon's stretch beyond its path, which the other pair's bend lengthens or shortens
(a tendon routed off its pair's plane), and which cannot be negative. Neither is assumed: the
identification keeps the one that predicts held-out calibration data better
(:func:`icenav.calibration.transmission.identify_transmission_form`).

Two extensions (``extension``), each a generic change of shape, not a family's law, chosen the
same way: ``"bend-tension"`` (TR3b) adds a share ``eta`` of the section's total bend to every
tendon's tension (the sheath pressed against the bent lumen loads every tendon, whatever its
pair), so every band widens with the bend's size, not only with the tendon's own pull;
``"two-play"`` (TR4b-c) gives each tendon's band a shape (a narrow and a wide element: a
rounded loop instead of a parallelogram, as in Prandtl-Ishlinskii models of tendon-sheath
friction, Do et al. 2014). ``"none"`` keeps eta = 0 and a = 0.

Compensation (:class:`TendonCompensator`): for a wanted effective knob pair ``z*`` the motor
knobs ``x`` are found by a 1-D root search per knob (``z_j`` is non-decreasing in ``x_j``)
inside Gauss-Seidel sweeps over the pair (coupled through the bend and the tensions), from
the model's current state, which is then advanced; inside the dead-zone (``|z*_j| < eps``)
the command is interpolated between the solutions for ``+-eps`` (no jump across it). The
roll and the distal twist keep the per-joint models of :mod:`icenav.compensation.hysteresis`.
:class:`icenav.compensation.tendon_map.TendonKnobMap` composes it with F as the controller's
compensation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.compensation.elasticity import ElasticityMap
from icenav.compensation.hysteresis import HysteresisCompensator
from icenav.compensation.knob_residual import KnobResidual, update_sense
from icenav.compensation.section_length import SectionLength
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY

__all__ = [
    "COUPLING_FORMS",
    "EXTENSIONS",
    "PairTransmission",
    "TendonCompensator",
    "TendonTransmission",
    "TransmissionCalibration",
    "TransmissionFit",
    "g_minus",
    "g_plus",
    "static_terms",
]

_MAX_PLAY = math.radians(20.0)
COUPLING_FORMS = ("added", "stretch")
"""The tension forms of (TR3) / (TR3s) (see the module docstring)."""
EXTENSIONS = ("none", "bend-tension", "two-play")
"""The model's optional extensions (module docstring): which extra parameters it has."""
_EXTRA_NAMES = {
    "none": (),
    "bend-tension": ("bend_tension",),
    "two-play": ("second_weight", "second_width"),
}
_PARAM_NAMES = (
    "ap.slack",
    "ap.seal_play",
    "ap.tension_play",
    "ap.coupling",
    "rl.slack",
    "rl.seal_play",
    "rl.tension_play",
    "rl.coupling",
    "wrap",
    "friction",
)


def g_plus(x: float) -> float:
    """(e^x - 1)/x - 1: extra lag factor of a pulled tendon for capstan exponent x >= 0."""
    if x < 1e-6:
        return 0.5 * x
    return math.expm1(x) / x - 1.0


def g_minus(x: float) -> float:
    """1 - (1 - e^-x)/x: lead factor of a released tendon for capstan exponent x >= 0."""
    if x < 1e-6:
        return 0.5 * x
    return 1.0 + math.expm1(-x) / x


def _check_range(name: str, v: float, lo: float, hi: float, unit: str) -> float:
    f = float(v)
    if not math.isfinite(f) or f < lo or f > hi:
        raise ConfigurationError(f"{name} must be in [{lo:.4g}, {hi:.4g}] {unit}, got {v!r}")
    return f


def _tensions(
    dA: float, dB: float, dC: float, dD: float, cz1: float, cz2: float, stretch: bool
) -> tuple[float, float, float, float]:
    """Tensions (rad of pull) of tendons A-D from their distal pulls and the other pairs'
    signed shares ``cz1 = gamma_1 z2``, ``cz2 = gamma_2 z1``: (TR3s) if ``stretch`` else (TR3)."""
    if stretch:  # (TR3s)
        return max(dA + cz1, 0.0), max(dB - cz1, 0.0), max(dC + cz2, 0.0), max(dD - cz2, 0.0)
    return (  # (TR3)
        max(dA, 0.0) + max(cz1, 0.0),
        max(dB, 0.0) + max(-cz1, 0.0),
        max(dC, 0.0) + max(cz2, 0.0),
        max(dD, 0.0) + max(-cz2, 0.0),
    )


@dataclass(frozen=True)
class PairTransmission:
    """One antagonistic tendon pair (angles as knob rotation, rad)."""

    slack: float = 0.0
    """s: slack of each tendon at the knob's centre (rad of knob): dead-zone half-width."""
    seal_play: float = 0.0
    """w: tension-independent half-width of each tendon's friction band (rad)."""
    tension_play: float = 0.0
    """kappa: band half-width per rad of tendon tension per unit of g+- (rad/rad)."""
    coupling: float = 0.0
    """gamma: tension put on this pair's tendon (sigma gamma z_other > 0) per rad of the other
    knob's effective angle (rad/rad, signed)."""

    def __post_init__(self) -> None:
        _check_range("slack", self.slack, 0.0, _MAX_PLAY, "rad")
        _check_range("seal_play", self.seal_play, 0.0, _MAX_PLAY, "rad")
        _check_range("tension_play", self.tension_play, 0.0, 2.0, "rad/rad")
        _check_range("coupling", self.coupling, -2.0, 2.0, "rad/rad")


@dataclass(frozen=True)
class TendonTransmission:
    """The per-tendon transmission of both knobs (see the module docstring)."""

    ap: PairTransmission = field(default_factory=PairTransmission)
    """Tendons A, B driven by the AP knob (phi1)."""
    rl: PairTransmission = field(default_factory=PairTransmission)
    """Tendons C, D driven by the RL knob (phi2)."""
    wrap: float = 0.0
    """Capstan exponent mu Theta of the straight catheter with the section straight (>= 0)."""
    friction: float = 0.0
    """mu: growth of the capstan exponent per rad of bend of the section (>= 0)."""
    max_substep: float = math.radians(2.0)
    """Largest knob change per substep of :meth:`step` (rad), > 0."""
    coupling_form: str = "added"
    """How the other pair's bend enters a tendon's tension: ``"added"`` (TR3) or
    ``"stretch"`` (TR3s)."""
    extension: str = "none"
    """Which extension the model has (:data:`EXTENSIONS`): its parameters below are free in
    the identification; the others stay at their neutral values."""
    bend_tension: float = 0.0
    """eta (TR3b): tension on every tendon per rad of the section's total effective bend
    (rad/rad, >= 0; ``"bend-tension"`` only)."""
    second_weight: float = 0.0
    """a (TR4c): weight of each tendon's second play element ([0, 0.95]; ``"two-play"``
    only)."""
    second_width: float = 1.0
    """rho (TR4b): the second element's band over the first's ([0, 5])."""
    residual: KnobResidual | None = None
    """The effective knobs' residual along knob circles by sense of turning (KR1-KR3 of
    :mod:`icenav.compensation.knob_residual`), added to the band's effective knobs; None: the
    band alone. Its sense of turning is the last element of the state."""

    def __post_init__(self) -> None:
        if self.residual is not None and not isinstance(self.residual, KnobResidual):
            raise ConfigurationError(
                f"residual must be a KnobResidual or None, got {type(self.residual).__name__}"
            )
        if self.coupling_form not in COUPLING_FORMS:
            raise ConfigurationError(
                f"coupling_form must be one of {COUPLING_FORMS}, got {self.coupling_form!r}"
            )
        if self.extension not in EXTENSIONS:
            raise ConfigurationError(
                f"extension must be one of {EXTENSIONS}, got {self.extension!r}"
            )
        _check_range("bend_tension", self.bend_tension, 0.0, 2.0, "rad/rad")
        _check_range("second_weight", self.second_weight, 0.0, 0.95, "(fraction)")
        _check_range("second_width", self.second_width, 0.0, 5.0, "(ratio)")
        if self.extension != "bend-tension" and self.bend_tension != 0.0:
            raise ConfigurationError(
                f"bend_tension must be 0 without the 'bend-tension' extension, got "
                f"{self.bend_tension!r}"
            )
        if self.extension != "two-play" and self.second_weight != 0.0:
            raise ConfigurationError(
                f"second_weight must be 0 without the 'two-play' extension, got "
                f"{self.second_weight!r}"
            )
        for name in ("ap", "rl"):
            if not isinstance(getattr(self, name), PairTransmission):
                raise ConfigurationError(f"{name} must be a PairTransmission")
        _check_range("wrap", self.wrap, 0.0, 10.0, "(dimensionless)")
        _check_range("friction", self.friction, 0.0, 5.0, "per rad")
        _check_range("max_substep", self.max_substep, 1e-4, 0.5, "rad")

    # --- parameter vector (identification) -------------------------------------------------

    @property
    def form(self) -> str:
        """The model's form: the tension form, ``+extension`` unless ``"none"``, and
        ``+residual`` with a circle residual."""
        name = (
            self.coupling_form
            if self.extension == "none"
            else f"{self.coupling_form}+{self.extension}"
        )
        return name if self.residual is None else f"{name}+residual"

    @property
    def extra_names(self) -> tuple[str, ...]:
        """Names of the extension's parameters, in the order of :meth:`extra_vector`."""
        return _EXTRA_NAMES[self.extension]

    def extra_vector(self) -> Array:
        """The extension's parameters (k,) (see :attr:`extra_names`)."""
        return np.array([float(getattr(self, n)) for n in self.extra_names])

    def with_extra(self, v: ArrayLike) -> TendonTransmission:
        """The same model with the extension's parameters ``v`` (k,)."""
        x = check_finite(v, "extension parameters").ravel()
        names = self.extra_names
        if x.size != len(names):
            raise ShapeError(f"{self.extension!r} has {len(names)} parameters, got {x.size}")
        new = {n: float(t) for n, t in zip(names, x, strict=True)}
        return replace(
            self,
            bend_tension=new.get("bend_tension", self.bend_tension),
            second_weight=new.get("second_weight", self.second_weight),
            second_width=new.get("second_width", self.second_width),
        )

    def to_vector(self) -> Array:
        """The 10 parameters in the order of ``PARAM_NAMES``."""
        a, r = self.ap, self.rl
        return np.array(
            [
                a.slack,
                a.seal_play,
                a.tension_play,
                a.coupling,
                r.slack,
                r.seal_play,
                r.tension_play,
                r.coupling,
                self.wrap,
                self.friction,
            ]
        )

    @classmethod
    def from_vector(
        cls,
        v: ArrayLike,
        max_substep: float = math.radians(2.0),
        coupling_form: str = "added",
        extension: str = "none",
        extra: ArrayLike = (),
    ) -> TendonTransmission:
        """Inverse of :meth:`to_vector` (``coupling_form``, ``extension``: see the class;
        ``extra``: the extension's parameters, :meth:`extra_vector`)."""
        x = check_finite(v, "parameter vector").ravel()
        if x.size != len(_PARAM_NAMES):
            raise ShapeError(f"parameter vector must have {len(_PARAM_NAMES)} values, got {x.size}")
        return cls(
            ap=PairTransmission(*(float(t) for t in x[0:4])),
            rl=PairTransmission(*(float(t) for t in x[4:8])),
            wrap=float(x[8]),
            friction=float(x[9]),
            max_substep=max_substep,
            coupling_form=coupling_form,
        ).with_extension(extension, extra)

    def with_extension(self, extension: str, extra: ArrayLike = ()) -> TendonTransmission:
        """The same model with ``extension`` (:data:`EXTENSIONS`) and its parameters ``extra``
        (default: neutral, eta = 0 or a = 0 with rho = 0.5)."""
        if extension not in EXTENSIONS:
            raise ConfigurationError(f"extension must be one of {EXTENSIONS}, got {extension!r}")
        base = replace(
            self, extension="none", bend_tension=0.0, second_weight=0.0, second_width=1.0
        )
        model = replace(base, extension=extension)
        x = np.asarray(extra, dtype=np.float64).ravel()
        if x.size == 0:
            x = np.array({"none": [], "bend-tension": [0.0], "two-play": [0.0, 0.5]}[extension])
        return model.with_extra(x)

    def with_vessel(self, vessel_curvature: float) -> TendonTransmission:
        """The same transmission with the shaft laid through a vessel that turns by
        ``vessel_curvature`` (rad, the sum of its arcs' turning angles, e.g. from imaging):
        every tendon's wrap grows by it, so the capstan exponent grows by mu times it::

            wrap' = wrap + friction * vessel_curvature          # (TR2) Theta_i + Theta_vessel
        """
        t = _check_range("vessel_curvature", vessel_curvature, 0.0, 4.0 * math.pi, "rad")
        return replace(self, wrap=min(self.wrap + self.friction * t, 10.0))

    # --- simulation ------------------------------------------------------------------------

    @property
    def state_size(self) -> int:
        """Length of the tendon state: 4 distal pulls (A, B, C, D), or 8 with ``"two-play"``
        (each tendon's two elements, d' then d'')."""
        return self._band_size + (0 if self.residual is None else 1)

    @property
    def _band_size(self) -> int:
        """The band's part of the state: 4 distal pulls, or 8 with ``"two-play"``."""
        return 8 if self.extension == "two-play" else 4

    def relaxed_state(self, x: ArrayLike = (0.0, 0.0)) -> Array:
        """Tendon state (:attr:`state_size`,) of a relaxed transmission at motor knobs x (2,):
        every element at d_i = p_i."""
        xx = check_finite(x, "x", "rad").ravel()
        if xx.size != 2:
            raise ShapeError(f"x must have 2 knob angles, got {xx.size}")
        s1, s2 = self.ap.slack, self.rl.slack
        d = np.array([xx[0] - s1, -xx[0] - s1, xx[1] - s2, -xx[1] - s2])
        d = np.concatenate([d, d]) if self._band_size == 8 else d
        return d if self.residual is None else np.append(d, 0.0)  # the sense: never turned

    def step(
        self, d: Sequence[float], x_from: Sequence[float], x_to: Sequence[float]
    ) -> list[float]:
        """Advance the tendon state ``d`` (:attr:`state_size`,) while the knobs move from
        ``x_from`` to ``x_to`` (2,) along a straight line, in substeps of at most
        ``max_substep``. Returns the new state (a list; the input is not modified). Pure float
        math (hot loop). With a residual the last element is the sense of turning
        (:func:`~icenav.compensation.knob_residual.update_sense` of the band's effective
        knobs before and after)."""
        if self.residual is not None:
            band = list(d[: self._band_size])
            new = self._band_step(band, x_from, x_to)
            z0, z1 = self._band_effective(band), self._band_effective(new)
            return [*new, update_sense(float(d[-1]), z0, z1)]
        return self._band_step(d, x_from, x_to)

    def _band_step(
        self, d: Sequence[float], x_from: Sequence[float], x_to: Sequence[float]
    ) -> list[float]:
        """:meth:`step` of the band alone (state 4 or 8)."""
        if self.extension == "two-play":
            return self._step_two(d, x_from, x_to)
        row = [float(x_to[0]), float(x_to[1])]
        return self._run_one([row], d, [float(x_from[0]), float(x_from[1])])[1]

    def _step_two(
        self, d: Sequence[float], x_from: Sequence[float], x_to: Sequence[float]
    ) -> list[float]:
        """:meth:`step` with two play elements per tendon (TR4b-c); state (8,): the first
        elements of A-D, then the second ones. Unrolled over the tendons (hot loop: the
        identification simulates it a few hundred times per fit)."""
        a0, b0 = float(x_from[0]), float(x_from[1])
        a1, b1 = float(x_to[0]), float(x_to[1])
        n = max(1, math.ceil(max(abs(a1 - a0), abs(b1 - b0)) / self.max_substep))
        eA, eB, eC, eD, fA, fB, fC, fD = (float(t) for t in d)
        ap, rl = self.ap, self.rl
        s1, w1, k1, c1 = ap.slack, ap.seal_play, ap.tension_play, ap.coupling
        s2, w2, k2, c2 = rl.slack, rl.seal_play, rl.tension_play, rl.coupling
        wrap, mu = self.wrap, self.friction
        a, rho = self.second_weight, self.second_width
        b = 1.0 - a
        stretch = self.coupling_form == "stretch"
        for i in range(1, n + 1):
            f = i / n
            x1 = a0 + f * (a1 - a0)
            x2 = b0 + f * (b1 - b0)
            # (TR4c) each tendon's pull from its two elements
            dA, dB, dC, dD = b * eA + a * fA, b * eB + a * fB, b * eC + a * fC, b * eD + a * fD
            z1 = max(dA, 0.0) - max(dB, 0.0)
            z2 = max(dC, 0.0) - max(dD, 0.0)
            e = wrap + mu * math.hypot(z1, z2)  # (TR2)
            gp, gm = g_plus(e), g_minus(e)
            tA, tB, tC, tD = _tensions(dA, dB, dC, dD, c1 * z2, c2 * z1, stretch)
            # (TR1), (TR4) element 1 and (TR4b) element 2, rho times as wide
            p = x1 - s1
            lo, hi = w1 + k1 * tA * gp, w1 + k1 * tA * gm
            eA = min(max(eA, p - lo), p + hi)
            fA = min(max(fA, p - rho * lo), p + rho * hi)
            p = -x1 - s1
            lo, hi = w1 + k1 * tB * gp, w1 + k1 * tB * gm
            eB = min(max(eB, p - lo), p + hi)
            fB = min(max(fB, p - rho * lo), p + rho * hi)
            p = x2 - s2
            lo, hi = w2 + k2 * tC * gp, w2 + k2 * tC * gm
            eC = min(max(eC, p - lo), p + hi)
            fC = min(max(fC, p - rho * lo), p + rho * hi)
            p = -x2 - s2
            lo, hi = w2 + k2 * tD * gp, w2 + k2 * tD * gm
            eD = min(max(eD, p - lo), p + hi)
            fD = min(max(fD, p - rho * lo), p + rho * hi)
        return [eA, eB, eC, eD, fA, fB, fC, fD]

    def effective(self, d: Sequence[float]) -> tuple[float, float]:
        """Effective knob angles (z1, z2) (rad) of a tendon state d (:attr:`state_size`,):
        the band's (TR5), plus the residual (KR3) if the model has one."""
        if self.residual is None:
            return self._band_effective(d)
        z1, z2 = self._band_effective(d[: self._band_size])
        e1, e2 = self.residual.delta(z1, z2, float(d[-1]))
        return z1 + e1, z2 + e2

    def _band_effective(self, d: Sequence[float]) -> tuple[float, float]:
        """(TR5) of the band's state (4 or 8)."""
        if len(d) == 8:
            a = self.second_weight
            dA, dB, dC, dD = ((1.0 - a) * d[k] + a * d[k + 4] for k in range(4))  # (TR4c)
        else:
            dA, dB, dC, dD = d
        return max(dA, 0.0) - max(dB, 0.0), max(dC, 0.0) - max(dD, 0.0)

    def simulate(self, x_path: ArrayLike, x_start: ArrayLike | None = None) -> Array:
        """Effective knobs (n, 2) along motor knob commands ``x_path`` (n, 2) or (n, 4) (rad),
        from a relaxed transmission at ``x_start`` (2,) (default: the first command)."""
        x = check_finite(x_path, "x_path", "rad")
        if x.ndim != 2 or x.shape[1] not in (2, 4) or x.shape[0] < 1:
            raise ShapeError(f"x_path must have shape (n, 2) or (n, 4), got {x.shape}")
        x = x[:, :2]
        start = x[0] if x_start is None else check_finite(x_start, "x_start", "rad").ravel()[:2]
        band = replace(self, residual=None)
        d0 = band.relaxed_state(start).tolist()
        d = d0
        prev = [float(start[0]), float(start[1])]
        if band.state_size == 4:
            out = np.array(band._run_one(x.tolist(), d, prev)[0])
        else:
            out = np.empty((x.shape[0], 2))
            for k, row in enumerate(x.tolist()):
                d = band.step(d, prev, row)
                prev = row
                out[k] = band.effective(d)
        if self.residual is None:
            return out
        return out + self.residual.along(out, 0.0, band.effective(d0))  # (KR3)

    def _run_one(
        self, rows: list[list[float]], d: Sequence[float], prev: list[float]
    ) -> tuple[list[tuple[float, float]], list[float]]:
        """The one-element transmission (state (4,)) driven along every row of ``rows``
        (n, 2) from state ``d`` at ``prev`` (2,), each row a straight knob line in substeps of
        at most ``max_substep``: the effective knobs after each row (n, 2) and the final
        state (4,). One loop with the parameters read once: :meth:`step` (one row) and
        :meth:`simulate` (the identification's hot loop) both run it."""
        dA, dB, dC, dD = (float(t) for t in d)
        ap, rl = self.ap, self.rl
        s1, w1, k1, c1 = ap.slack, ap.seal_play, ap.tension_play, ap.coupling
        s2, w2, k2, c2 = rl.slack, rl.seal_play, rl.tension_play, rl.coupling
        wrap, mu, eta = self.wrap, self.friction, self.bend_tension
        stretch = self.coupling_form == "stretch"
        sub = self.max_substep
        expm1 = math.expm1
        a1, b1 = float(prev[0]), float(prev[1])
        out = []
        for row in rows:
            a0, b0 = a1, b1
            a1, b1 = row[0], row[1]
            n = max(1, math.ceil(max(abs(a1 - a0), abs(b1 - b0)) / sub))
            for i in range(1, n + 1):
                f = i / n
                x1 = a0 + f * (a1 - a0)
                x2 = b0 + f * (b1 - b0)
                z1 = (dA if dA > 0.0 else 0.0) - (dB if dB > 0.0 else 0.0)
                z2 = (dC if dC > 0.0 else 0.0) - (dD if dD > 0.0 else 0.0)
                bend = math.hypot(z1, z2)
                e = wrap + mu * bend  # (TR2) capstan exponent
                if e < 1e-6:  # g_plus, g_minus inlined
                    gp = gm = 0.5 * e
                else:
                    gp, gm = expm1(e) / e - 1.0, 1.0 + expm1(-e) / e
                # tensions (rad of pull): own pull and the other pair's bend (signed coupling)
                cz1, cz2 = c1 * z2, c2 * z1
                if stretch:  # (TR3s)
                    tA, tB = max(dA + cz1, 0.0), max(dB - cz1, 0.0)
                    tC, tD = max(dC + cz2, 0.0), max(dD - cz2, 0.0)
                else:  # (TR3)
                    tA = (dA if dA > 0.0 else 0.0) + (cz1 if cz1 > 0.0 else 0.0)
                    tB = (dB if dB > 0.0 else 0.0) + (-cz1 if cz1 < 0.0 else 0.0)
                    tC = (dC if dC > 0.0 else 0.0) + (cz2 if cz2 > 0.0 else 0.0)
                    tD = (dD if dD > 0.0 else 0.0) + (-cz2 if cz2 < 0.0 else 0.0)
                if eta > 0.0:  # (TR3b)
                    tb = eta * bend
                    tA, tB, tC, tD = tA + tb, tB + tb, tC + tb, tD + tb
                # (TR1), (TR4): each distal pull sticks inside its friction band
                p = x1 - s1
                dA = min(max(dA, p - w1 - k1 * tA * gp), p + w1 + k1 * tA * gm)
                p = -x1 - s1
                dB = min(max(dB, p - w1 - k1 * tB * gp), p + w1 + k1 * tB * gm)
                p = x2 - s2
                dC = min(max(dC, p - w2 - k2 * tC * gp), p + w2 + k2 * tC * gm)
                p = -x2 - s2
                dD = min(max(dD, p - w2 - k2 * tD * gp), p + w2 + k2 * tD * gm)
            out.append((max(dA, 0.0) - max(dB, 0.0), max(dC, 0.0) - max(dD, 0.0)))  # (TR5)
        return out, [dA, dB, dC, dD]


# --- observations ----------------------------------------------------------------------------


# --- identification --------------------------------------------------------------------------


def static_terms(degree: int) -> list[tuple[int, int]]:
    """(a, b) exponents of the monomials z1^a z2^b, a + b <= ``degree``, in the order of
    :attr:`TransmissionFit.static_coefficients`' rows (the static map G)."""
    return [(a, n - a) for n in range(degree + 1) for a in range(n + 1)]


@dataclass(frozen=True)
class TransmissionFit:
    """Result of :func:`identify_transmission`."""

    model: TendonTransmission
    """The identified transmission."""
    rms: float
    """RMS residual of the tracked model knobs (rad) with the identified model."""
    rms_without_play: float
    """The same residual with a play-free transmission (z = x) and the same static map (rad):
    what the play model explains."""
    static_coefficients: Array
    """(m, 2) coefficients of the static polynomial map G: z -> observed model knobs."""
    n_samples: int
    """Valid samples used."""
    n_evaluations: int
    """Model simulations made by the optimiser."""
    degree: int = 7
    """Total degree of the static map G (``static_coefficients`` has (degree+1)(degree+2)/2
    rows)."""
    held_out_rms: tuple[tuple[str, float], ...] = ()
    """(coupling form, RMS residual (rad)) of each form tried on held-out calibration data
    (:func:`icenav.calibration.transmission.identify_transmission_form`); empty if the form
    was not chosen that way."""


# --- compensation ----------------------------------------------------------------------------


class TendonCompensator:
    """Stateful inverse of a :class:`TendonTransmission` (knobs), with the roll's and the
    twist's per-joint plays of :class:`icenav.compensation.hysteresis.HysteresisCompensator`.

    :meth:`command` takes the wanted *effective* joint state (z1, z2, phi3, d4) and returns the
    motor command; the model's tendon state is advanced as if that command were executed.
    """

    def __init__(
        self,
        model: TendonTransmission,
        roll: HysteresisCompensator | None = None,
        *,
        knob_limit: float = DEFAULT_GEOMETRY.knob_limit,
        dead_zone_ramp: float = math.radians(0.5),
        xtol: float = 1e-7,
    ) -> None:
        if not isinstance(model, TendonTransmission):
            raise ConfigurationError(f"model must be a TendonTransmission, got {type(model)}")
        self.model = model
        """The transmission being inverted."""
        self.roll = (
            None
            if roll is None
            else HysteresisCompensator(
                [None, None, roll.joints[2], roll.joints[3]],
                roll_play_per_bend=roll.roll_play_per_bend,
                twist_play_per_bend=roll.twist_play_per_bend,
                reversal_threshold=roll.reversal_threshold,
                roll_play=roll.roll_play,
                twist_play=roll.twist_play,
            )
        )
        """Per-joint compensator for phi3 and d4 (knobs pass through), or None."""
        self.knob_limit = _check_range("knob_limit", knob_limit, 1e-3, math.pi, "rad")
        """Motor knob limit (rad): commands are searched within +-knob_limit."""
        self.dead_zone_ramp = _check_range(
            "dead_zone_ramp", dead_zone_ramp, 1e-6, math.radians(5.0), "rad"
        )
        """eps (rad): |z*| below it is reached by interpolating the commands for +-eps."""
        self.xtol = float(xtol)
        self.reset()

    def reset(self, x_motor: ArrayLike = (0.0, 0.0, 0.0, 0.0)) -> None:
        """Relaxed state at motor joint state ``x_motor`` (4,) (default zeros)."""
        q = check_finite(x_motor, "x_motor").ravel()
        if q.size != 4:
            raise ShapeError(f"x_motor must have 4 values, got {q.size}")
        self._x = [float(q[0]), float(q[1])]
        self._d = self.model.relaxed_state(q[:2]).tolist()
        if self.roll is not None:
            self.roll.reset(np.array([0.0, 0.0, q[2], q[3]]))

    @property
    def effective_knobs(self) -> tuple[float, float]:
        """The model's current effective knob angles (rad)."""
        return self.model.effective(self._d)

    def _z_after(self, x: list[float]) -> tuple[float, float]:
        return self.model.effective(self.model.step(self._d, self._x, x))

    def _solve_knob(self, j: int, target: float, x: list[float]) -> float:
        lim = self.knob_limit

        def f(v: float) -> float:
            xx = list(x)
            xx[j] = v
            return self._z_after(xx)[j] - target

        here = x[j]
        fh = f(here)
        if fh == 0.0:
            return here
        sgn = -1.0 if fh > 0.0 else 1.0  # direction to move
        stepv = math.radians(2.0)
        a = here
        while True:
            b = min(max(a + sgn * stepv, -lim), lim)
            fb = f(b)
            if fb == 0.0:
                return b
            if (fb > 0.0) != (fh > 0.0):
                lo_, hi_ = (a, b) if a < b else (b, a)
                return float(brentq(f, lo_, hi_, xtol=self.xtol))
            if b in (-lim, lim):
                return b  # unreachable within the limits: the nearest reachable command
            a, fh = b, fb
            stepv *= 2.0

    def _solve(self, target: tuple[float, float]) -> list[float]:
        x = list(self._x)
        for _ in range(8):  # Gauss-Seidel over the pair (coupled through bend and tension)
            before = list(x)
            for j in (0, 1):
                x[j] = self._solve_knob(j, target[j], x)
            if max(abs(x[0] - before[0]), abs(x[1] - before[1])) < self.xtol:
                break
        return x

    def knob_command(self, z1: float, z2: float) -> tuple[float, float]:
        """Motor knobs (rad) that bring the model's effective knobs to (z1, z2) (rad) from its
        current state, which is *not* advanced (see :meth:`advance`)."""
        eps = self.dead_zone_ramp
        tz = (float(z1), float(z2))
        inside = [abs(t) < eps for t in tz]
        if not any(inside):
            x = self._solve(tz)
        else:
            # inside a dead-zone: interpolate the commands for +-eps (no jump across it),
            # then solve the other knob exactly with that one fixed
            xa = self._solve((-eps if inside[0] else tz[0], -eps if inside[1] else tz[1]))
            xb = self._solve((eps if inside[0] else tz[0], eps if inside[1] else tz[1]))
            x = []
            for j in (0, 1):
                w = (tz[j] + eps) / (2.0 * eps) if inside[j] else 0.5
                x.append(xa[j] + w * (xb[j] - xa[j]))
            for j in (0, 1):
                if not inside[j]:
                    x[j] = self._solve_knob(j, tz[j], x)
        return float(x[0]), float(x[1])

    def state(self) -> tuple[tuple[float, ...], tuple[float, float]]:
        """The knobs' state: distal pulls (4,) and motor knobs (2,), for :meth:`set_state`."""
        return tuple(self._d), (self._x[0], self._x[1])

    def set_state(self, state: tuple[tuple[float, ...], tuple[float, float]]) -> None:
        """Restore a state taken with :meth:`state`."""
        d, x = state
        self._d = [float(v) for v in d]
        self._x = [float(x[0]), float(x[1])]

    def advance(self, x1: float, x2: float) -> None:
        """Advance the model's tendon state as the knobs move to (x1, x2) (rad)."""
        x = [float(x1), float(x2)]
        self._d = self.model.step(self._d, self._x, x)
        self._x = x

    def command(self, q_effective: ArrayLike, bend: float | None = None) -> Array:
        """Motor command (4,) for the wanted effective joint state (4,) (z1, z2 rad, phi3 rad,
        d4 mm); ``bend`` (rad) is passed to the roll's play model. The state is advanced as if
        the command were executed."""
        z = check_finite(q_effective, "q_effective").ravel()
        if z.size != 4:
            raise ShapeError(f"q_effective must have 4 values, got {z.size}")
        x = self.knob_command(float(z[0]), float(z[1]))
        self.advance(*x)
        out = z.copy()
        out[0], out[1] = x
        if self.roll is not None:
            r = self.roll.command(np.array([z[0], z[1], z[2], z[3]]), bend)
            out[2], out[3] = r[2], r[3]
        return out

    def command_path(self, q_effective_path: ArrayLike, bends: ArrayLike | None = None) -> Array:
        """Motor commands (n, 4) for wanted effective joint states (n, 4); ``bends`` (n,) rad."""
        path = check_finite(q_effective_path, "q_effective_path")
        if path.ndim != 2 or path.shape[1] != 4:
            raise ShapeError(f"q_effective_path must have shape (n, 4), got {path.shape}")
        if bends is None:
            return np.array([self.command(row) for row in path])
        b = check_finite(bends, "bends", "rad").ravel()
        if b.size != path.shape[0]:
            raise ShapeError(f"bends must have {path.shape[0]} values, got {b.size}")
        return np.array([self.command(row, float(bi)) for row, bi in zip(path, b, strict=True)])


# --- calibration (identification + the elasticity map on effective knobs) --------------------


@dataclass(frozen=True)
class TransmissionCalibration:
    """Everything the tendon compensation needs, calibrated on one catheter."""

    fit: TransmissionFit
    """The identified transmission and its residuals."""
    effective_map: ElasticityMap
    """F on effective knobs: model knobs -> the effective knobs that put the real tip there
    (thin-plate RBF, smoothed, over the relabelled raster and circle samples)."""
    compensator: TendonCompensator
    """The stateful inverse (knobs), with the roll's per-joint play if given."""
    n_moves: int
    """Robot moves of the circles it was (re-)identified from (0 for
    :func:`icenav.calibration.transmission.build_transmission`)."""
    section: SectionLength = field(default_factory=SectionLength)
    """The bending section's length (:mod:`icenav.compensation.section_length`): F was
    built on tracked tips with its axial excess removed, and the compensation sends it to
    the translation (the model's own length: nothing)."""
