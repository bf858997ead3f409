"""Calibration files: the tracked samples of a calibration with the registration they were
measured through, as one versioned JSON document.

The document is :meth:`icenav.compensation.elasticity.CalibrationSet.to_dict` (``format``
``icenav.calibration.plans``, ``version`` 2) plus, when known, ``registration``: the
:meth:`icenav.devices.registration.Registration.to_dict` of the tracker's registration
(``tracker2base``, ``sensor2tip``, residuals; its own ``format`` number). Version 1 files (no
registration) still load; their registration is None.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from icenav.compensation.elasticity import CalibrationSet
from icenav.devices.registration import Registration
from icenav.errors import FileFormatError

__all__ = ["CalibrationFile"]


@dataclass(frozen=True, eq=False)
class CalibrationFile:
    """A calibration as it is saved and loaded."""

    calibration: CalibrationSet
    """The motor joint states and the tracked tip poses (base frame, mm)."""
    registration: Registration | None = None
    """The tracker's registration the tip poses were measured through; None: not recorded."""

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

    def to_dict(self) -> dict[str, Any]:
        """The JSON document."""
        doc = self.calibration.to_dict()
        if self.registration is not None:
            doc["registration"] = self.registration.to_dict()
        return doc

    @classmethod
    def from_dict(cls, doc: object, source: str = "calibration document") -> CalibrationFile:
        """Parse a document (version 1 or 2); FileFormatError naming ``source``."""
        cal = CalibrationSet.from_dict(doc, source)
        assert isinstance(doc, dict)  # from_dict refused anything else
        reg = doc.get("registration")
        registration = (
            None if reg is None else Registration.from_dict(reg, f"{source}: registration")
        )
        return cls(calibration=cal, registration=registration)

    def save(self, path: str | Path) -> None:
        """Write the versioned JSON file."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=1) + "\n", encoding="utf-8")

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
