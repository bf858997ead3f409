"""Family ``out-of-tolerance``: the default twin's laws, every parameter 2-3x outside today's
tolerance band.

Each field of :class:`~icenav.sim.params.PlantParams` is moved from its nominal value by
``m * tolerance`` (:data:`~icenav.sim.params.TOLERANCES`, relative or absolute), ``m``
uniform in [2, 3] with a random sign, so *every* parameter lies outside the band today's
catheters are drawn from (a catheter from another production lot, another maker's
similar catheter, or one aged by use)::

    theta_k = theta_k,nominal (1 +- m_k tol_k)      (relative tolerance)          (O1)
    theta_k = theta_k,nominal +- m_k tol_k          (absolute tolerance),  m_k ~ U[2, 3]

The laws are the default twin's (:class:`~icenav.sim.plant.CatheterPlant`), so this family
shares the forms our compensation models (the capstan band, ``h0 + h1 bend``); it is the
one family that does, on purpose: it asks whether identification holds over a parameter
range wider than the one the methods were developed on, not whether its forms are general.
"""

from __future__ import annotations

from icenav.sim.families.base import family_rng, sample_params
from icenav.sim.params import PlantParams, Vessel
from icenav.sim.plant import CatheterPlant

__all__ = ["OUT_OF_TOLERANCE_SPREAD", "out_of_tolerance_params", "out_of_tolerance_plant"]

TAG = 0x0071
"""Random-stream tag of the family."""
OUT_OF_TOLERANCE_SPREAD = (2.0, 3.0)
"""Range of ``m`` in (O1): multiples of today's tolerance."""


def out_of_tolerance_params(seed: int) -> PlantParams:
    """The parameters (O1) of catheter ``seed`` of the family."""
    return sample_params(family_rng(seed, TAG), OUT_OF_TOLERANCE_SPREAD)


def out_of_tolerance_plant(seed: int, vessel: str | Vessel = "straight") -> CatheterPlant:
    """The default twin's plant with the out-of-tolerance parameters of ``seed``."""
    return CatheterPlant(seed=seed, vessel=vessel, params=out_of_tolerance_params(seed))
