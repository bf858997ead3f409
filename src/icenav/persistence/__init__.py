"""icenav.persistence."""
