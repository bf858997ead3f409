"""icenav.recovery."""
