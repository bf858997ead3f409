"""DICOM export and import of a view's image clip (one heart beat), as the paper recorded.

A clip is written as an *Ultrasound Multi-frame Image Storage* object (SOP class
1.2.840.10008.5.1.4.1.1.3.1), 8-bit MONOCHROME2, explicit VR little endian, with:

- Frame Time (0018,1063, ms) and Frame Increment Pointer, Number of Frames;
- Acquisition DateTime (0008,002A) and Content/Study/Series date and time;
- a Sequence of Ultrasound Regions item with the pixel size (cm, as DICOM requires);
- the catheter state in a private block (group 0x0011, creator ``ICENAV 1``):
  motor joint state q (phi1 rad, phi2 rad, phi3 rad, d4 mm), tip2base (4x4, mm, row
  major), the view name (as a DICOM LO value: cleaned, at most 64 characters) and each
  frame's cardiac phase; and the same state with the full view name, readable by a person,
  in Image Comments (0020,4000).

:func:`export_view_clip` writes, :func:`read_view_clip` reads back a :class:`ViewClip`.
:class:`ExportDirectory` writes clips for clients (the console's Export DICOM button) into one
configured directory, under file names it makes itself (never a client's path).
``python -m icenav.persistence.dicom CLIP.npz OUT.dcm`` exports frames kept in an ``.npz`` (until
the
store provides them to ``icenav export-view``).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import os
import sys
import unicodedata
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from pydicom.dataset import Dataset

from icenav._validation import check_finite, check_joint_state, check_positive, check_transform
from icenav.errors import (
    ConfigurationError,
    ExportError,
    FileFormatError,
    InvalidValueError,
    ShapeError,
    UnsafeExportPathError,
)

__all__ = [
    "EXPORT_SUFFIX",
    "ExportDirectory",
    "PRIVATE_CREATOR",
    "ViewClip",
    "export_file_stem",
    "export_view_clip",
    "main",
    "read_view_clip",
]

PRIVATE_CREATOR = "ICENAV 1"
"""Private creator of icenav's block in group 0x0011."""

_GROUP = 0x0011
_Q_MOTOR = 0x01  # FD x 4: motor joint state (rad, rad, rad, mm)
_TIP2BASE = 0x02  # FD x 16: tip2base, row major (mm)
_VIEW = 0x03  # LO: view name
_PHASES = 0x04  # FD x n_frames: cardiac phase of each frame (fraction of the beat)
_US_MULTIFRAME = "1.2.840.10008.5.1.4.1.1.3.1"


@dataclass(frozen=True)
class ViewClip:
    """A view's image clip with its acquisition time and catheter state."""

    frames: NDArray[np.uint8]
    """(n_frames, rows, cols) B-mode pictures."""
    frame_time_s: float
    """Time between frames (s)."""
    acquired_at: dt.datetime
    """Acquisition date and time of the first frame (UTC)."""
    q_motor: NDArray[np.float64]
    """(4,) motor joint state when the clip was acquired (phi1 rad, phi2 rad, phi3 rad, d4 mm)."""
    tip2base: NDArray[np.float64]
    """(4, 4) pose of the image frame in the robot base frame (mm)."""
    view_name: str = ""
    """Name of the saved view."""
    pixel_mm: float | None = None
    """Side of a square pixel (mm), if known."""
    cardiac_phases: NDArray[np.float64] | None = None
    """(n_frames,) cardiac phase of each frame (fraction of the beat), if known."""


