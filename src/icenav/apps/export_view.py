"""``icenav export-view``: a saved view's image as ultrasound DICOM, from a session file.

::

    icenav export-view --session FILE --view NAME [--out DIR]
    icenav export-view CLIP.npz OUT.dcm [--view-name NAME]     # a clip kept in an .npz

The session (opened read-only: a running console may hold it) gives the view's image (the
live ICE image at the moment it was saved), its motor joint state and its tip pose; the file
is written into ``--out`` (default ``exports/`` beside the session) with a name made by the
program (:class:`icenav.persistence.dicom.ExportDirectory`, as the console's Export DICOM
button), and its path printed. The ``.npz`` form is :func:`icenav.persistence.dicom.main`.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from icenav.errors import ExportError, IcenavError, StoreError

__all__ = ["main"]

SINGLE_FRAME_TIME_S = 0.05
"""Frame time written for a one-frame export (s; DICOM needs one)."""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="icenav export-view",
        description="Export a saved view's image (with its joint state and pose) from a "
        "session file as ultrasound DICOM.",
    )
    p.add_argument("--session", type=Path, required=True, metavar="FILE", help="session file")
    p.add_argument("--view", required=True, metavar="NAME", help="the saved view's name")
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="directory to write into (default: exports/ beside the session file)",
    )
    return p


def export_from_session(session: Path, view: str, out: Path | None) -> Path:
    """Write view ``view`` of ``session`` into ``out``; the file written."""
    from icenav.persistence.dicom import ExportDirectory, ViewClip
    from icenav.persistence.store import SessionStore

    if not session.is_file():
        raise StoreError(f"{session}: no such session file")
    with SessionStore(session, read_only=True) as store:
        views = store.load_views()
    names = [v.name for v in views]
    if view not in names:
        saved = ", ".join(repr(n) for n in names) or "none"
        raise ExportError(f"{session}: no saved view named {view!r} (saved views: {saved})")
    v = views.get(view)
    if v.thumbnail is None:
        raise ExportError(f"{session}: view {view!r} has no saved image: nothing to export")
    pixels = np.asarray(v.thumbnail, dtype=np.uint8)
    if pixels.ndim == 3:  # RGB: grey for MONOCHROME2
        pixels = pixels.mean(axis=2).round().astype(np.uint8)
    tip2base = v.tip2base
    if tip2base is None:
        from icenav.geometry.kinematics import forward

        tip2base = forward(v.q)
    root = out if out is not None else session.parent / "exports"
    clip = ViewClip(
        frames=pixels[np.newaxis],
        frame_time_s=SINGLE_FRAME_TIME_S,
        acquired_at=dt.datetime.fromtimestamp(v.created_s, dt.UTC),
        q_motor=np.asarray(v.q, dtype=np.float64),
        tip2base=np.asarray(tip2base, dtype=np.float64),
        view_name=view,
    )
    return ExportDirectory(root.expanduser().absolute()).write_clip(clip)


def main(argv: Sequence[str] | None = None) -> int:
    args_in = list(sys.argv[1:] if argv is None else argv)
    if args_in and not args_in[0].startswith("-") and args_in[0].endswith(".npz"):
        from icenav.persistence.dicom import main as npz_main

        return npz_main(args_in)
    parser = _parser()
    args = parser.parse_args(args_in)
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        parser.error(f"--out {args.out} exists and is not a directory")
    try:
        path = export_from_session(args.session, args.view, args.out)
    except IcenavError as exc:
        print(f"icenav export-view: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {path}")
    return 0
