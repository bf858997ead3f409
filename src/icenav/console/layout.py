"""The page's layout: the panels' widths and the CSS rules viser cannot express (the sticky
safety bar, the picture fitting the window's height, the red banners, the narrow-window
media query; docs/console.md)."""

from __future__ import annotations

__all__ = ["CONTROL_PANEL_PX", "IMAGE_DISPLAY_PX", "IMAGE_PANEL_PX", "IMAGE_PANEL_VW", "PAGE_CSS"]

IMAGE_PANEL_PX = 880
"""Width of the ICE image panel (CSS pixels) in a window of at least 1900 pixels (46 % of
a full-HD one). viser docks panels by pixel width only; in narrower windows ``PAGE_CSS``
narrows the panel to ``IMAGE_PANEL_VW`` of the window, so the 3-D scene keeps room."""
IMAGE_PANEL_VW = 46
"""The image panel's width in windows narrower than 1900 pixels (% of the window)."""
CONTROL_PANEL_PX = 360
"""Width of the control panel (CSS pixels)."""
_DOCK_PX = 4
"""What viser adds to a docked panel's width (its resize handle; CSS pixels)."""
IMAGE_DISPLAY_PX = 800
"""Width of the displayed ICE picture's image part (pixels; the browser scales it down to
the panel, and to the window's height: ``PAGE_CSS``)."""
PAGE_CSS = (
    """<style>
/* the safety bar (the block holding .icenav-safety) stays at the top of its panel */
div:has(> div:nth-child(3)) > div:has(.icenav-safety) {
  position: sticky; top: 0; z-index: 20; background: var(--mantine-color-body);
}
/* ... which needs no box between it and the panel's scroll area to clip by "hidden" */
[data-scrollarea-viewport] div:has(.icenav-safety):not([data-scrollarea-viewport]) {
  overflow: clip !important;
}
/* the ICE picture fits the window's height (aspect kept) */
[data-dock-region="left"] img[src^="blob:"] {
  max-height: calc(100vh - 170px); width: auto; max-width: 100%; margin: 0 auto;
}
.icenav-banner { background: #c92a2a; color: white; padding: 0.4em 0.6em; border-radius: 4px; }
"""
    # In a window narrower than 1900 px the image panel takes IMAGE_PANEL_VW % of it, and the
    # 3-D scene's canvas starts where the panel ends. The selectors match only while the
    # panels have the widths the console gave them: once the operator drags a panel's edge or
    # minimizes it, viser's own layout applies unchanged.
    + f"""@media (max-width: 1899px) {{
  [style*="width: {IMAGE_PANEL_PX + _DOCK_PX}px"] {{ width: {IMAGE_PANEL_VW}vw !important; }}
  [style*="left: calc(1em + {IMAGE_PANEL_PX + _DOCK_PX}px)"] {{
    left: calc(1em + {IMAGE_PANEL_VW}vw) !important;
  }}
  div[style*="inset: 0px {CONTROL_PANEL_PX + _DOCK_PX}px 0px {IMAGE_PANEL_PX + _DOCK_PX}px"] {{
    left: {IMAGE_PANEL_VW}vw !important;
  }}
}}
</style><span class="icenav-safety"></span>"""
)