def export_view_clip(
    path: str | Path,
    frames: ArrayLike,
    frame_time_s: float,
    q_motor: ArrayLike,
    tip2base: ArrayLike,
    *,
    acquired_at: dt.datetime | None = None,
    view_name: str = "",
    pixel_mm: float | None = None,
    cardiac_phases: ArrayLike | None = None,
    patient_id: str = "ICENAV-SIM",
) -> Path:
    """Write one clip as an ultrasound multi-frame DICOM file.

    Parameters
    ----------
    path : str or Path
        Output file (a path the caller trusts; for names that come from a client use
        :meth:`ExportDirectory.write_clip`).
    frames : array-like of uint8, shape (n_frames, rows, cols)
        The pictures (one heart beat).
    frame_time_s : float
        Time between frames (s), > 0.
    q_motor : array-like, shape (4,)
        Motor joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm).
    tip2base : array-like, shape (4, 4)
        Pose of the image frame in the base frame (mm).
    acquired_at : datetime, optional
        Time of the first frame; now (UTC) if omitted.
    view_name, pixel_mm, cardiac_phases, patient_id :
        Optional metadata (``cardiac_phases`` has shape (n_frames,)).

    Returns
    -------
    Path
        The file written.
    """
    ds = _clip_dataset(
        frames,
        frame_time_s,
        q_motor,
        tip2base,
        acquired_at=acquired_at,
        view_name=view_name,
        pixel_mm=pixel_mm,
        cardiac_phases=cardiac_phases,
        patient_id=patient_id,
    )
    out = Path(path)
    ds.save_as(out, enforce_file_format=True)
    return out


def _clip_dataset(
    frames: ArrayLike,
    frame_time_s: float,
    q_motor: ArrayLike,
    tip2base: ArrayLike,
    *,
    acquired_at: dt.datetime | None = None,
    view_name: str = "",
    pixel_mm: float | None = None,
    cardiac_phases: ArrayLike | None = None,
    patient_id: str = "ICENAV-SIM",
) -> Dataset:
    """The DICOM dataset of one clip (arguments as :func:`export_view_clip`)."""
    import pydicom
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.sequence import Sequence as DicomSequence
    from pydicom.uid import UID, ExplicitVRLittleEndian, generate_uid

    arr = np.asarray(frames)
    if arr.ndim != 3 or arr.shape[0] < 1 or arr.shape[1] < 1 or arr.shape[2] < 1:
        raise ShapeError(f"frames must have shape (n_frames, rows, cols), got {arr.shape}")
    if arr.dtype != np.uint8:
        raise InvalidValueError(f"frames must be uint8 (0..255 grey), got dtype {arr.dtype}")
    ft = check_positive(frame_time_s, "frame_time_s", "s")
    q = check_joint_state(q_motor, name="q_motor")
    if q.shape != (4,):
        raise ShapeError(f"q_motor must have shape (4,), got {q.shape}")
    pose = check_transform(tip2base, "tip2base")
    if pose.shape != (4, 4):
        raise ShapeError(f"tip2base must have shape (4, 4), got {pose.shape}")
    phases = None
    if cardiac_phases is not None:
        phases = check_finite(cardiac_phases, "cardiac_phases").ravel()
        if phases.size != arr.shape[0]:
            raise ShapeError(
                f"cardiac_phases must have one value per frame ({arr.shape[0]}), got {phases.size}"
            )
    if pixel_mm is not None:
        pixel_mm = check_positive(pixel_mm, "pixel_mm", "mm")
    when = acquired_at or dt.datetime.now(dt.UTC)

    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = UID(_US_MULTIFRAME)
    sop_uid = generate_uid()
    meta.MediaStorageSOPInstanceUID = sop_uid
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID = UID(_US_MULTIFRAME)
    ds.SOPInstanceUID = sop_uid
    ds.StudyInstanceUID = generate_uid()
    ds.SeriesInstanceUID = generate_uid()
    ds.Modality = "US"
    ds.Manufacturer = "icenav"
    ds.ManufacturerModelName = "icenav simulated ICE"
    ds.PatientName = "ICENAV^SIM"
    ds.PatientID = patient_id
    date = when.strftime("%Y%m%d")
    time = when.strftime("%H%M%S.%f")
    ds.StudyDate = ds.SeriesDate = ds.ContentDate = date
    ds.StudyTime = ds.SeriesTime = ds.ContentTime = time
    ds.AcquisitionDateTime = when.strftime("%Y%m%d%H%M%S.%f") + (
        when.strftime("%z") if when.tzinfo else ""
    )
    ds.SpecificCharacterSet = "ISO_IR 192"  # UTF-8: view names are any text
    ds.SeriesDescription = _lo(f"ICE view {view_name}".strip())
    ds.ImageType = ["ORIGINAL", "PRIMARY"]
    ds.InstanceNumber = 1
    n, rows, cols = arr.shape
    ds.NumberOfFrames = n
    ds.FrameTime = f"{ft * 1000.0:.6g}"  # ms
    ds.FrameIncrementPointer = pydicom.tag.Tag(0x0018, 0x1063)
    ds.CineRate = max(1, round(1.0 / ft))
    ds.Rows, ds.Columns = rows, cols
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    ds.BitsAllocated = 8
    ds.BitsStored = 8
    ds.HighBit = 7
    ds.PixelRepresentation = 0
    if pixel_mm is not None:
        region = Dataset()
        region.RegionSpatialFormat = 1  # 2-D
        region.RegionDataType = 1  # tissue
        region.RegionFlags = 0
        region.RegionLocationMinX0 = 0
        region.RegionLocationMinY0 = 0
        region.RegionLocationMaxX1 = cols - 1
        region.RegionLocationMaxY1 = rows - 1
        region.PhysicalUnitsXDirection = 3  # cm
        region.PhysicalUnitsYDirection = 3
        region.PhysicalDeltaX = pixel_mm / 10.0
        region.PhysicalDeltaY = pixel_mm / 10.0
        ds.SequenceOfUltrasoundRegions = DicomSequence([region])
    block = ds.private_block(_GROUP, PRIVATE_CREATOR, create=True)
    block.add_new(_Q_MOTOR, "FD", [float(v) for v in q])
    block.add_new(_TIP2BASE, "FD", [float(v) for v in pose.ravel()])
    block.add_new(_VIEW, "LO", _lo(view_name))
    if phases is not None:
        block.add_new(_PHASES, "FD", [float(v) for v in phases])
    ds.ImageComments = json.dumps(
        {
            "view": view_name[:1024],  # LT holds 10240 characters
            "q_motor": {"phi1_rad": q[0], "phi2_rad": q[1], "phi3_rad": q[2], "d4_mm": q[3]},
            "tip_position_in_base_mm": pose[:3, 3].round(4).tolist(),
        }
    )
    ds.PixelData = np.ascontiguousarray(arr).tobytes()
    return ds


