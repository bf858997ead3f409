"""ICE B-mode sector images of the heart phantom at a tip pose (fast, numpy/scipy).

Imaging geometry
----------------
The phased array lies along the catheter axis, so the image plane is the x-z plane of the
``tip`` frame (x = image facing direction = centre line of the sector, z = catheter axis):
a sample at range ``r`` (mm) on the beam at steering angle ``theta`` (rad, positive towards
+z, the distal end) sits at ``(r cos theta, 0, r sin theta)`` in the tip frame.

The picture (``image_size`` x ``image_size``, uint8) has square pixels of
:attr:`ProbeConfig.pixel_mm`; the apex (the transducer) is at the middle of the top edge,
rows go deeper (tip x), columns go distal (tip z): the right half of the picture is the
catheter tip's side. Pixel (row, col) has its centre at tip-frame
``x = (row + 0.5) * pixel_mm``, ``z = (col + 0.5 - image_size / 2) * pixel_mm``.

Image formation (per frame; equations and sources in ``docs/imaging.md``)
-------------------------------------------------------------------------
1. The sector's polar sample grid (beams x samples) is moved to the anatomy frame; each
   sample's material point ``X = x - u(x, t)`` gives its tissue label and so its acoustic
   impedance Z, attenuation alpha and diffuse backscatter b.
2. Along each beam: the pressure reflection coefficient at every interface,
   ``Gamma = (Z2 - Z1) / (Z2 + Z1)`` (Eq. I1), seen with an incidence-angle directivity
   ``cos^m`` (Eq. I2); the two-way transmission ``prod (1 - Gamma^2)`` of the interfaces in
   front (Eq. I3: acoustic shadowing) and the two-way attenuation ``2 alpha f r`` (Eq. I4).
3. Diffuse echo: tissue-fixed complex scatterers (a periodic 3-D texture sampled at X)
   times b; blood scatterers are redrawn every frame (flow). Specular echo: Gamma.
4. Near-field clutter (reverberation from the catheter, transducer-fixed, decaying with
   range; Eq. I6) is added; the field is blurred by the point-spread function: axial
   Gaussian, lateral Gaussian whose width follows the beam (Eq. I5: diffraction-limited
   receive, transmit focused at ``focus_mm``), so resolution worsens with depth.
5. Electronic noise, side-lobe haze (Eq. I7), time-gain compensation and gain (Eq. I8),
   log compression over the dynamic range, scan conversion, speckle reduction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.ndimage as ndi
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_finite, check_positive, check_transform
from icenav.errors import ConfigurationError
from icenav.sim.anatomy import ACOUSTICS, BLOOD_LABELS, ROI_LABELS, HeartPhantom, Tissue
from icenav.sim.anatomy import default_phantom as _default_phantom

__all__ = [
    "Frame",
    "ProbeConfig",
    "RoiObservation",
    "SPECKLE_REDUCTION_MM",
    "UltrasoundRenderer",
]

SOUND_SPEED_M_S = 1540.0
"""Speed of sound assumed by the beamformer (m/s), the soft-tissue convention."""


def _check_range(value: float, name: str, unit: str, lo: float, hi: float) -> float:
    v = float(check_finite(value, name, unit))
    if not lo <= v <= hi:
        raise ConfigurationError(f"{name} must be in [{lo:g}, {hi:g}] {unit}, got {v:g} {unit}")
    return v


@dataclass(frozen=True)
class ProbeConfig:
    """Transducer, beamforming and display settings of the simulated ICE probe.

    Defaults: an ICE phased array (64 elements at half-wavelength pitch, 7 MHz; sources in
    ``docs/imaging.md``). ``gain_db``, ``depth_mm``, ``tgc_db_per_cm`` and
    ``dynamic_range_db`` are the operator's settings (:meth:`UltrasoundRenderer.with_settings`).
    """

    sector_angle: float = math.pi / 2
    """Full opening angle of the sector (rad); ~90 deg for ICE phased arrays."""
    depth_mm: float = 140.0
    """Imaging depth (mm), in [20, 300]; ICE images 12-16 cm."""
    image_size: int = 256
    """Output picture is image_size x image_size pixels."""
    n_beams: int = 96
    """Number of beams (lateral samples of the polar grid)."""
    n_samples: int = 256
    """Samples per beam (axial samples of the polar grid)."""
    frequency_mhz: float = 7.0
    """Centre frequency (MHz), in [2, 15]; ICE catheters image at 5.5-10 MHz."""
    aperture_mm: float = 7.0
    """Active aperture (mm): 64 elements at half-wavelength pitch (0.11 mm at 7 MHz)."""
    focus_mm: float = 60.0
    """Transmit focal depth (mm); the receive focus is dynamic."""
    psf_axial_mm: float = 0.45
    """Axial Gaussian PSF sigma (mm); a 7 MHz two-cycle pulse gives ~0.2 mm, the display's
    0.55 mm sampling limits it here."""
    specular_exponent: float = 4.0
    """Exponent m of the specular directivity cos^m(incidence) (Eq. I2)."""
    specular_db: float = 46.0
    """Echo of a perfect plane reflector (Gamma = 1, normal incidence) above the rms
    diffuse echo of myocardium (dB)."""
    gain_db: float = 0.0
    """Overall receive gain (dB), in [-30, 30]."""
    tgc_db_per_cm: float | None = None
    """Time-gain compensation slope (dB per cm of depth, in [0, 20]); None: compensate
    the two-way attenuation of 0.35 dB/cm/MHz (a path of heart wall, fat and blood)."""
    dynamic_range_db: float = 55.0
    """Displayed dynamic range of the log compression (dB), in [20, 100]."""
    white_db: float = 16.0
    """Echo level (dB above the rms myocardial echo at 0 dB gain) shown as white."""
    noise_level: float = 1e-5
    """Electronic noise rms before TGC, relative to the rms myocardial echo (-100 dB)."""
    clutter_db: float = 6.0
    """Near-field clutter at the transducer face, relative to the myocardial echo (dB)."""
    clutter_length_mm: float = 5.0
    """Range over which the clutter amplitude falls by 1/e (mm)."""
    sidelobe_db: float = -50.0
    """Side-lobe haze: power of the wide PSF component relative to the main lobe (dB)."""
    flow_speckle: bool = True
    """Blood scatterers are redrawn every frame (flowing blood); False: tissue-fixed."""
    speckle_voxel_mm: float = 0.35
    """Cell size of the scatterer texture (mm)."""
    speckle_texture_size: tuple[int, int, int] = (97, 101, 103)
    """Cells of the (periodic) scatterer texture along x, y, z (co-prime periods)."""
    seed: int = 0
    """Seed of the scatterer texture, the clutter and the electronic noise."""
    speckle_reduction_px: float | None = None
    """Sigma (pixels) of the display's speckle-reduction smoothing of the log image (as
    scanners' speckle-reduction filters); 0: off; None: :data:`SPECKLE_REDUCTION_MM` at this
    picture's pixel size (the filter acts on the scanner's image, whose grain does not depend
    on the picture size we render)."""

    def __post_init__(self) -> None:
        ang = check_positive(self.sector_angle, "sector_angle", "rad")
        if ang >= math.pi:
            raise ConfigurationError(f"sector_angle must be in (0, pi) rad, got {ang} rad")
        _check_range(self.depth_mm, "depth_mm", "mm", 20.0, 300.0)
        for name in ("image_size", "n_beams", "n_samples"):
            v = getattr(self, name)
            if not isinstance(v, int) or not 16 <= v <= 4096:
                raise ConfigurationError(f"{name} must be an int in [16, 4096], got {v!r}")
        _check_range(self.frequency_mhz, "frequency_mhz", "MHz", 2.0, 15.0)
        _check_range(self.gain_db, "gain_db", "dB", -30.0, 30.0)
        if self.tgc_db_per_cm is not None:
            _check_range(self.tgc_db_per_cm, "tgc_db_per_cm", "dB/cm", 0.0, 20.0)
        _check_range(self.dynamic_range_db, "dynamic_range_db", "dB", 20.0, 100.0)
        _check_range(self.sidelobe_db, "sidelobe_db", "dB", -120.0, -10.0)
        _check_range(self.clutter_db, "clutter_db", "dB", -120.0, 30.0)
        for name, unit in (
            ("aperture_mm", "mm"),
            ("focus_mm", "mm"),
            ("psf_axial_mm", "mm"),
            ("speckle_voxel_mm", "mm"),
            ("clutter_length_mm", "mm"),
            ("specular_exponent", ""),
        ):
            check_positive(getattr(self, name), name, unit)
        if self.noise_level < 0:
            raise ConfigurationError(f"noise_level must be >= 0, got {self.noise_level}")
        if self.speckle_reduction_px is not None:
            _check_range(self.speckle_reduction_px, "speckle_reduction_px", "px", 0.0, 20.0)

    @property
    def speckle_reduction_sigma_px(self) -> float:
        """Sigma (pixels) of the speckle-reduction smoothing at this picture size."""
        if self.speckle_reduction_px is not None:
            return float(self.speckle_reduction_px)
        return SPECKLE_REDUCTION_MM / self.pixel_mm

    @property
    def pixel_mm(self) -> float:
        """Side of a square pixel (mm): the whole sector fits the picture."""
        half = 0.5 * self.sector_angle
        width = 2.0 * self.depth_mm * math.sin(half)
        return max(self.depth_mm / self.image_size, width / self.image_size)

    @property
    def wavelength_mm(self) -> float:
        """Wavelength at the centre frequency (mm)."""
        return SOUND_SPEED_M_S / (self.frequency_mhz * 1e3)

    @property
    def tgc_slope_db_per_cm(self) -> float:
        """The TGC slope in use (dB/cm)."""
        if self.tgc_db_per_cm is not None:
            return float(self.tgc_db_per_cm)
        return 2.0 * _TGC_REFERENCE_DB_CM_MHZ * self.frequency_mhz

    def lateral_fwhm_mm(self, range_mm: ArrayLike) -> Array:
        """Two-way lateral beam width (FWHM, mm) at ``range_mm`` (Eq. I5)."""
        r = np.maximum(np.asarray(range_mm, dtype=np.float64), 1e-3)
        lam, d = self.wavelength_mm, self.aperture_mm
        w_rx = 1.02 * lam * r / d
        w_tx = np.hypot(w_rx, d * np.abs(1.0 - r / self.focus_mm))
        out: Array = 1.0 / np.sqrt(1.0 / w_rx**2 + 1.0 / w_tx**2)
        return out


_TGC_REFERENCE_DB_CM_MHZ = 0.35
SPECKLE_REDUCTION_MM = 1.5 * 2.0 * 140.0 * math.sin(math.pi / 4.0) / 256.0
"""Sigma (mm, about 1.16) of the display's speckle-reduction smoothing: 1.5 pixels of the
default 256-pixel picture of the 90-deg, 140-mm sector (its pictures are unchanged); smaller
or larger pictures keep the same physical filter, as the gym's pictures already did."""
_BANK_SIZE = 8
_FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


