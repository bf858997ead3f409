"""Calibration files: a calibration's tracked samples, the registration they were measured
through and, from version 3, the compensation the fit produced, as one versioned JSON
document.

The document is :meth:`icenav.compensation.elasticity.CalibrationSet.to_dict` (``format``
``icenav.calibration.plans``) plus:

- ``registration`` (when known): the :meth:`icenav.devices.registration.Registration.to_dict`
  of the tracker's registration (``tracker2base``, ``sensor2tip``, residuals; its own
  ``format`` number);
- version 3: ``kind`` (``dense``, ``five_point`` or ``dense+hysteresis``) and ``model``, the
  fitted compensation (:mod:`icenav.calibration.model_files`): the paper's F, or for
  ``dense+hysteresis`` the per-tendon / hysteresis model whose knob map the controller
  installs;
- version 4: the same, the roll's and the twist's plays as laws over the knob plane (the
  bend and its direction). A file is written with the oldest version that holds its model
  (3 when every play is a law of the bend alone), and a version 3 file's laws load as the
  same law in every direction.

:meth:`CalibrationFile.compensation` gives the controller's compensation: the stored model
(v3), or for version 1 and 2 files (samples only; version 1 has no registration either) the
paper's F built on the samples, as before.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from icenav.calibration.catheter import CatheterCalibration
from icenav.calibration.model_files import (
    MODEL_KINDS,
    decode_model,
    encode_model,
    needs_knob_plane,
)
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.devices.registration import Registration
from icenav.errors import ConfigurationError, FileFormatError, UnsupportedVersionError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry

__all__ = ["CALIBRATION_FILE_VERSION", "CalibrationFile"]

CALIBRATION_FILE_VERSION = 4
"""The newest version :meth:`CalibrationFile.save` writes (when the model holds a play over the
knob plane; 3 for any other model; 1 to 4 load)."""
_MODEL_VERSIONS = (3, 4)  # the versions with a kind and a model
_SAMPLES_VERSION = 2  # the samples' own document (CalibrationSet) inside a version 3 or 4 file


@dataclass(frozen=True, eq=False)
class CalibrationFile:
    """A calibration as it is saved and loaded."""

    calibration: CalibrationSet
    """The motor joint states and the tracked tip poses (base frame, mm)."""
    registration: Registration | None = None
    """The tracker's registration the tip poses were measured through; None: not recorded."""
    kind: str = ""
    """``dense``, ``five_point`` or ``dense+hysteresis``; "" for a file without a model
    (version 1 or 2)."""
    model: Any = None
    """The fitted compensation: an :class:`ElasticityMap` (``dense``, ``five_point``) or a
    :class:`~icenav.calibration.catheter.CatheterCalibration` (``dense+hysteresis``); None:
    samples only (F is built from them)."""

    def __post_init__(self) -> None:
        if not isinstance(self.calibration, CalibrationSet):
            raise FileFormatError(
                f"calibration must be a CalibrationSet, got {type(self.calibration).__name__}"
            )
        if self.registration is not None and not isinstance(self.registration, Registration):
            raise FileFormatError(
                f"registration must be a Registration or None, got "
                f"{type(self.registration).__name__}"
            )
        if (self.model is None) != (self.kind == ""):
            raise FileFormatError(
                f"a calibration file has both a kind and a model or neither, got kind "
                f"{self.kind!r} and model {type(self.model).__name__}"
            )
        if self.kind and self.kind not in MODEL_KINDS:
            raise FileFormatError(f"kind must be one of {MODEL_KINDS}, got {self.kind!r}")
        if self.kind == "dense+hysteresis" and not isinstance(self.model, CatheterCalibration):
            raise FileFormatError(
                f"a dense+hysteresis model must be a CatheterCalibration, got "
                f"{type(self.model).__name__}"
            )
        if self.kind in ("dense", "five_point") and not isinstance(self.model, ElasticityMap):
            raise FileFormatError(
                f"a {self.kind} model must be an ElasticityMap, got {type(self.model).__name__}"
            )

    @classmethod
    def from_outcome(
        cls,
        outcome: Any,
        registration: Registration | None = None,
        *,
        catheter_id: str | None = None,
        notes: str | None = None,
    ) -> CalibrationFile:
        """The file of a :class:`~icenav.calibration.procedure.CalibrationOutcome` of kind
        ``dense``, ``five_point`` or ``dense+hysteresis`` (the samples, and the model: the
        outcome's F, or its :class:`CatheterCalibration`); ``catheter_id`` / ``notes``
        replace the samples' own when given."""
        kind = getattr(outcome, "kind", None)
        if kind not in MODEL_KINDS:
            raise ConfigurationError(
                f"a calibration file holds a {', '.join(MODEL_KINDS)} calibration, got {kind!r}"
            )
        cal = outcome.calibration_set
        changes = {
            k: v for k, v in (("catheter_id", catheter_id), ("notes", notes)) if v is not None
        }
        if changes:
            cal = replace(cal, **changes)
        model = outcome.details if kind == "dense+hysteresis" else outcome.knob_map
        return cls(calibration=cal, registration=registration, kind=kind, model=model)

    def compensation(self, geometry: CatheterGeometry = DEFAULT_GEOMETRY) -> Any:
        """The controller's compensation (``model_to_motor`` / ``motor_to_model``): the
        ``dense+hysteresis`` knob map (:class:`~icenav.compensation.tendon_map.TendonKnobMap`,
        a new one, relaxed at zeros), the stored F of ``dense`` / ``five_point``, or F built
        on the samples (a file without a model). ConfigurationError when the model was
        fitted for another catheter geometry."""
        if self.model is None:
            return ElasticityMap.build(self.calibration, geometry)
        fitted = (
            self.model.elasticity_map.geometry
            if isinstance(self.model, CatheterCalibration)
            else self.model.geometry
        )
        if fitted != geometry:
            raise ConfigurationError(
                f"the calibration was fitted for catheter geometry {fitted}, not {geometry}: "
                "calibrate this catheter again"
            )
        if isinstance(self.model, CatheterCalibration):
            return self.model.knob_map(geometry=geometry)
        return self.model

    def describe(self) -> str:
        """What the file holds, for the operator."""
        cal = self.calibration
        what = self.kind or cal.method or "samples only"
        text = f"{cal.n_samples} samples ({what})"
        if self.model is None:
            text += "; F built on the samples (a file without a fitted model)"
        if self.registration is not None:
            text += (
                f", recorded through a registration of "
                f"{self.registration.rms_residual_mm:.2f} mm RMS"
            )
        return text

    def to_dict(self) -> dict[str, Any]:
        """The JSON document (version 4 with a play over the knob plane, 3 with another
        model, else version 2)."""
        doc = self.calibration.to_dict()
        if self.registration is not None:
            doc["registration"] = self.registration.to_dict()
        if self.model is not None:
            doc["version"] = CALIBRATION_FILE_VERSION if needs_knob_plane(self.model) else 3
            doc["kind"] = self.kind
            doc["model"] = encode_model(self.kind, self.model)
        return doc

    @classmethod
    def from_dict(cls, doc: object, source: str = "calibration document") -> CalibrationFile:
        """Parse a document (version 1 to 4); FileFormatError naming ``source`` and the
        field."""
        if not isinstance(doc, dict):
            raise FileFormatError(f"{source}: expected a JSON object, got {type(doc).__name__}")
        version = doc.get("version")
        if (
            isinstance(version, int)
            and not isinstance(version, bool)
            and not 1 <= version <= CALIBRATION_FILE_VERSION
        ):
            raise UnsupportedVersionError(
                f"{source}: calibration file version {version} is not supported; this "
                f"icenav reads versions 1..{CALIBRATION_FILE_VERSION} (upgrade icenav to "
                "read newer files)"
            )
        samples = dict(doc, version=_SAMPLES_VERSION) if version in _MODEL_VERSIONS else doc
        cal = CalibrationSet.from_dict(samples, source)
        reg = doc.get("registration")
        registration = (
            None if reg is None else Registration.from_dict(reg, f"{source}: registration")
        )
        if version not in _MODEL_VERSIONS:
            return cls(calibration=cal, registration=registration)
        kind = doc.get("kind")
        if kind not in MODEL_KINDS:
            raise FileFormatError(
                f"{source}: kind must be one of {', '.join(MODEL_KINDS)}, got {kind!r}"
            )
        if "model" not in doc:
            raise FileFormatError(f"{source}: model is missing (a version {version} file has one)")
        model = decode_model(kind, doc["model"], source)
        return cls(calibration=cal, registration=registration, kind=kind, model=model)

    def save(self, path: str | Path) -> None:
        """Write the versioned JSON file."""
        Path(path).write_text(json.dumps(self.to_dict()) + "\n", encoding="utf-8")

    @classmethod
    def load(cls, path: str | Path) -> CalibrationFile:
        """Read a file written by :meth:`save` (or by :meth:`CalibrationSet.save`)."""
        p = Path(path)
        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
        except UnicodeDecodeError as exc:
            raise FileFormatError(f"{p}: not a text (JSON) file") from exc
        except json.JSONDecodeError as exc:
            raise FileFormatError(f"{p}: not valid JSON ({exc.msg} at line {exc.lineno})") from exc
        except FileNotFoundError as exc:
            raise FileFormatError(f"{p}: no such calibration file") from exc
        except OSError as exc:  # a folder, no permission, ...
            raise FileFormatError(f"{p}: cannot be read ({exc.strerror or exc})") from exc
        return cls.from_dict(doc, source=str(p))