def _lo(text: str) -> str:
    """``text`` as a DICOM LO value: no backslash (the value separator), no control
    characters, at most 64 characters."""
    clean = "".join("/" if c == "\\" else c for c in text if c.isprintable())
    return clean[:64].strip()


def _private(ds: object, element: int) -> object | None:
    try:
        block = ds.private_block(_GROUP, PRIVATE_CREATOR)  # type: ignore[attr-defined]
    except KeyError:
        return None
    try:
        return block[element].value
    except KeyError:
        return None


def read_view_clip(path: str | Path) -> ViewClip:
    """Read a clip written by :func:`export_view_clip`.

    Raises
    ------
    FileFormatError
        Not a DICOM file, not an ultrasound multi-frame image, or no icenav catheter state.
    """
    import pydicom
    from pydicom.errors import InvalidDicomError

    try:
        ds = pydicom.dcmread(path)
    except (InvalidDicomError, OSError, EOFError) as exc:
        raise FileFormatError(f"{path}: not a readable DICOM file ({exc})") from exc
    if str(ds.get("SOPClassUID", "")) != _US_MULTIFRAME:
        raise FileFormatError(
            f"{path}: SOP class {ds.get('SOPClassUID', 'missing')} is not Ultrasound "
            f"Multi-frame Image Storage ({_US_MULTIFRAME})"
        )
    q = _private(ds, _Q_MOTOR)
    pose = _private(ds, _TIP2BASE)
    if q is None or pose is None:
        raise FileFormatError(
            f"{path}: no icenav catheter state (private creator {PRIVATE_CREATOR})"
        )
    n = int(ds.NumberOfFrames)
    rows, cols = int(ds.Rows), int(ds.Columns)
    if int(ds.BitsAllocated) != 8 or int(ds.SamplesPerPixel) != 1:
        raise FileFormatError(f"{path}: expected 8-bit single-sample pixels")
    raw = np.frombuffer(ds.PixelData, dtype=np.uint8)
    if raw.size != n * rows * cols:
        raise FileFormatError(
            f"{path}: pixel data has {raw.size} bytes, expected {n} x {rows} x {cols}"
        )
    frames = raw.reshape(n, rows, cols).copy()
    adt = str(ds.AcquisitionDateTime)
    fmt = "%Y%m%d%H%M%S.%f%z" if ("+" in adt or "-" in adt[8:]) else "%Y%m%d%H%M%S.%f"
    when = dt.datetime.strptime(adt, fmt)
    pixel_mm = None
    if "SequenceOfUltrasoundRegions" in ds and len(ds.SequenceOfUltrasoundRegions) > 0:
        pixel_mm = float(ds.SequenceOfUltrasoundRegions[0].PhysicalDeltaX) * 10.0
    phases_raw = _private(ds, _PHASES)
    phases = None if phases_raw is None else np.asarray(phases_raw, dtype=np.float64).ravel()
    view = _private(ds, _VIEW)
    with contextlib.suppress(ValueError, KeyError, TypeError):  # the full name (LO: <= 64)
        view = json.loads(str(ds.get("ImageComments", "")))["view"]
    return ViewClip(
        frames=frames,
        frame_time_s=float(ds.FrameTime) / 1000.0,
        acquired_at=when,
        q_motor=np.asarray(q, dtype=np.float64).reshape(4),
        tip2base=np.asarray(pose, dtype=np.float64).reshape(4, 4),
        view_name=str(view) if view is not None else "",
        pixel_mm=pixel_mm,
        cardiac_phases=phases,
    )


