"""The page's layout: the panels' widths and the CSS rules viser cannot express (the sticky
safety bar, the picture fitting the window's height, the red banners, the narrow-window
media query; docs/console.md)."""

from __future__ import annotations

__all__ = [
    "ALARM_AREA_EM",
    "CONTROL_PANEL_PX",
    "FEEDBACK_SLOT",
    "FEEDBACK_SLOT_EM",
    "IMAGE_DISPLAY_PX",
    "IMAGE_PANEL_PX",
    "IMAGE_PANEL_VW",
    "JOG_GUARD_JS",
    "PAGE_CSS",
    "STATUS_SLOT",
    "STATUS_SLOT_EM",
]

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
ALARM_AREA_EM = 10.0
"""Height of the safety bar's alarm area (em): the halt banner (title, cause, what clears
it) at the control panel's width; reserved whether a banner is shown or not."""
STATUS_SLOT_EM = 4.6
"""Height reserved for the safety bar's status line (em: three lines)."""
FEEDBACK_SLOT_EM = 3.1
"""Height reserved for a browser's feedback line above its tabs (em: two lines; longer
answers scroll inside it)."""
STATUS_SLOT = '<span class="icenav-status-slot"></span>'
"""Marks the status line's markdown (its reserved height: ``PAGE_CSS``)."""
FEEDBACK_SLOT = '<span class="icenav-feedback-slot"></span>'
"""Marks a browser's feedback markdown (its reserved height: ``PAGE_CSS``)."""
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
.icenav-banner + .icenav-banner { margin-top: 0.3em; }
.icenav-clear { color: var(--mantine-color-dimmed); padding: 0.4em 0.6em; }
"""
    # Reserved heights: a banner, a status line or an answer that comes, goes or wraps
    # differently moves no control below it (a held jog button stays under the pointer).
    + f""".icenav-alarm {{ height: {ALARM_AREA_EM}em; overflow-y: auto; }}
p:has(> .icenav-status-slot) {{ height: {STATUS_SLOT_EM}em; overflow-y: auto; margin: 0; }}
p:has(> .icenav-feedback-slot) {{ height: {FEEDBACK_SLOT_EM}em; overflow-y: auto; margin: 0; }}
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

JOG_GUARD_JS = """((ids) => {
  // icenav's jog guard: a held jog button's press ends (and the release is sent) when the
  // pointer leaves the button, the button moves from under the pointer, the window loses
  // the focus or the page is hidden. viser's button keeps its hold timer running until
  // pointer-up (it captures the pointer), so without this a press dragged off the button
  // or a window switched away from kept jogging until the server's dead-man.
  const g = window.__icenavJogGuard
    || (window.__icenavJogGuard = {ids: new Set(), held: null, x: 0, y: 0, log: []});
  ids.forEach((i) => g.ids.add(i));
  if (g.installed) return;
  g.installed = true;
  const note = (what, b) => {
    g.log.push({what, t: Math.round(performance.now()), button: b ? b.textContent.trim() : null});
    if (g.log.length > 100) g.log.shift();
  };
  const jogButton = (t) => {
    const b = t && t.closest ? t.closest('button') : null;
    return b && g.ids.has(b.id) ? b : null;
  };
  const end = (why) => {
    const h = g.held;
    if (!h) return;
    g.held = null;
    clearInterval(h.timer);
    note(why, h.button);
    // viser's button stops its hold timer on pointercancel; its click is the release
    h.target.dispatchEvent(new PointerEvent('pointercancel', {bubbles: true, pointerId: h.id}));
    h.button.click();
  };
  const check = (why) => {
    const h = g.held;
    if (!h) return;
    const r = h.button.getBoundingClientRect();
    if (!h.button.isConnected || h.button.disabled || g.x < r.left || g.x > r.right
        || g.y < r.top || g.y > r.bottom) end(why);
  };
  addEventListener('pointerdown', (e) => {
    const b = jogButton(e.target);
    if (!b || e.button !== 0) return;
    end('another press');
    g.x = e.clientX; g.y = e.clientY;
    g.held = {button: b, target: e.target, id: e.pointerId,
              timer: setInterval(() => check('the button moved from under the pointer'), 50)};
    note('press', b);
  }, true);
  addEventListener('pointermove', (e) => {
    g.x = e.clientX; g.y = e.clientY;
    check('the pointer left the button');
  }, true);
  const up = (e) => {
    const h = g.held;
    if (h && e.isTrusted && e.pointerId === h.id) {
      g.held = null; clearInterval(h.timer); note(e.type, h.button);
    }
  };
  addEventListener('pointerup', up, true);
  addEventListener('pointercancel', up, true);
  addEventListener('blur', () => end('the window lost the focus'));
  addEventListener('pagehide', () => end('the page was left'));
  document.addEventListener('visibilitychange', () => {
    if (document.hidden) end('the page was hidden');
  });
})"""
"""The page's jog guard (JavaScript: a function of the jog buttons' element ids, called
once per browser on connection; :mod:`icenav.console.jog_controls`)."""
