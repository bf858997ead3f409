"""The fitted compensation of a calibration as JSON (the ``model`` of a calibration file,
format versions 3 and 4; :mod:`icenav.calibration.files`).

A calibration file of version 2 kept the tracked samples only, so a loader could rebuild the
paper's F from them but not our per-tendon / hysteresis model. Version 3 also keeps what the
fit produced, so that loading gives the compensation the fit gave:

- ``dense`` and ``five_point``: the paper's F
  (:class:`~icenav.compensation.elasticity.ElasticityMap`);
- ``dense+hysteresis``: the :class:`~icenav.calibration.catheter.CatheterCalibration` -- F on
  the raster, the per-joint
  :class:`~icenav.calibration.hysteresis.HysteresisIdentification`, the
  :class:`~icenav.compensation.tracker_bias.TrackerBias` and the
  :class:`~icenav.compensation.transmission.TransmissionCalibration` (the per-tendon model, F
  on its effective knobs, the compensator with the roll's and the twist's plays), whose
  :meth:`~icenav.calibration.catheter.CatheterCalibration.knob_map` is the controller's
  compensation.

The compensation classes are serialised here, from outside, field by field (each frozen
dataclass as a JSON object with one key per ``dataclasses.fields`` entry, each stateful
compensator by its constructor's parameters). An :class:`ElasticityMap` is stored as its
samples, its build options and report, and its two tables (F and F^-1 at the table's nodes,
(91 * 91, 2) rad each): rebuilding F from the samples costs seconds to a minute (F on the
effective knobs interpolates about 1,000 samples), rebuilding its tables from their node values
milliseconds, and F evaluates the same to rounding (the tests bound it). The map's real-tip
interpolant (``ElasticityMap.real_position``, which no compensation path uses) is rebuilt from
the samples on first use.

Version 4 differs only in the roll's and the twist's plays: a law over the knob plane
(:class:`~icenav.compensation.bend_play.KnobPlanePlay`) is stored as ``directions`` (rad) and
``laws`` (one law of the bend each, as version 3 stores its one law); a version 3 law loads as
that law in every direction.

Errors name the source (file) and the field's path in the document
(``model.transmission.fit.static_coefficients``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from icenav._typing import Array
from icenav.calibration.catheter import CatheterCalibration
from icenav.calibration.hysteresis import HysteresisFit, HysteresisIdentification
from icenav.compensation.bend_play import BendPlay, KnobPlanePlay, PlayLaw
from icenav.compensation.elasticity import (
    TABLE_NODES,
    BuildReport,
    CalibrationSet,
    ElasticityMap,
    table_nodes,
)
from icenav.compensation.hysteresis import HysteresisCompensator, JointHysteresis
from icenav.compensation.knob_residual import KnobResidual
from icenav.compensation.section_length import SectionLength
from icenav.compensation.tracker_bias import TrackerBias
from icenav.compensation.transmission import (
    PairTransmission,
    TendonCompensator,
    TendonTransmission,
    TransmissionCalibration,
    TransmissionFit,
)
from icenav.errors import FileFormatError, IcenavError
from icenav.geometry.kinematics import CatheterGeometry

__all__ = [
    "HYSTERESIS_COMPENSATOR_KEYS",
    "MODEL_KINDS",
    "TENDON_COMPENSATOR_KEYS",
    "decode_model",
    "encode_model",
    "needs_knob_plane",
]

MODEL_KINDS = ("dense", "five_point", "dense+hysteresis")
"""Calibration kinds a file keeps the model of: the paper's F for the first two, the
:class:`CatheterCalibration` for ``dense+hysteresis``."""


# --- reading with the field's path in every error ---------------------------------------------


class _Field:
    """A JSON object being read: ``source`` (file) and ``path`` (dotted keys) for errors."""

    def __init__(self, doc: object, source: str, path: str) -> None:
        if not isinstance(doc, dict):
            raise FileFormatError(
                f"{source}: {path} must be a JSON object, got {type(doc).__name__}"
            )
        self.doc: dict[str, Any] = doc
        self.source = source
        self.path = path

    def _name(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def error(self, key: str, text: str) -> FileFormatError:
        return FileFormatError(f"{self.source}: {self._name(key)} {text}")

    def get(self, key: str) -> Any:
        if key not in self.doc:
            raise self.error(key, "is missing")
        return self.doc[key]

    def sub(self, key: str) -> _Field:
        return _Field(self.get(key), self.source, self._name(key))

    def optional(self, key: str) -> _Field | None:
        v = self.get(key)
        return None if v is None else _Field(v, self.source, self._name(key))

    def items(self, key: str) -> list[_Field | None]:
        """A list of JSON objects or nulls."""
        v = self.get(key)
        if not isinstance(v, list):
            raise self.error(key, f"must be a list, got {type(v).__name__}")
        return [
            None if x is None else _Field(x, self.source, f"{self._name(key)}[{i}]")
            for i, x in enumerate(v)
        ]

    def number(self, key: str) -> float:
        v = self.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise self.error(key, f"must be a number, got {v!r}")
        return float(v)

    def integer(self, key: str) -> int:
        v = self.get(key)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(key, f"must be an integer, got {v!r}")
        return v

    def boolean(self, key: str) -> bool:
        v = self.get(key)
        if not isinstance(v, bool):
            raise self.error(key, f"must be true or false, got {v!r}")
        return v

    def text(self, key: str) -> str:
        v = self.get(key)
        if not isinstance(v, str):
            raise self.error(key, f"must be a string, got {v!r}")
        return v

    def array(self, key: str, shape: tuple[int, ...]) -> Array:
        """A numeric array of ``shape`` (-1: any length on that axis)."""
        v = self.get(key)
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise self.error(key, "must be a numeric array") from exc
        want = "(" + ", ".join("n" if s < 0 else str(s) for s in shape) + ")"
        if a.ndim != len(shape) or any(
            s >= 0 and s != t for s, t in zip(shape, a.shape, strict=False)
        ):
            raise self.error(key, f"must have shape {want}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise self.error(key, "must be finite (no NaN or infinity)")
        return a

    def floats(self, key: str, n: int) -> tuple[float, ...]:
        return tuple(float(x) for x in self.array(key, (n,)))

    def build(self, make: Callable[[], Any]) -> Any:
        """``make()``, with a value error of the class itself named after this field."""
        try:
            return make()
        except FileFormatError:
            raise
        except IcenavError as exc:
            raise FileFormatError(f"{self.source}: {self.path}: {exc}") from exc


def _data(obj: Any, **values: Any) -> dict[str, Any]:
    """The JSON object of a frozen dataclass: ``values`` for the fields that need encoding,
    the rest as they are (numbers, strings); every field of ``dataclasses.fields`` is
    written (a field added to the class without an encoding here fails the tests)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        if not f.init:
            continue
        out[f.name] = values[f.name] if f.name in values else getattr(obj, f.name)
    return out


