"""Array aliases shared by every module (one definition)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["Array"]

Array = NDArray[np.float64]
"""A float64 array; shapes and units are in each docstring."""
