"""icenav.geometry."""