# --- geometry ------------------------------------------------------------------------------------


def _geometry_to_dict(g: CatheterGeometry) -> dict[str, Any]:
    """The catheter geometry a model was fitted for."""
    return _data(g, translation_limits=list(g.translation_limits))


def _pair(v: tuple[float, ...]) -> tuple[float, float]:
    return (v[0], v[1])


def _geometry_from_dict(r: _Field) -> CatheterGeometry:
    """Inverse of :func:`_geometry_to_dict`."""
    return r.build(
        lambda: CatheterGeometry(
            bending_length=r.number("bending_length"),
            knob_radius=r.number("knob_radius"),
            catheter_radius=r.number("catheter_radius"),
            us_offset=r.number("us_offset"),
            knob_limit=r.number("knob_limit"),
            translation_limits=_pair(r.floats("translation_limits", 2)),
        )
    )


# --- the paper's F -------------------------------------------------------------------------------


def _encode_map(m: ElasticityMap) -> dict[str, Any]:
    nodes = table_nodes(m.geometry)
    a, b = (x.ravel() for x in np.meshgrid(nodes, nodes, indexing="ij"))
    fwd = np.stack(m.model_to_motor_knobs(a, b, check=False), axis=-1)
    inv = np.stack(m.motor_to_model_knobs(a, b, check=False), axis=-1)
    return {
        "geometry": _geometry_to_dict(m.geometry),
        "calibration": m.calibration.to_dict(),
        "report": _data(m.report),
        "dead_zone_det": float(m.dead_zone_det),
        "table_nodes": int(nodes.size),
        "model_to_motor": fwd.tolist(),
        "motor_to_model": inv.tolist(),
    }


