"""icenav.compensation."""
