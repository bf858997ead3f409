"""icenav.calibration."""