def _decode_map(r: _Field) -> ElasticityMap:
    g = _geometry_from_dict(r.sub("geometry"))
    cal_doc = r.get("calibration")
    cal = CalibrationSet.from_dict(cal_doc, f"{r.source}: {r.path}.calibration")
    rep = r.sub("report")
    report = rep.build(
        lambda: BuildReport(
            interpolant=rep.text("interpolant"),
            smoothing=rep.number("smoothing"),
            relative_to_model=rep.boolean("relative_to_model"),
            n_samples=rep.integer("n_samples"),
            fit_rms_mm=rep.number("fit_rms_mm"),
            nn_match_rms_mm=rep.number("nn_match_rms_mm"),
            refined_match_rms_mm=rep.number("refined_match_rms_mm"),
            unreachable_fraction=rep.number("unreachable_fraction"),
        )
    )
    if report.interpolant not in ("spline", "rbf", "clough-tocher"):
        raise rep.error(
            "interpolant", f"must be spline, rbf or clough-tocher, got {report.interpolant!r}"
        )
    n = r.integer("table_nodes")
    if n != TABLE_NODES:
        raise r.error("table_nodes", f"must be {TABLE_NODES}, got {n}")
    fwd = r.array("model_to_motor", (n * n, 2))
    inv = r.array("motor_to_model", (n * n, 2))
    built: list[ElasticityMap] = []

    def real_position(a: Array, b: Array) -> Array:
        # the interpolant of the samples, rebuilt on first use (no compensation path uses it)
        if not built:
            built.append(
                ElasticityMap.build(
                    cal,
                    g,
                    interpolant=report.interpolant,
                    smoothing=report.smoothing,
                    relative_to_model=report.relative_to_model,
                )
            )
        return built[0].real_position(a, b)

    return ElasticityMap.from_tables(
        g, real_position, fwd, inv, report, cal, r.number("dead_zone_det")
    )


# --- per-joint hysteresis ------------------------------------------------------------------------


def _encode_joint(j: JointHysteresis | None) -> dict[str, Any] | None:
    return None if j is None else _data(j)


def _decode_joint(r: _Field | None) -> JointHysteresis | None:
    if r is None:
        return None
    return r.build(
        lambda: JointHysteresis(
            backlash=r.number("backlash"),
            backlash_slope=r.number("backlash_slope"),
            dead_zone=r.number("dead_zone"),
            centre=r.number("centre"),
            smoothing=r.number("smoothing"),
        )
    )


def _encode_bend_play(p: BendPlay | None) -> dict[str, Any] | None:
    if p is None:
        return None
    return _data(
        p,
        coef=list(p.coef),
        bends=list(p.bends),
        extra=list(p.extra),
        loo_rms=None if math.isnan(p.loo_rms) else p.loo_rms,
    )


def _encode_play(p: PlayLaw | None) -> dict[str, Any] | None:
    """A law of the bend alone as before (version 3); a law over the knob plane (version 4)
    as ``directions`` (rad) and one law of the bend per direction."""
    if isinstance(p, KnobPlanePlay):
        return {
            "directions": list(p.directions),
            "laws": [_encode_bend_play(x) for x in p.laws],
            "period": p.period,  # absent in the files written before it: pi
        }
    return _encode_bend_play(p)


def _decode_play(r: _Field | None) -> PlayLaw | None:
    """Either form of :func:`_encode_play` (a version 3 file has laws of the bend alone)."""
    if r is None:
        return None
    if "laws" not in r.doc:
        return _decode_bend_play(r)
    laws = [_decode_bend_play(x) for x in r.items("laws")]
    if any(x is None for x in laws):
        raise r.error("laws", "must not hold null")
    return r.build(
        lambda: KnobPlanePlay(
            directions=r.floats("directions", -1),
            laws=tuple(x for x in laws if x is not None),
            period=r.number("period") if "period" in r.doc else math.pi,
        )
    )


