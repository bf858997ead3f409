"""icenav.refinement."""