@dataclass(frozen=True)
class RoiObservation:
    """A named structure as seen in one picture (from the label map)."""

    name: str
    """ROI name (see :data:`icenav.sim.anatomy.ROI_LABELS`)."""
    n_pixels: int
    """Pixels of the picture showing it (0: not visible)."""
    centroid_px: tuple[float, float]
    """Centroid (row, col) in pixels; NaN when not visible."""
    centroid_mm: tuple[float, float]
    """Centroid in the image plane (depth = tip x, lateral = tip z; mm); NaN if not visible."""

    @property
    def visible(self) -> bool:
        """Whether any pixel shows the structure."""
        return self.n_pixels > 0


@dataclass(frozen=True)
class Frame:
    """One rendered ICE frame with its ground truth."""

    image: NDArray[np.uint8]
    """B-mode picture, shape (image_size, image_size), 0 outside the sector."""
    labels: NDArray[np.int8]
    """Tissue label of each pixel (nearest polar sample), -1 outside the sector."""
    t: float
    """Acquisition time (s)."""
    cardiac_phase: float
    """Phase in the beat (0 = R wave, fraction of the beat)."""
    tip2anatomy: Array
    """(4, 4) pose of the image frame in the anatomy frame (mm)."""
    rois: dict[str, RoiObservation] = field(default_factory=dict)
    """Observed ROIs by name."""


