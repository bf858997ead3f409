"""The ICE image as the console displays it: display gain and depth, a depth scale in cm,
the sector's orientation marker and an ECG strip, drawn into one RGB picture (Pillow).

The overlays are drawn into the picture, as an ultrasound system draws them, so they scale
with it in the browser. Pure functions, no viser.

Frames and units
----------------
Pixel (i = column, j = row) maps to the tip frame (mm) through the frame's ``ijk2tip``; the
depth of a row is the distance from the transducer (the tip frame's origin) of its pixel in
the middle column. The orientation marker sits on the side of the sector towards the
catheter tip (the side where the column axis points along +z of the tip frame, distal).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from PIL import Image, ImageDraw, ImageFont

from icenav._typing import Array
from icenav.errors import ConfigurationError, ShapeError

__all__ = [
    "DisplaySettings",
    "ECG_WINDOW_S",
    "ImageGeometry",
    "check_display_settings",
    "ecg_mv",
    "ecg_samples",
    "heart_rate_bpm",
    "image_geometry",
    "imaged_depth_cm",
    "imaged_rows",
    "render_display",
]

DISPLAY_DYNAMIC_RANGE_DB = 55.0
"""Dynamic range the console assumes for an 8-bit log-compressed B-mode image (dB over 255
grey levels; the twin's ``ProbeConfig.dynamic_range_db``): display gain g dB adds
255 g / 55 grey levels."""
ECG_WINDOW_S = 3.0
"""Seconds of ECG the strip shows (the newest at the right)."""
SCALE_MARGIN_PX = 46
"""Width of the depth-scale margin at the right of the image (display pixels)."""
ECG_STRIP_PX = 84
"""Height of the ECG strip below the image (display pixels)."""
MARKER_RGB = (255, 170, 0)
ECG_RGB = (60, 230, 90)

# McSharry, Clifford, Tarassenko & Smith (2003), "A dynamical model for generating synthetic
# electrocardiogram signals", IEEE Trans. Biomed. Eng. 50(3):289-294, Table 1: P, Q, R, S, T
# at angles theta_i (rad) with amplitudes a_i and widths b_i (rad). Integrated over one beat
# at constant angular speed, each Gaussian term of dz/dt gives a wave of height ~ a_i b_i^2.
_ECG_THETA = np.array([-math.pi / 3, -math.pi / 12, 0.0, math.pi / 12, math.pi / 2])
_ECG_A = np.array([1.2, -5.0, 30.0, -7.5, 0.75])
_ECG_B = np.array([0.25, 0.1, 0.1, 0.1, 0.4])
_ECG_R_MV = 1.2
"""Height of the R wave (mV, a lead II R wave)."""


def ecg_mv(phase: ArrayLike) -> Array:
    """A lead-II-like ECG (mV) at cardiac ``phase`` (fraction of the beat, 0 = R wave),
    shaped by the P, Q, R, S, T terms of McSharry et al. (2003); same shape as ``phase``."""
    p = np.asarray(phase, dtype=np.float64)
    theta = np.angle(np.exp(2j * math.pi * p))[..., None]  # in (-pi, pi]
    d = np.angle(np.exp(1j * (theta - _ECG_THETA)))
    waves = _ECG_A * _ECG_B**2 * np.exp(-(d**2) / (2.0 * _ECG_B**2))
    peak = float(_ECG_A[2] * _ECG_B[2] ** 2)
    return np.asarray(waves.sum(axis=-1) * (_ECG_R_MV / peak))


@dataclass(frozen=True)
class DisplaySettings:
    """The operator's display settings (they change the picture, not the acquisition)."""

    gain_db: float = 0.0
    """Display gain (dB), in [-20, 20]: brightens or darkens the log-compressed image."""
    depth_cm: float | None = None
    """Displayed depth (cm), >= 2; None shows the image's full depth."""


def check_display_settings(s: DisplaySettings) -> DisplaySettings:
    """``s`` if its values are in range, else a ConfigurationError naming the value."""
    if not (math.isfinite(s.gain_db) and -20.0 <= s.gain_db <= 20.0):
        raise ConfigurationError(f"display gain must be in [-20, 20] dB, got {s.gain_db}")
    if s.depth_cm is not None and not (math.isfinite(s.depth_cm) and s.depth_cm >= 2.0):
        raise ConfigurationError(f"display depth must be >= 2 cm, got {s.depth_cm}")
    return s


@dataclass(frozen=True)
class ImageGeometry:
    """Where an image's rows lie in depth, and which side is towards the catheter tip."""

    row_depth_mm: Array
    """(H,) depth of each row (mm from the transducer, middle column)."""
    distal_right: bool
    """True when the column axis points distally (the marker goes at the right)."""


def image_geometry(ijk2tip: ArrayLike, shape: tuple[int, int]) -> ImageGeometry | None:
    """The depth of each row and the marker side of an (H, W) image; None when ``ijk2tip``
    is the identity (the imager did not say where its pixels are)."""
    m = np.asarray(ijk2tip, dtype=np.float64)
    if m.shape != (4, 4):
        raise ShapeError(f"ijk2tip must have shape (4, 4), got {m.shape}")
    if np.array_equal(m, np.eye(4)):
        return None
    h, w = shape
    rows = np.stack([np.full(h, (w - 1) / 2.0), np.arange(h, dtype=np.float64)])
    pts = m[:3, :2] @ rows + m[:3, 3:4]
    return ImageGeometry(np.linalg.norm(pts, axis=0), bool(m[2, 0] > 0))


def imaged_rows(pixels: NDArray[np.uint8]) -> int:
    """Rows down to the deepest one with any echo (the blank rows below a sector are cut);
    at least 2."""
    p = np.asarray(pixels)
    lit = np.flatnonzero(p.reshape(p.shape[0], -1).max(axis=1) > 0)
    return max(2, int(lit[-1]) + 1) if len(lit) else p.shape[0]


def imaged_depth_cm(pixels: NDArray[np.uint8], ijk2tip: ArrayLike) -> float | None:
    """Depth (cm) of the deepest row with any echo; None without a placement."""
    geo = image_geometry(ijk2tip, (pixels.shape[0], pixels.shape[1]))
    if geo is None:
        return None
    return float(geo.row_depth_mm[imaged_rows(pixels) - 1]) / 10.0


@functools.lru_cache(maxsize=8)
def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        return ImageFont.load_default()


def render_display(
    pixels: NDArray[np.uint8],
    ijk2tip: ArrayLike,
    width_px: int,
    settings: DisplaySettings = DisplaySettings(),
    ecg: tuple[Array, Array] | None = None,
    ecg_note: str = "",
) -> NDArray[np.uint8]:
    """The displayed picture of an (H, W) B-mode image.

    Parameters
    ----------
    pixels : (H, W) uint8
        The B-mode image (row 0 at the transducer).
    ijk2tip : (4, 4)
        Pixel to tip frame (mm); the identity draws no depth scale and no marker.
    width_px : int
        Width of the image part of the picture (display pixels, >= 64); the depth scale
        adds :data:`SCALE_MARGIN_PX`.
    settings : DisplaySettings
        Display gain and depth.
    ecg : ((n,) seconds before now, (n,) mV), optional
        The ECG of the last :data:`ECG_WINDOW_S` seconds; None draws no strip.
    ecg_note : str
        Text at the strip's top left (the source of the ECG, the phase).

    Returns
    -------
    (h, width_px + SCALE_MARGIN_PX, 3) uint8 RGB picture; the image keeps its aspect.
    """
    p = np.asarray(pixels)
    if p.ndim != 2:
        raise ShapeError(f"pixels must be (H, W), got {p.shape}")
    if width_px < 64:
        raise ConfigurationError(f"width_px must be >= 64 pixels, got {width_px}")
    check_display_settings(settings)
    geo = image_geometry(ijk2tip, (p.shape[0], p.shape[1]))
    rows = imaged_rows(p)
    if geo is not None and settings.depth_cm is not None:
        deepest = int(np.searchsorted(geo.row_depth_mm, settings.depth_cm * 10.0, "right"))
        rows = max(2, min(rows, deepest))
    shown = p[:rows]
    if settings.gain_db != 0.0:  # outside the sector (0) stays black
        gained = shown.astype(np.float32) + 255.0 * settings.gain_db / DISPLAY_DYNAMIC_RANGE_DB
        shown = np.where(shown > 0, np.clip(gained, 1, 255), 0).astype(np.uint8)
    scale = width_px / p.shape[1]
    img_h = max(1, round(rows * scale))
    strip = ECG_STRIP_PX if ecg is not None else 0
    canvas = Image.new("RGB", (width_px + SCALE_MARGIN_PX, img_h + strip), (0, 0, 0))
    canvas.paste(Image.fromarray(shown).resize((width_px, img_h), Image.Resampling.BILINEAR))
    draw = ImageDraw.Draw(canvas)
    if geo is not None:
        _depth_scale(draw, geo.row_depth_mm[:rows], scale, width_px, img_h)
        _marker(draw, geo.distal_right, width_px)
    if ecg is not None:
        _ecg_strip(draw, ecg, img_h, width_px + SCALE_MARGIN_PX, ecg_note)
    return np.asarray(canvas)


def _depth_scale(
    draw: ImageDraw.ImageDraw, depth_mm: Array, scale: float, x0: int, img_h: int
) -> None:
    """Ticks every 1 cm (longer every 5 cm), a number every 2 cm, "cm" at the top."""
    font = _font(15)
    rows = np.arange(len(depth_mm), dtype=np.float64)
    if len(depth_mm) < 2 or not np.all(np.diff(depth_mm) > 0):
        return
    draw.text((x0 + 8, 2), "cm", fill=(220, 220, 220), font=font)
    for cm in range(1, int(depth_mm[-1] // 10) + 1):
        row = float(np.interp(cm * 10.0, depth_mm, rows))
        y = (row + 0.5) * scale
        if y > img_h - 1:
            break
        length = 14 if cm % 5 == 0 else 8
        draw.line([(x0 + 2, y), (x0 + 2 + length, y)], fill=(230, 230, 230), width=2)
        if cm % 2 == 0:
            draw.text((x0 + 19, y - 8), str(cm), fill=(230, 230, 230), font=font)


def _marker(draw: ImageDraw.ImageDraw, right: bool, width_px: int) -> None:
    """The orientation marker: a dot and "tip" on the distal side of the sector's top."""
    font = _font(14)
    cx = width_px - 22 if right else 22
    draw.ellipse([cx - 7, 10, cx + 7, 24], fill=MARKER_RGB)
    tx = cx - 44 if right else cx + 12
    draw.text((tx, 9), "tip", fill=MARKER_RGB, font=font)


def _ecg_strip(
    draw: ImageDraw.ImageDraw, ecg: tuple[Array, Array], y0: int, width: int, note: str
) -> None:
    t, mv = (np.asarray(a, dtype=np.float64) for a in ecg)
    draw.line([(0, y0), (width, y0)], fill=(70, 70, 70), width=1)
    draw.text((6, y0 + 3), note, fill=ECG_RGB, font=_font(14))
    if len(t) < 2:
        return
    top, bottom = y0 + 22, y0 + ECG_STRIP_PX - 6
    base = bottom - 0.25 * (bottom - top)  # 0 mV; the R wave (1.2 mV) reaches near the top
    px_per_mv = (base - top) / 1.3
    x = (1.0 + t / ECG_WINDOW_S) * (width - 12) + 2
    y = np.clip(base - mv * px_per_mv, top, bottom)
    draw.line(list(zip(x.tolist(), y.tolist(), strict=True)), fill=ECG_RGB, width=2)
    draw.ellipse([x[-1] - 4, y[-1] - 4, x[-1] + 4, y[-1] + 4], fill=(255, 255, 255))


def ecg_samples(
    cardiac_phase: Callable[[float], float], now_s: float, n: int = 240
) -> tuple[Array, Array]:
    """The ECG of the last :data:`ECG_WINDOW_S` seconds before controller time ``now_s``:
    ((n,) seconds before now, in [-window, 0]; (n,) mV) from a phase source."""
    t = np.linspace(-ECG_WINDOW_S, 0.0, n)
    phases = np.array([cardiac_phase(now_s + dt) for dt in t])
    return t, ecg_mv(phases)


def heart_rate_bpm(
    cardiac_phase: Callable[[float], float], now_s: float, dt: float = 0.05
) -> float:
    """Heart rate (beats/min) at controller time ``now_s``: the phase's rate of change over
    the last ``dt`` seconds (the phase wraps from 1 to 0 at each R wave)."""
    advance = (cardiac_phase(now_s) - cardiac_phase(now_s - dt)) % 1.0
    return 60.0 * advance / dt
