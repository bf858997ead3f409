"""icenav.apps."""
