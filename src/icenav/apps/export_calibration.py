"""``icenav export-calibration``: the calibration in use of a session, as a calibration file.

::

    icenav export-calibration --session FILE --out CAL.json

The session (opened read-only: a running console may hold it) stores the calibration in use
(a calibration finished in the console, or the ``--calibration`` file installed) as its
calibration-file document, fitted model included; this writes it out, with the session's
registration of the tracker when it has one, for ``icenav demo|serve|run --calibration`` on
another session or machine and for ``icenav eval spin --calibration``. A command rather than
a console button: it works on a closed (or crashed) session, needs no browser, and scripts
well -- as ``icenav export-view --session``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from icenav.errors import IcenavError, StoreError

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="icenav export-calibration",
        description="Write the calibration in use of a session file (samples, fitted model "
        "and the session's registration) as a calibration file.",
    )
    p.add_argument("--session", type=Path, required=True, metavar="FILE", help="session file")
    p.add_argument(
        "--out", type=Path, required=True, metavar="CAL.json", help="calibration file to write"
    )
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    return p


def export_calibration(session: Path, out: Path, *, force: bool = False) -> str:
    """Write ``session``'s calibration in use to ``out``; returns what was written.
    StoreError when the session holds none; FileFormatError when it cannot be read."""
    from dataclasses import replace

    from icenav.calibration.files import CalibrationFile
    from icenav.persistence.store import SessionStore

    if out.exists() and not force:
        raise StoreError(f"--out {out} exists: give --force to overwrite it")
    with SessionStore(session, read_only=True) as store:
        stored = store.calibration_document()
        registration = store.registration()
    if stored is None:
        raise StoreError(
            f"{session}: the session holds no calibration in use (run a calibration in the "
            "console, or start it with --calibration FILE)"
        )
    loaded = CalibrationFile.from_dict(stored[1], f"{session}: calibration in use")
    if loaded.registration is None and registration is not None:
        loaded = replace(loaded, registration=registration)
    loaded.save(out)
    return f"wrote {out}: {loaded.describe()}"


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if not args.session.is_file():
        parser.error(f"--session {args.session}: no such file")
    if args.out.is_dir():
        parser.error(f"--out {args.out} is a directory")
    try:
        print(export_calibration(args.session, args.out, force=args.force))
    except IcenavError as exc:
        print(f"icenav export-calibration: {exc}", file=sys.stderr)
        return 1
    return 0