def needs_knob_plane(model: object) -> bool:
    """Whether a model holds a play over the knob plane (a version 4 file): the file
    version :mod:`icenav.calibration.files` writes is the oldest that can hold the model."""
    if isinstance(model, CatheterCalibration):
        comps = [model.hysteresis.compensator, model.transmission.compensator.roll]
        return any(
            isinstance(c.roll_play, KnobPlanePlay) or isinstance(c.twist_play, KnobPlanePlay)
            for c in comps
            if c is not None
        )
    return False


def _decode_bend_play(r: _Field | None) -> BendPlay | None:
    if r is None:
        return None
    loo = r.get("loo_rms")
    return r.build(
        lambda: BendPlay(
            form=r.text("form"),
            coef=r.floats("coef", -1),
            bends=r.floats("bends", -1),
            extra=r.floats("extra", -1),
            loo_rms=math.nan if loo is None else r.number("loo_rms"),
        )
    )


HYSTERESIS_COMPENSATOR_KEYS = (
    "joints",
    "roll_play_per_bend",
    "knob_play_per_bend",
    "twist_play_per_bend",
    "reversal_threshold",
    "roll_play",
    "twist_play",
)
"""What a :class:`HysteresisCompensator` is stored as: its constructor's parameters."""


def _encode_compensator(c: HysteresisCompensator | None) -> dict[str, Any] | None:
    if c is None:
        return None
    return {
        "joints": [_encode_joint(j) for j in c.joints],
        "roll_play_per_bend": c.roll_play_per_bend,
        "knob_play_per_bend": c.knob_play_per_bend,
        "twist_play_per_bend": c.twist_play_per_bend,
        "reversal_threshold": c.reversal_threshold,
        "roll_play": _encode_play(c.roll_play),
        "twist_play": _encode_play(c.twist_play),
    }


def _decode_compensator(r: _Field | None) -> HysteresisCompensator | None:
    if r is None:
        return None
    joints = r.items("joints")
    if len(joints) != 4:
        raise r.error("joints", f"must have 4 entries (phi1, phi2, phi3, d4), got {len(joints)}")
    return r.build(
        lambda: HysteresisCompensator(
            [_decode_joint(j) for j in joints],
            roll_play_per_bend=r.number("roll_play_per_bend"),
            knob_play_per_bend=r.number("knob_play_per_bend"),
            twist_play_per_bend=r.number("twist_play_per_bend"),
            reversal_threshold=r.number("reversal_threshold"),
            roll_play=_decode_play(r.optional("roll_play")),
            twist_play=_decode_play(r.optional("twist_play")),
        )
    )


def _encode_identification(h: HysteresisIdentification) -> dict[str, Any]:
    return _data(
        h,
        compensator=_encode_compensator(h.compensator),
        fits=[_data(f, model=_encode_joint(f.model), gain=list(f.gain)) for f in h.fits],
    )


def _decode_identification(r: _Field) -> HysteresisIdentification:
    fits = []
    for i, fr in enumerate(r.items("fits")):
        if fr is None:
            raise r.error(f"fits[{i}]", "must be a JSON object, got null")
        model = _decode_joint(fr.sub("model"))
        assert model is not None  # sub() refused a null
        g = fr.floats("gain", 3)
        fits.append(HysteresisFit(model=model, gain=(g[0], g[1], g[2]), rms=fr.number("rms")))
    comp = _decode_compensator(r.sub("compensator"))
    assert comp is not None
    return HysteresisIdentification(
        compensator=comp, fits=tuple(fits), n_moves=r.integer("n_moves")
    )


# --- tracker bias, per-tendon transmission -------------------------------------------------------


def _encode_bias(b: TrackerBias) -> dict[str, Any]:
    return _data(
        b,
        offset_mm=b.offset_mm.tolist(),
        gradient=b.gradient.tolist(),
        quadratic=None if b.quadratic is None else b.quadratic.tolist(),
        centre_mm=None if b.centre_mm is None else b.centre_mm.tolist(),
    )


