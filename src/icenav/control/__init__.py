"""icenav.control."""