# ------------------------------------------------------------------ exports from clients


EXPORT_SUFFIX = ".dcm"
"""File name extension of exported clips."""
_STEM_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_")


def export_file_stem(view_name: str, max_chars: int = 48) -> str:
    """A file-name stem made from a view name that a client gave: only ASCII letters,
    digits, ``-`` and ``_`` (accents dropped, every other run of characters one ``_``), no
    leading or trailing ``-`` / ``_``, at most ``max_chars`` characters; ``"view"`` when
    nothing is left. It holds no separator, no dot (so no ``..``, no hidden file) and is
    never absolute."""
    if max_chars < 1:
        raise InvalidValueError(f"max_chars must be >= 1 character, got {max_chars}")
    ascii_text = unicodedata.normalize("NFKD", str(view_name)).encode("ascii", "ignore").decode()
    out: list[str] = []
    for c in ascii_text:
        c = c if c in _STEM_CHARS else "_"
        if not (c == "_" and out and out[-1] == "_"):
            out.append(c)
    stem = "".join(out)[:max_chars].strip("-_")
    return stem or "view"


@dataclass(frozen=True)
class ExportDirectory:
    """The one directory into which clients' exports are written; file names are made here,
    never taken from a client.

    A name is ``<stem>_<UTC time>.dcm`` (:func:`export_file_stem` of the view name, time as
    ``YYYYmmddTHHMMSSZ``), with ``-2``, ``-3``, ... added when that name exists. The file is
    created exclusively, relative to the directory's descriptor, without following a
    symlink: an existing file or a symlink planted under the name is never written through.
    """

    root: Path
    """The export directory (made on the first export); stored absolute, with symlinks
    resolved when the ExportDirectory is made."""
    max_stem_chars: int = 48
    """Longest stem taken from a view name (characters, 1..128)."""

    def __post_init__(self) -> None:
        if not 1 <= self.max_stem_chars <= 128:
            raise ConfigurationError(
                f"max_stem_chars must be in [1, 128] characters, got {self.max_stem_chars}"
            )
        root = Path(self.root).expanduser().resolve()
        if root.exists() and not root.is_dir():
            raise ConfigurationError(f"export directory {root} exists and is not a directory")
        object.__setattr__(self, "root", root)

    def path_for(self, view_name: str, when: dt.datetime | None = None) -> Path:
        """A path for a new export of ``view_name`` at ``when`` (now, UTC, if omitted): a
        direct child of :attr:`root` that does not exist yet (not even as a symlink)."""
        stem = export_file_stem(view_name, self.max_stem_chars)
        stamp = (when or dt.datetime.now(dt.UTC)).astimezone(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
        for k in range(1, 1000):
            name = f"{stem}_{stamp}{'' if k == 1 else f'-{k}'}{EXPORT_SUFFIX}"
            path = self.root / name
            if not os.path.lexists(path):
                return self._checked(path)
        raise ExportError(f"999 exports of {stem!r} in the second {stamp}: try again")

    def _checked(self, path: Path) -> Path:
        """Refuse a path that is not a plain direct child of the root (never expected: the
        names are made above; this is the last line of defence)."""
        name = path.name
        if (
            path.parent != self.root
            or name in ("", ".", "..")
            or "/" in name
            or "\\" in name
            or "\0" in name
        ):
            raise UnsafeExportPathError(f"refused export path {str(path)!r}: not in {self.root}")
        return path

    def write_clip(self, clip: ViewClip, when: dt.datetime | None = None) -> Path:
        """Write ``clip`` as a new DICOM file in the directory; returns its path.

        Raises
        ------
        UnsafeExportPathError
            The directory was replaced by a symlink (or moved) since it was configured.
        ExportError
            The file could not be written (disk full, permissions, ...).
        """
        ds = _clip_dataset(
            clip.frames,
            clip.frame_time_s,
            clip.q_motor,
            clip.tip2base,
            acquired_at=clip.acquired_at,
            view_name=clip.view_name,
            pixel_mm=clip.pixel_mm,
            cardiac_phases=clip.cardiac_phases,
        )
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ExportError(f"cannot make the export directory {self.root}: {exc}") from exc
        if self.root.resolve() != self.root:
            raise UnsafeExportPathError(
                f"export directory {self.root} now leads to {self.root.resolve()} "
                "(replaced by a symlink?): refused"
            )
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
        try:
            dir_fd = os.open(self.root, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
        except OSError as exc:
            raise UnsafeExportPathError(f"cannot open {self.root} as a directory: {exc}") from exc
        try:
            for _ in range(1000):
                path = self.path_for(clip.view_name, when)
                try:
                    fd = os.open(path.name, flags, 0o644, dir_fd=dir_fd)
                except FileExistsError:  # made between the check and the open: next name
                    continue
                except OSError as exc:
                    raise ExportError(f"cannot create {path}: {exc}") from exc
                try:
                    with os.fdopen(fd, "wb") as f:
                        ds.save_as(f, enforce_file_format=True)
                except (OSError, ValueError) as exc:
                    with contextlib.suppress(OSError):
                        os.unlink(path.name, dir_fd=dir_fd)
                    raise ExportError(f"cannot write {path}: {exc}") from exc
                return path
            raise ExportError(f"no free file name for {clip.view_name!r} in {self.root}")
        finally:
            os.close(dir_fd)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m icenav.persistence.dicom CLIP.npz OUT.dcm``: export a clip kept in an .npz.

    The .npz holds ``frames`` (n, rows, cols) uint8, ``frame_time_s``, ``q_motor`` (4,),
    ``tip2base`` (4, 4) and optionally ``view_name``, ``pixel_mm``, ``cardiac_phases``.
    """
    parser = argparse.ArgumentParser(
        prog="icenav export-view", description="Export a view's clip as ultrasound DICOM."
    )
    parser.add_argument("clip", help=".npz with frames, frame_time_s, q_motor, tip2base")
    parser.add_argument("out", help="output DICOM file")
    parser.add_argument("--view-name", default=None, help="overrides the name in the .npz")
    args = parser.parse_args(list(argv) if argv is not None else None)
    try:
        with np.load(args.clip) as data:
            missing = [
                k for k in ("frames", "frame_time_s", "q_motor", "tip2base") if k not in data
            ]
            if missing:
                print(f"icenav export-view: {args.clip} lacks {missing}", file=sys.stderr)
                return 2
            name = args.view_name
            if name is None:
                name = str(data["view_name"]) if "view_name" in data else ""
            n_frames = int(np.shape(data["frames"])[0])
            out = export_view_clip(
                args.out,
                data["frames"],
                float(data["frame_time_s"]),
                data["q_motor"],
                data["tip2base"],
                view_name=name,
                pixel_mm=float(data["pixel_mm"]) if "pixel_mm" in data else None,
                cardiac_phases=data.get("cardiac_phases", None),
            )
    except (OSError, ValueError) as exc:
        print(f"icenav export-view: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out} ({n_frames} frames)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