def _decode_bias(r: _Field) -> TrackerBias:
    # files written before the quadratic field (TB2) have neither key: the affine field
    quad = r.array("quadratic", (3, 6)) if r.doc.get("quadratic") is not None else None
    centre = r.array("centre_mm", (3,)) if r.doc.get("centre_mm") is not None else None
    return r.build(
        lambda: TrackerBias(
            offset_mm=r.array("offset_mm", (3,)),
            gradient=r.array("gradient", (3, 3)),
            rms_residual_mm=r.number("rms_residual_mm"),
            n_samples=r.integer("n_samples"),
            quadratic=quad,
            centre_mm=centre,
        )
    )


def _encode_tendons(t: TendonTransmission) -> dict[str, Any]:
    r = t.residual
    res = None if r is None else _data(r, radii=list(r.radii), coefficients=list(r.coefficients))
    return _data(t, ap=_data(t.ap), rl=_data(t.rl), residual=res)


def _decode_residual(r: _Field | None) -> KnobResidual | None:
    if r is None:
        return None
    return r.build(
        lambda: KnobResidual(
            radii=r.floats("radii", -1),
            harmonics=r.integer("harmonics"),
            coefficients=r.floats("coefficients", -1),
        )
    )


def _decode_pair(r: _Field) -> PairTransmission:
    return r.build(
        lambda: PairTransmission(
            slack=r.number("slack"),
            seal_play=r.number("seal_play"),
            tension_play=r.number("tension_play"),
            coupling=r.number("coupling"),
        )
    )


def _decode_tendons(r: _Field) -> TendonTransmission:
    ap, rl = _decode_pair(r.sub("ap")), _decode_pair(r.sub("rl"))
    return r.build(
        lambda: TendonTransmission(
            ap=ap,
            rl=rl,
            wrap=r.number("wrap"),
            friction=r.number("friction"),
            max_substep=r.number("max_substep"),
            # files written before the form was chosen hold the added form (TR3)
            coupling_form=r.text("coupling_form") if "coupling_form" in r.doc else "added",
            # files written before the extensions hold none
            extension=r.text("extension") if "extension" in r.doc else "none",
            bend_tension=r.number("bend_tension") if "bend_tension" in r.doc else 0.0,
            second_weight=r.number("second_weight") if "second_weight" in r.doc else 0.0,
            second_width=r.number("second_width") if "second_width" in r.doc else 1.0,
            # files written before the circle residual hold none
            residual=_decode_residual(r.optional("residual")) if "residual" in r.doc else None,
        )
    )


TENDON_COMPENSATOR_KEYS = ("model", "roll", "knob_limit", "dead_zone_ramp", "xtol")
"""What a :class:`TendonCompensator` is stored as: its constructor's parameters."""


def _encode_transmission(t: TransmissionCalibration) -> dict[str, Any]:
    fit = t.fit
    c = t.compensator
    return _data(
        t,
        fit=_data(
            fit,
            model=_encode_tendons(fit.model),
            static_coefficients=np.asarray(fit.static_coefficients).tolist(),
            held_out_rms=[[name, v] for name, v in fit.held_out_rms],
        ),
        effective_map=_encode_map(t.effective_map),
        compensator={
            "model": _encode_tendons(c.model),
            "roll": _encode_compensator(c.roll),
            "knob_limit": c.knob_limit,
            "dead_zone_ramp": c.dead_zone_ramp,
            "xtol": c.xtol,
        },
        section=_data(t.section),
    )


def _decode_section(r: _Field | None) -> SectionLength:
    if r is None:
        return SectionLength.none()
    return r.build(
        lambda: SectionLength(
            scale=r.number("scale"),
            offset_mm=r.number("offset_mm"),
            rms_residual_mm=r.number("rms_residual_mm"),
            cv_residual_mm=r.number("cv_residual_mm"),
            cv_residual_nominal_mm=r.number("cv_residual_nominal_mm"),
            n_samples=r.integer("n_samples"),
            length_mm=r.number("length_mm"),
        )
    )


