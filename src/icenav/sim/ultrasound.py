"""ICE B-mode sector images of the heart phantom at a tip pose (fast, numpy/scipy).

Imaging geometry
----------------
The phased array lies along the catheter axis, so the image plane is the x-z plane of the
``tip`` frame (x = image facing direction = centre line of the sector, z = catheter axis):
a sample at range ``r`` (mm) on the beam at steering angle ``theta`` (rad, positive towards
+z, the distal end) sits at ``(r cos theta, 0, r sin theta)`` in the tip frame.

The picture (``image_size`` x ``image_size``, uint8) has square pixels of
:attr:`ProbeConfig.pixel_mm`; the apex is at the middle of the top edge, rows go deeper
(tip x), columns go distal (tip z). Pixel (row, col) has its centre at tip-frame
``x = (row + 0.5) * pixel_mm``, ``z = (col + 0.5 - image_size / 2) * pixel_mm``.

Image formation (per frame)
---------------------------
1. The sector's polar sample grid (beams x samples) is precomputed in the tip frame; it is
   moved to the anatomy frame by ``tip2anatomy``.
2. Each sample's material point ``X = x - u(x, t)`` (tissue-fixed) gives its tissue label
   and echogenicity; complex scatterer amplitudes come from a fixed random 3-D texture
   sampled trilinearly at ``X`` (same tissue, same speckle, moving with the tissue).
3. Electronic noise (complex Gaussian, seeded by the frame time) is added.
4. Point-spread function: a separable Gaussian, axial sigma < lateral sigma (lateral in
   angle, so the beam widens with depth), applied to the complex field; envelope = |.|.
5. Depth attenuation (net of time-gain compensation, dB/mm), log compression over a
   dynamic range, scan conversion (bilinear) to the picture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage as ndi
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_finite, check_positive, check_transform
from icenav.errors import ConfigurationError
from icenav.sim.anatomy import ROI_LABELS, HeartPhantom, Tissue, default_phantom

__all__ = [
    "Frame",
    "ProbeConfig",
    "RoiObservation",
    "UltrasoundRenderer",
]


@dataclass(frozen=True)
class ProbeConfig:
    """Transducer, beamforming and display settings of the simulated ICE probe."""

    sector_angle: float = math.pi / 2
    """Full opening angle of the sector (rad); ~90 deg for ICE phased arrays."""
    depth_mm: float = 140.0
    """Imaging depth (mm); 12-16 cm for ICE."""
    image_size: int = 256
    """Output picture is image_size x image_size pixels."""
    n_beams: int = 96
    """Number of beams (lateral samples of the polar grid)."""
    n_samples: int = 256
    """Samples per beam (axial samples of the polar grid)."""
    psf_axial_mm: float = 0.45
    """Axial Gaussian PSF sigma (mm)."""
    psf_lateral_rad: float = 0.016
    """Lateral Gaussian PSF sigma (rad of steering angle; ~1.1 mm at 70 mm depth)."""
    attenuation_db_per_mm: float = 0.04
    """Net round-trip attenuation after time-gain compensation (dB/mm)."""
    dynamic_range_db: float = 50.0
    """Displayed dynamic range of the log compression (dB)."""
    gain_db: float = 0.0
    """Display gain (dB) added before compression."""
    noise_level: float = 0.012
    """Electronic noise amplitude relative to echogenicity 1 (complex Gaussian sigma)."""
    speckle_voxel_mm: float = 0.35
    """Cell size of the scatterer texture (mm)."""
    speckle_texture_size: tuple[int, int, int] = (97, 101, 103)
    """Cells of the (periodic) scatterer texture along x, y, z (co-prime periods)."""
    seed: int = 0
    """Seed of the scatterer texture and of the electronic noise."""
    speckle_reduction_px: float = 1.5
    """Sigma (pixels) of the display's speckle-reduction smoothing of the log image (as
    scanners' speckle-reduction filters); 0: off."""

    def __post_init__(self) -> None:
        ang = check_positive(self.sector_angle, "sector_angle", "rad")
        if ang >= math.pi:
            raise ConfigurationError(f"sector_angle must be in (0, pi) rad, got {ang} rad")
        depth = check_positive(self.depth_mm, "depth_mm", "mm")
        if not 20.0 <= depth <= 300.0:
            raise ConfigurationError(f"depth_mm must be in [20, 300] mm, got {depth} mm")
        for name in ("image_size", "n_beams", "n_samples"):
            v = getattr(self, name)
            if not isinstance(v, int) or not 16 <= v <= 4096:
                raise ConfigurationError(f"{name} must be an int in [16, 4096], got {v!r}")
        check_positive(self.psf_axial_mm, "psf_axial_mm", "mm")
        check_positive(self.psf_lateral_rad, "psf_lateral_rad", "rad")
        check_positive(self.dynamic_range_db, "dynamic_range_db", "dB")
        check_positive(self.speckle_voxel_mm, "speckle_voxel_mm", "mm")
        if self.noise_level < 0 or self.attenuation_db_per_mm < 0:
            raise ConfigurationError(
                f"noise_level and attenuation_db_per_mm must be >= 0, got "
                f"{self.noise_level}, {self.attenuation_db_per_mm} dB/mm"
            )

    @property
    def pixel_mm(self) -> float:
        """Side of a square pixel (mm): the whole sector fits the picture."""
        half = 0.5 * self.sector_angle
        width = 2.0 * self.depth_mm * math.sin(half)
        return max(self.depth_mm / self.image_size, width / self.image_size)


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
        self, phantom: HeartPhantom | None = None, config: ProbeConfig | None = None
    ) -> None:
        self.phantom = phantom if phantom is not None else default_phantom()
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
        rng = np.random.default_rng(cfg.seed)
        shape = cfg.speckle_texture_size
        tex = rng.standard_normal((*shape, 2)).astype(np.float32)
        self._texture = (tex[..., 0] + 1j * tex[..., 1]).astype(np.complex64) / math.sqrt(2.0)
        padded = np.pad(self._texture, ((0, 1), (0, 1), (0, 1)), mode="wrap")
        self._texture_padded = padded.ravel()
        self._tex_strides = (padded.shape[1] * padded.shape[2], padded.shape[2])
        self._echo_table = HeartPhantom.echogenicity(np.arange(max(int(t) for t in Tissue) + 1))
        att = 10.0 ** (-cfg.attenuation_db_per_mm * self.ranges_mm / 20.0)
        self._attenuation = att[None, :]
        self._psf_sigma = (
            cfg.psf_lateral_rad / (self.beam_angles[1] - self.beam_angles[0]),
            cfg.psf_axial_mm / self.dr_mm,
        )
        self._build_scan_conversion()

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
    def _noise(self, t: float, noise_seed: int | None) -> NDArray[np.complex64]:
        cfg = self.config
        seed = noise_seed if noise_seed is not None else int(round(t * 1e4)) & 0x7FFFFFFF
        rng = np.random.default_rng([cfg.seed, 1, seed])
        shape = (cfg.n_beams, cfg.n_samples)
        noise = rng.standard_normal((2, *shape), dtype=np.float32)
        out: NDArray[np.complex64] = (noise[0] + 1j * noise[1]) * np.float32(
            cfg.noise_level / math.sqrt(2.0)
        )
        return out

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
            ``noise_seed`` is given, the electronic noise.
        noise_seed : int, optional
            Seed of this frame's electronic noise.
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
        pts = self._grid_tip @ pose[:3, :3].T + pose[:3, 3]
        material = self.phantom.material_points(pts, t)
        labels = self.phantom.labels_of_material(material, t)
        echo = self._echo_table[labels].astype(np.float32)
        scat = self._speckle(material)
        field_ = (echo * scat).reshape(cfg.n_beams, cfg.n_samples) + self._noise(t, noise_seed)
        field_ = ndi.gaussian_filter(field_, self._psf_sigma, mode="nearest", truncate=3.0)
        env = np.abs(field_) * self._attenuation
        db = 20.0 * np.log10(env + 1e-6) + cfg.gain_db
        # 0 dB: about the rms of a unit-echogenicity scatterer field after the PSF
        grey = np.clip((db - self._ref_db) / cfg.dynamic_range_db + 1.0, 0.0, 1.0) * 255.0
        flat = grey.ravel()
        n = cfg.image_size
        img = np.zeros(n * n, dtype=np.float32)
        img[self._pix_inside] = np.einsum("ki,ki->i", self._sc_w, flat[self._sc_idx])
        if cfg.speckle_reduction_px > 0.0:
            img = ndi.gaussian_filter(img.reshape(n, n), cfg.speckle_reduction_px).ravel()
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

    @property
    def _ref_db(self) -> float:
        # rms of the PSF-blurred unit-variance complex field: 1 / sqrt(4 pi sa sl) (2-D)
        sa, sl = self._psf_sigma[1], self._psf_sigma[0]
        return 20.0 * math.log10(1.0 / math.sqrt(4.0 * math.pi * sa * sl))

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