class UltrasoundRenderer:
    """Renders ICE B-mode frames of a :class:`HeartPhantom`.

    Parameters
    ----------
    phantom : HeartPhantom, optional
        The anatomy; :func:`icenav.sim.anatomy.default_phantom` if omitted.
    config : ProbeConfig, optional
        Probe and display settings.
    """

    def __init__(
        self,
        phantom: HeartPhantom | None = None,
        config: ProbeConfig | None = None,
        *,
        _texture: NDArray[np.complex64] | None = None,
    ) -> None:
        self.phantom = phantom if phantom is not None else _default_phantom()
        self.config = cfg = config if config is not None else ProbeConfig()
        half = 0.5 * cfg.sector_angle
        self.beam_angles = np.linspace(-half, half, cfg.n_beams)
        self.dr_mm = cfg.depth_mm / cfg.n_samples
        self.ranges_mm = (np.arange(cfg.n_samples) + 0.5) * self.dr_mm
        th, rr = np.meshgrid(self.beam_angles, self.ranges_mm, indexing="ij")
        # polar grid in the tip frame, shape (n_beams * n_samples, 3)
        self._grid_tip = np.stack(
            [rr * np.cos(th), np.zeros_like(rr), rr * np.sin(th)], axis=-1
        ).reshape(-1, 3)
        if _texture is None:
            rng = np.random.default_rng(cfg.seed)
            tex = rng.standard_normal((*cfg.speckle_texture_size, 2)).astype(np.float32)
            _texture = (tex[..., 0] + 1j * tex[..., 1]).astype(np.complex64) / math.sqrt(2.0)
        self._texture = _texture
        padded = np.pad(self._texture, ((0, 1), (0, 1), (0, 1)), mode="wrap")
        self._texture_padded = padded.ravel()
        self._tex_strides = (padded.shape[1] * padded.shape[2], padded.shape[2])
        self._build_tables()
        self._build_psf()
        self._build_clutter()
        self._build_scan_conversion()
        # frame-random fields (electronic noise, flowing blood) are rolled copies of a bank
        # drawn once: a fresh draw per frame cost ~15 % of a frame
        bank_rng = np.random.default_rng([cfg.seed, 4])
        self._bank = [self._white(bank_rng) for _ in range(_BANK_SIZE)]

    def with_settings(self, **changes: Any) -> UltrasoundRenderer:
        """A renderer with some :class:`ProbeConfig` settings changed (gain_db, depth_mm,
        tgc_db_per_cm, dynamic_range_db, ...), sharing this one's phantom and scatterers.

        Raises ConfigurationError (naming the value, unit and range) for a bad setting.
        """
        unknown = sorted(set(changes) - set(ProbeConfig.__dataclass_fields__))
        if unknown:
            raise ConfigurationError(f"unknown probe settings {unknown}")
        cfg = replace(self.config, **changes)
        same_texture = (cfg.seed, cfg.speckle_texture_size) == (
            self.config.seed,
            self.config.speckle_texture_size,
        )
        return UltrasoundRenderer(
            self.phantom, cfg, _texture=self._texture if same_texture else None
        )

    # --- precomputed per-probe quantities -------------------------------------------------
    def _build_tables(self) -> None:
        cfg = self.config
        n = max(int(t) for t in Tissue) + 1
        z = np.ones(n)
        att = np.zeros(n)
        back = np.zeros(n)
        blood = np.zeros(n, dtype=bool)
        for tissue, p in ACOUSTICS.items():
            z[int(tissue)] = p.impedance_mrayl
            att[int(tissue)] = p.attenuation_db_cm_mhz
            back[int(tissue)] = p.backscatter
        for tissue in BLOOD_LABELS:
            blood[int(tissue)] = True
        self._z_table = z.astype(np.float32)
        # Eq. (I4): two-way attenuation per sample (dB) = 2 alpha f dr
        self._att_table = (2.0 * att * cfg.frequency_mhz * self.dr_mm / 10.0).astype(np.float32)
        self._back_table = back.astype(np.float32)
        self._blood_table = blood
        self._echo_table = HeartPhantom.echogenicity(np.arange(n))
        # Eq. (I8): TGC and gain (dB) at each range
        tgc_db = cfg.gain_db + cfg.tgc_slope_db_per_cm * self.ranges_mm / 10.0
        self._tgc = (10.0 ** (tgc_db / 20.0)).astype(np.float32)[None, :]
        self._spec_gain = np.float32(10.0 ** (cfg.specular_db / 20.0))

    def _build_psf(self) -> None:
        cfg = self.config
        dth = float(self.beam_angles[1] - self.beam_angles[0])
        # Eq. (I5): lateral sigma in beams at each range (at least half a beam spacing)
        sig_mm = cfg.lateral_fwhm_mm(self.ranges_mm) / _FWHM_PER_SIGMA
        sig_b = np.maximum(sig_mm / (self.ranges_mm * dth), 0.5)
        half = int(min(8, math.ceil(3.0 * float(sig_b.max()))))
        offs = np.arange(-half, half + 1)
        w = np.exp(-0.5 * (offs[None, :] / sig_b[:, None]) ** 2)
        self._lat_w = (w / w.sum(axis=1, keepdims=True)).astype(np.float32)  # (ns, 2h+1)
        self._lat_half = half
        self._lat_sigma_beams = sig_b
        self._ax_sigma = cfg.psf_axial_mm / self.dr_mm
        # rms of the blurred scatterer texture at each range: the diffuse echo of myocardium
        # is normalised to rms 1 at every depth (the texture's own correlation divided out)
        pts = self._grid_tip
        tex = self._speckle(pts + np.array([13.7, 5.3, 21.1])).reshape(cfg.n_beams, -1)
        rms = np.sqrt(np.mean(np.abs(self._blur(tex)) ** 2, axis=0))
        self._diffuse_norm = (1.0 / np.maximum(rms, 1e-6)).astype(np.float32)[None, :]
        white = self._blur(self._white(np.random.default_rng([cfg.seed, 2])))
        self._white_norm = np.float32(1.0 / max(float(np.sqrt(np.mean(np.abs(white) ** 2))), 1e-6))

    def _build_clutter(self) -> None:
        """Eq. (I6): transducer-fixed reverberation clutter, laterally smooth bands."""
        cfg = self.config
        white = self._white(np.random.default_rng([cfg.seed, 3]))
        bands = ndi.gaussian_filter(white.real, (6.0, 1.0)) + 1j * ndi.gaussian_filter(
            white.imag, (6.0, 1.0)
        )
        bands /= np.sqrt(np.mean(np.abs(bands) ** 2))
        amp = 10.0 ** (cfg.clutter_db / 20.0) * np.exp(-self.ranges_mm / cfg.clutter_length_mm)
        self._clutter = (bands * amp[None, :]).astype(np.complex64)

    def _frame_random(self, rng: np.random.Generator) -> NDArray[np.complex64]:
        """A unit-rms complex Gaussian field for one frame (a randomly rolled bank entry)."""
        cfg = self.config
        k, a, b = rng.integers((_BANK_SIZE, cfg.n_beams, cfg.n_samples))
        out: NDArray[np.complex64] = np.roll(self._bank[int(k)], (int(a), int(b)), axis=(0, 1))
        return out

    def _white(self, rng: np.random.Generator) -> NDArray[np.complex64]:
        cfg = self.config
        g = rng.standard_normal((2, cfg.n_beams, cfg.n_samples), dtype=np.float32)
        out: NDArray[np.complex64] = (g[0] + 1j * g[1]) * np.float32(1.0 / math.sqrt(2.0))
        return out

    def _blur(self, f: NDArray[np.complex64]) -> NDArray[np.complex64]:
        """Point-spread function: axial Gaussian, then the range-dependent lateral one."""
        f = ndi.gaussian_filter1d(f, self._ax_sigma, axis=1, mode="nearest", truncate=3.0)
        h = self._lat_half
        padded = np.pad(f, ((h, h), (0, 0)), mode="edge")
        nb = f.shape[0]
        out = padded[0:nb] * self._lat_w[None, :, 0]
        for j in range(1, 2 * h + 1):
            out += padded[j : j + nb] * self._lat_w[None, :, j]
        return out

    # --- geometry ------------------------------------------------------------------------
    def _build_scan_conversion(self) -> None:
        cfg = self.config
        n = cfg.image_size
        rows, cols = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        x, z = self.pixel_to_plane(rows.ravel(), cols.ravel())
        r = np.hypot(x, z)
        th = np.arctan2(z, x)
        dth = self.beam_angles[1] - self.beam_angles[0]
        fb = (th - self.beam_angles[0]) / dth  # fractional beam index
        fs = r / self.dr_mm - 0.5  # fractional sample index
        inside = (
            (np.abs(th) <= 0.5 * cfg.sector_angle) & (r <= cfg.depth_mm) & (fs >= -0.5) & (x > 0)
        )
        fb = np.clip(fb, 0.0, cfg.n_beams - 1.000001)
        fs = np.clip(fs, 0.0, cfg.n_samples - 1.000001)
        b0 = np.floor(fb).astype(np.intp)
        s0 = np.floor(fs).astype(np.intp)
        wb = fb - b0
        ws = fs - s0
        ns = cfg.n_samples
        idx = np.stack(
            [b0 * ns + s0, b0 * ns + s0 + 1, (b0 + 1) * ns + s0, (b0 + 1) * ns + s0 + 1], axis=0
        )
        w = np.stack([(1 - wb) * (1 - ws), (1 - wb) * ws, wb * (1 - ws), wb * ws], axis=0)
        self._pix_inside = np.flatnonzero(inside)
        self._outside = np.flatnonzero(~inside)
        self._sc_idx = idx[:, self._pix_inside]
        self._sc_w = w[:, self._pix_inside].astype(np.float32)
        nearest = np.rint(fb).astype(np.intp) * ns + np.rint(fs).astype(np.intp)
        self._sc_nearest = nearest[self._pix_inside]

    def pixel_to_plane(self, rows: ArrayLike, cols: ArrayLike) -> tuple[Array, Array]:
        """Image-plane coordinates (depth = tip x, lateral = tip z; mm) of pixel centres."""
        s = self.config.pixel_mm
        n = self.config.image_size
        x = (np.asarray(rows, dtype=np.float64) + 0.5) * s
        z = (np.asarray(cols, dtype=np.float64) + 0.5 - 0.5 * n) * s
        return x, z

    def plane_to_pixel(self, depth_mm: ArrayLike, lateral_mm: ArrayLike) -> tuple[Array, Array]:
        """Fractional (row, col) of image-plane points (inverse of :meth:`pixel_to_plane`)."""
        s = self.config.pixel_mm
        n = self.config.image_size
        row = np.asarray(depth_mm, dtype=np.float64) / s - 0.5
        col = np.asarray(lateral_mm, dtype=np.float64) / s - 0.5 + 0.5 * n
        return row, col

    def project(self, points_in_anatomy: ArrayLike, tip2anatomy: ArrayLike) -> tuple[Array, Array]:
        """Project anatomy points into the picture.

        Parameters
        ----------
        points_in_anatomy : array-like, shape (..., 3)
            Points (mm).
        tip2anatomy : array-like, shape (4, 4)
            Pose of the image frame.

        Returns
        -------
        pixel : ndarray, shape (..., 2)
            Fractional (row, col) of the orthogonal projection onto the image plane.
        out_of_plane_mm : ndarray, shape (...)
            Signed distance from the image plane (tip y, mm).
        """
        t = check_transform(tip2anatomy, "tip2anatomy")
        p = check_finite(points_in_anatomy, "points_in_anatomy", "mm")
        p_tip = (p - t[:3, 3]) @ t[:3, :3]
        row, col = self.plane_to_pixel(p_tip[..., 0], p_tip[..., 2])
        return np.stack([row, col], axis=-1), p_tip[..., 1]

    def in_sector(self, points_in_anatomy: ArrayLike, tip2anatomy: ArrayLike) -> NDArray[np.bool_]:
        """Whether the in-plane projection of each point lies inside the imaged sector."""
        t = check_transform(tip2anatomy, "tip2anatomy")
        p = check_finite(points_in_anatomy, "points_in_anatomy", "mm")
        p_tip = (p - t[:3, 3]) @ t[:3, :3]
        r = np.hypot(p_tip[..., 0], p_tip[..., 2])
        th = np.arctan2(p_tip[..., 2], p_tip[..., 0])
        out: NDArray[np.bool_] = (np.abs(th) <= 0.5 * self.config.sector_angle) & (
            r <= self.config.depth_mm
        )
        return out

    # --- rendering -----------------------------------------------------------------------
    def _speckle(self, material: Array) -> NDArray[np.complex64]:
        """Trilinear sample of the periodic scatterer texture at material points (N, 3)."""
        shape = self._texture.shape
        g = material / self.config.speckle_voxel_mm
        base = np.floor(g)
        f = (g - base).astype(np.float32)
        i = base.astype(np.intp)
        # the padded texture repeats its first cell, so corner + 1 never wraps
        flat = (
            np.mod(i[:, 0], shape[0]) * self._tex_strides[0]
            + np.mod(i[:, 1], shape[1]) * self._tex_strides[1]
            + np.mod(i[:, 2], shape[2])
        )
        fx, fy, fz = f[:, 0], f[:, 1], f[:, 2]
        gx, gy, gz = 1.0 - fx, 1.0 - fy, 1.0 - fz
        tex = self._texture_padded
        sx, sy = self._tex_strides
        out = (tex[flat] * gz + tex[flat + 1] * fz) * (gx * gy)
        out += (tex[flat + sy] * gz + tex[flat + sy + 1] * fz) * (gx * fy)
        out += (tex[flat + sx] * gz + tex[flat + sx + 1] * fz) * (fx * gy)
        out += (tex[flat + sx + sy] * gz + tex[flat + sx + sy + 1] * fz) * (fx * fy)
        return out

    def echo_field(
        self, labels: NDArray[np.int8], scatterers: NDArray[np.complex64]
    ) -> tuple[NDArray[np.complex64], Array]:
        """Echo of each polar sample before the PSF, and the two-way amplitude reaching it.

        Parameters
        ----------
        labels : ndarray of int8, shape (n_beams, n_samples)
            Tissue label of each sample.
        scatterers : ndarray of complex64, shape (n_beams, n_samples)
            Unit-rms complex scatterer amplitudes.

        Returns
        -------
        echo : ndarray of complex64, shape (n_beams, n_samples)
            Diffuse plus specular echo, relative to the rms myocardial echo (Eqs. I1-I4).
        transmitted : ndarray, shape (n_beams, n_samples)
            Two-way amplitude factor of transmission and attenuation (1 at the face).
        """
        cfg = self.config
        z = self._z_table[labels]
        # Eq. (I1): pressure reflection coefficient at the interface in front of sample k
        gamma = np.zeros_like(z)
        gamma[:, 1:] = (z[:, 1:] - z[:, :-1]) / (z[:, 1:] + z[:, :-1])
        # Eq. (I2): incidence angle from the in-plane impedance gradient (smoothed field)
        zs = ndi.gaussian_filter(z, 1.0, mode="nearest")
        g_r = np.zeros_like(zs)
        g_r[:, 1:-1] = (zs[:, 2:] - zs[:, :-2]) / (2.0 * self.dr_mm)
        g_t = np.zeros_like(zs)
        dth = float(self.beam_angles[1] - self.beam_angles[0])
        g_t[1:-1] = (zs[2:] - zs[:-2]) / (2.0 * dth * self.ranges_mm[None, :].astype(np.float32))
        cos_inc = np.abs(g_r) / np.sqrt(g_r * g_r + g_t * g_t + np.float32(1e-12))
        specular = gamma * cos_inc ** np.float32(cfg.specular_exponent) * self._spec_gain
        # Eqs. (I3)-(I4): two-way transmission through the interfaces and the tissue in front
        loss_db = np.cumsum(self._att_table[labels], axis=1) - 0.5 * self._att_table[labels]
        log_t = np.cumsum(np.log1p(-np.minimum(gamma * gamma, np.float32(0.999999))), axis=1)
        transmitted = np.exp(log_t - loss_db * np.float32(math.log(10.0) / 20.0))
        # the echo from interface k is not reduced by interface k itself
        before = np.exp(-np.log1p(-np.minimum(gamma * gamma, np.float32(0.999999))))
        diffuse = self._back_table[labels] * scatterers * self._diffuse_norm
        echo = (diffuse + specular * before) * transmitted
        return echo.astype(np.complex64), transmitted

    def render(
        self,
        tip2anatomy: ArrayLike,
        t: float,
        *,
        noise_seed: int | None = None,
        check: bool = True,
    ) -> Frame:
        """Render the frame seen from ``tip2anatomy`` at time ``t``.

        Parameters
        ----------
        tip2anatomy : array-like, shape (4, 4)
            Pose of the image frame (tip) in the anatomy frame (mm).
        t : float
            Acquisition time (s): sets cardiac and respiratory phase and, unless
            ``noise_seed`` is given, the electronic noise and the flowing blood's scatterers.
        noise_seed : int, optional
            Seed of this frame's electronic noise and blood scatterers.
        check : bool
            Validate the pose.

        Returns
        -------
        Frame
        """
        cfg = self.config
        pose = (
            check_transform(tip2anatomy, "tip2anatomy")
            if check
            else np.asarray(tip2anatomy, dtype=np.float64)
        )
        t = float(check_finite(t, "t", "s")) if check else float(t)
        nb, ns = cfg.n_beams, cfg.n_samples
        pts = self._grid_tip @ pose[:3, :3].T + pose[:3, 3]
        material = self.phantom.material_points(pts, t)
        labels = self.phantom.labels_of_material(material, t)
        lab2 = labels.reshape(nb, ns)
        scat = self._speckle(material).reshape(nb, ns)
        seed = noise_seed if noise_seed is not None else int(round(t * 1e4)) & 0x7FFFFFFF
        rng = np.random.default_rng([cfg.seed, 1, seed])
        if cfg.flow_speckle:  # blood scatterers flow: new ones every frame
            blood = self._blood_table[lab2]
            if blood.any():
                moving = self._frame_random(rng) * (self._white_norm / self._diffuse_norm)
                scat = np.where(blood, moving, scat).astype(np.complex64)
        echo, _ = self.echo_field(lab2, scat)
        field_ = self._blur(echo + self._clutter)
        if cfg.noise_level > 0.0:
            field_ += self._frame_random(rng) * np.float32(cfg.noise_level)
        power = (field_.real**2 + field_.imag**2).astype(np.float32)
        # Eq. (I7): side-lobe haze, a wide low-level copy of the echo power
        haze = ndi.gaussian_filter(power, (8.0, 2.0), mode="nearest", truncate=2.5)
        power += np.float32(10.0 ** (cfg.sidelobe_db / 10.0)) * haze
        env = np.sqrt(power) * self._tgc
        db = 20.0 * np.log10(env + np.float32(1e-9))
        grey = np.clip((db - cfg.white_db) / cfg.dynamic_range_db + 1.0, 0.0, 1.0) * 255.0
        flat = grey.ravel()
        n = cfg.image_size
        img = np.zeros(n * n, dtype=np.float32)
        img[self._pix_inside] = np.einsum("ki,ki->i", self._sc_w, flat[self._sc_idx])
        sigma_px = cfg.speckle_reduction_sigma_px
        if sigma_px > 0.0:
            img = ndi.gaussian_filter(img.reshape(n, n), sigma_px).ravel()
            img[self._outside] = 0.0
        lab_flat = np.full(n * n, -1, dtype=np.int8)
        lab_flat[self._pix_inside] = labels[self._sc_nearest]
        lab_img = lab_flat.reshape(n, n)
        return Frame(
            image=np.rint(img).astype(np.uint8).reshape(n, n),
            labels=lab_img,
            t=t,
            cardiac_phase=self.phantom.cardiac_phase(t),
            tip2anatomy=pose.copy(),
            rois=self._observe_rois(lab_img),
        )

    def _observe_rois(self, lab_img: NDArray[np.int8]) -> dict[str, RoiObservation]:
        out: dict[str, RoiObservation] = {}
        for name, tissue in ROI_LABELS.items():
            rows, cols = np.nonzero(lab_img == int(tissue))
            if rows.size == 0:
                nan = (math.nan, math.nan)
                out[name] = RoiObservation(name, 0, nan, nan)
                continue
            r, c = float(rows.mean()), float(cols.mean())
            x, z = self.pixel_to_plane(r, c)
            out[name] = RoiObservation(name, int(rows.size), (r, c), (float(x), float(z)))
        return out

    def render_clip(
        self, tip2anatomy: ArrayLike, t0: float, n_frames: int, frame_time_s: float
    ) -> list[Frame]:
        """Frames at ``t0 + k * frame_time_s`` for k = 0 .. n_frames - 1 (a still catheter)."""
        pose = check_transform(tip2anatomy, "tip2anatomy")
        check_positive(frame_time_s, "frame_time_s", "s")
        return [self.render(pose, t0 + k * frame_time_s, check=False) for k in range(int(n_frames))]