def _held_out(f: _Field) -> tuple[tuple[str, float], ...]:
    """``fit.held_out_rms``: a list of [coupling form, residual (rad)] pairs."""
    v = f.get("held_out_rms")
    ok = isinstance(v, list) and all(
        isinstance(x, list)
        and len(x) == 2
        and isinstance(x[0], str)
        and isinstance(x[1], int | float)
        and not isinstance(x[1], bool)
        for x in v
    )
    if not ok:
        raise f.error("held_out_rms", f"must be a list of [form, number] pairs, got {v!r}")
    return tuple((str(x[0]), float(x[1])) for x in v)


def _decode_transmission(r: _Field) -> TransmissionCalibration:
    f = r.sub("fit")
    degree = f.integer("degree")
    rows = (degree + 1) * (degree + 2) // 2
    fit = TransmissionFit(
        model=_decode_tendons(f.sub("model")),
        rms=f.number("rms"),
        rms_without_play=f.number("rms_without_play"),
        static_coefficients=f.array("static_coefficients", (rows, 2)),
        n_samples=f.integer("n_samples"),
        n_evaluations=f.integer("n_evaluations"),
        degree=degree,
        held_out_rms=_held_out(f) if "held_out_rms" in f.doc else (),
    )
    c = r.sub("compensator")
    compensator = c.build(
        lambda: TendonCompensator(
            _decode_tendons(c.sub("model")),
            _decode_compensator(c.optional("roll")),
            knob_limit=c.number("knob_limit"),
            dead_zone_ramp=c.number("dead_zone_ramp"),
            xtol=c.number("xtol"),
        )
    )
    return TransmissionCalibration(
        fit=fit,
        effective_map=_decode_map(r.sub("effective_map")),
        compensator=compensator,
        n_moves=r.integer("n_moves"),
        section=_decode_section(r.optional("section") if "section" in r.doc else None),
    )


# --- the model of a calibration ------------------------------------------------------------------


def encode_model(kind: str, model: Any) -> dict[str, Any]:
    """The JSON object of a calibration's fitted model: an :class:`ElasticityMap` for
    ``dense`` / ``five_point``, a :class:`CatheterCalibration` for ``dense+hysteresis``."""
    if kind in ("dense", "five_point"):
        if not isinstance(model, ElasticityMap):
            raise FileFormatError(
                f"a {kind} calibration's model must be an ElasticityMap, got {type(model).__name__}"
            )
        return {"elasticity_map": _encode_map(model)}
    if kind == "dense+hysteresis":
        if not isinstance(model, CatheterCalibration):
            raise FileFormatError(
                f"a dense+hysteresis calibration's model must be a CatheterCalibration, got "
                f"{type(model).__name__}"
            )
        return _data(
            model,
            dense=model.dense.to_dict(),
            elasticity_map=_encode_map(model.elasticity_map),
            hysteresis=_encode_identification(model.hysteresis),
            tracker_bias=_encode_bias(model.tracker_bias),
            transmission=_encode_transmission(model.transmission),
        )
    raise FileFormatError(f"calibration kind must be one of {MODEL_KINDS}, got {kind!r}")


def decode_model(kind: str, doc: object, source: str) -> Any:
    """Inverse of :func:`encode_model`; FileFormatError naming ``source`` and the field."""
    r = _Field(doc, source, "model")
    if kind in ("dense", "five_point"):
        return _decode_map(r.sub("elasticity_map"))
    if kind == "dense+hysteresis":
        return CatheterCalibration(
            dense=CalibrationSet.from_dict(r.get("dense"), f"{source}: model.dense"),
            elasticity_map=_decode_map(r.sub("elasticity_map")),
            hysteresis=_decode_identification(r.sub("hysteresis")),
            tracker_bias=_decode_bias(r.sub("tracker_bias")),
            transmission=_decode_transmission(r.sub("transmission")),
        )
    raise FileFormatError(f"{source}: kind must be one of {', '.join(MODEL_KINDS)}, got {kind!r}")
