"""Tissue labels of the heart phantom and their acoustic properties.

Each label has an acoustic impedance (sets the specular reflection and transmission at an
interface), an attenuation coefficient (dB/cm/MHz, linear in frequency) and a diffuse
backscatter level (dB relative to myocardium). Values and sources: ``docs/imaging.md``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

__all__ = [
    "ACOUSTICS",
    "BLOOD_LABELS",
    "ECHOGENICITY",
    "ROI_LABELS",
    "AcousticProperties",
    "Tissue",
]


class Tissue(enum.IntEnum):
    """Label of a point of the phantom."""

    SURROUNDING = 0
    """Outside the heart: epicardial and mediastinal fat, connective tissue, chest wall."""
    MYOCARDIUM = 1
    """Heart wall."""
    VESSEL_WALL = 2
    """Wall of the venae cavae, the aorta and the pulmonary artery."""
    RA_BLOOD = 3
    """Right atrium cavity."""
    RV_BLOOD = 4
    """Right ventricle cavity (with its outflow tract)."""
    LA_BLOOD = 5
    """Left atrium cavity."""
    LV_BLOOD = 6
    """Left ventricle cavity (with its outflow tract)."""
    AORTA_BLOOD = 7
    """Aortic root and ascending aorta lumen."""
    CAVA_BLOOD = 8
    """Inferior and superior vena cava lumen."""
    SEPTUM = 9
    """Interatrial septum."""
    TRICUSPID_VALVE = 10
    """Tricuspid annulus and leaflets."""
    MITRAL_VALVE = 11
    """Mitral annulus and leaflets."""
    AORTIC_VALVE = 12
    """Aortic annulus and cusps."""
    PA_BLOOD = 13
    """Pulmonary artery trunk lumen."""
    PERICARDIUM = 14
    """Fibrous pericardium around the heart."""
    LUNG = 15
    """Aerated lung (outside the pericardium, left and right)."""
    CALCIFICATION = 16
    """Calcified tissue (annular calcification, a calcified nodule): a strong reflector."""


BLOOD_LABELS: frozenset[Tissue] = frozenset(
    {
        Tissue.RA_BLOOD,
        Tissue.RV_BLOOD,
        Tissue.LA_BLOOD,
        Tissue.LV_BLOOD,
        Tissue.AORTA_BLOOD,
        Tissue.CAVA_BLOOD,
        Tissue.PA_BLOOD,
    }
)
"""Labels of blood pools."""


@dataclass(frozen=True)
class AcousticProperties:
    """Acoustic properties of one tissue (sources in ``docs/imaging.md``)."""

    impedance_mrayl: float
    """Characteristic acoustic impedance Z = rho c (MRayl = 1e6 kg m^-2 s^-1)."""
    attenuation_db_cm_mhz: float
    """Attenuation coefficient (dB/cm/MHz; one way, linear in frequency)."""
    backscatter_db: float
    """Diffuse backscatter amplitude relative to myocardium (dB)."""

    @property
    def backscatter(self) -> float:
        """Diffuse backscatter amplitude relative to myocardium (linear)."""
        return float(10.0 ** (self.backscatter_db / 20.0))


_BLOOD = AcousticProperties(1.68, 0.15, -40.0)
_CONNECTIVE = 1.57  # dB/cm/MHz, collagen-rich connective tissue

ACOUSTICS: dict[Tissue, AcousticProperties] = {
    Tissue.SURROUNDING: AcousticProperties(1.38, 0.63, -6.0),  # fat
    Tissue.MYOCARDIUM: AcousticProperties(1.74, 0.52, 0.0),
    Tissue.VESSEL_WALL: AcousticProperties(1.80, 1.0, 4.0),
    Tissue.RA_BLOOD: _BLOOD,
    Tissue.RV_BLOOD: _BLOOD,
    Tissue.LA_BLOOD: _BLOOD,
    Tissue.LV_BLOOD: _BLOOD,
    Tissue.AORTA_BLOOD: _BLOOD,
    Tissue.CAVA_BLOOD: _BLOOD,
    Tissue.PA_BLOOD: _BLOOD,
    Tissue.SEPTUM: AcousticProperties(1.78, 0.8, 2.0),
    Tissue.TRICUSPID_VALVE: AcousticProperties(1.90, _CONNECTIVE, 8.0),
    Tissue.MITRAL_VALVE: AcousticProperties(1.90, _CONNECTIVE, 8.0),
    Tissue.AORTIC_VALVE: AcousticProperties(1.90, _CONNECTIVE, 8.0),
    Tissue.PERICARDIUM: AcousticProperties(1.95, _CONNECTIVE, 10.0),
    Tissue.LUNG: AcousticProperties(0.26, 40.0, 6.0),
    Tissue.CALCIFICATION: AcousticProperties(6.5, 15.0, 16.0),
}
"""Acoustic properties of every label (impedance, attenuation, diffuse backscatter)."""

ECHOGENICITY: dict[Tissue, float] = {t: p.backscatter for t, p in ACOUSTICS.items()}
"""Relative diffuse backscatter amplitude of each tissue (myocardium 1; blood nearly 0)."""

ROI_LABELS: dict[str, Tissue] = {
    "aortic_valve": Tissue.AORTIC_VALVE,
    "interatrial_septum": Tissue.SEPTUM,
    "mitral_valve": Tissue.MITRAL_VALVE,
    "tricuspid_valve": Tissue.TRICUSPID_VALVE,
}
"""Named regions of interest and the label that marks each in a label map."""
