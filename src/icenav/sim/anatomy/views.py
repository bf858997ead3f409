"""Standard ICE views of the default phantom: joint states and what each should show.

The views follow the clinical ICE sequence from the right atrium (Enriquez et al.,
Circulation 2018; Bartel et al., Eur Heart J 2014): the home view, the septal view for
transseptal puncture and the aortic valve in short axis, plus the valve views of the
recovery evaluation (:data:`icenav.sim.anatomy.EXAMPLE_VIEWS`). Joint states were found by a
search over the knob grid (``docs/figures/make_imaging_figures.py``); each keeps the
transducer in right-atrial blood at least 4 mm from any wall over the beat.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from icenav.sim.anatomy.phantom import EXAMPLE_VIEWS
from icenav.sim.anatomy.tissue import Tissue

__all__ = ["STANDARD_VIEWS", "StandardView"]


@dataclass(frozen=True)
class StandardView:
    """A standard ICE view of the default phantom."""

    key: str
    """Identifier (``home``, ``septal``, ...)."""
    title: str
    """Name a clinician uses."""
    q: tuple[float, float, float, float]
    """Model joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm) of the default geometry."""
    structures: tuple[Tissue, ...]
    """Labels the view must contain (a test checks each in the label map)."""
    description: str
    """What the picture should show, near field (top) to far field."""


def _q(
    phi1_deg: float, phi2_deg: float, phi3_deg: float, d4_mm: float
) -> tuple[float, float, float, float]:
    return (math.radians(phi1_deg), math.radians(phi2_deg), math.radians(phi3_deg), d4_mm)


STANDARD_VIEWS: dict[str, StandardView] = {
    "home": StandardView(
        "home",
        "home view",
        _q(0.0, 0.0, 45.0, -20.0),
        (Tissue.RA_BLOOD, Tissue.TRICUSPID_VALVE, Tissue.RV_BLOOD),
        "Neutral catheter in the mid right atrium facing anteriorly and leftwards: the RA "
        "in the near field, the tricuspid valve leaflets at 3-4 cm, the right ventricle "
        "beyond them with its outflow tract towards the distal (right) side, the "
        "pericardium as the brightest line, mediastinal tissue in the far field.",
    ),
    "septal": StandardView(
        "septal",
        "septal view (transseptal puncture)",
        _q(20.0, 0.0, 105.0, 10.0),
        (Tissue.RA_BLOOD, Tissue.SEPTUM, Tissue.LA_BLOOD),
        "Rotated clockwise from the home view to face the interatrial septum: the septum "
        "as a bright band across the near field, the left atrium behind it, and the mitral "
        "apparatus or the left ventricle in the far field.",
    ),
    "aortic_valve_short_axis": StandardView(
        "aortic_valve_short_axis",
        "aortic valve, short axis",
        _q(-10.0, 20.0, 50.0, 5.0),
        (Tissue.RA_BLOOD, Tissue.AORTIC_VALVE, Tissue.AORTA_BLOOD),
        "Flexed and rotated towards the aortic root: the root in cross-section, cusps "
        "closed in diastole (the three-cusp 'Mercedes' pattern) and open in systole; the "
        "plane is 31 deg from the true short axis (the best a transducer kept in the RA "
        "reaches in this phantom), so the root reads as an ellipse.",
    ),
    "mitral_valve": StandardView(
        "mitral_valve",
        "mitral valve",
        tuple(EXAMPLE_VIEWS["mitral_valve"]),  # type: ignore[arg-type]
        (Tissue.RA_BLOOD, Tissue.MITRAL_VALVE, Tissue.LA_BLOOD),
        "Through the septum to the left heart: the left atrium, the mitral leaflets "
        "opening into the left ventricle in diastole.",
    ),
    "tricuspid_valve": StandardView(
        "tricuspid_valve",
        "tricuspid valve",
        tuple(EXAMPLE_VIEWS["tricuspid_valve"]),  # type: ignore[arg-type]
        (Tissue.RA_BLOOD, Tissue.TRICUSPID_VALVE, Tissue.RV_BLOOD),
        "Low in the RA, looking at the tricuspid annulus: leaflets open into the RV in "
        "diastole and meet in systole.",
    ),
}
"""The standard views, by key (see :class:`StandardView`)."""
