"""Fuzz targets for icenav's loaders and parsers, shared by the atheris harnesses
(``fuzz/fuzz_*.py``) and by the seeded-mutation test (``tests/reliability/``).

Each target takes raw bytes, feeds them to one loader or parser the way a file or a client
would, and returns normally when the input was accepted or rejected with an
:class:`~icenav.errors.IcenavError`. Anything else (another exception, a crash, a hang) is a
bug the fuzzer reports. Accepted results are also checked for the loader's own invariants.

``SEEDS`` holds valid inputs of each kind; :func:`mutate` derives inputs from them the way
a byte-level fuzzer does (flips, insertions, deletions, truncation, splices, interesting
values), so the corpus test needs no atheris.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import random
import sqlite3
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from icenav.errors import IcenavError

__all__ = ["SEEDS", "TARGETS", "mutate", "seed_inputs"]

_EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _tmp(data: bytes, suffix: str) -> Path:
    fd, name = tempfile.mkstemp(suffix=suffix, prefix="icenav-fuzz-")
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)
    return Path(name)


def _remove(path: Path) -> None:
    for p in (path, *(Path(str(path) + x) for x in ("-wal", "-shm", "-journal", ".lock"))):
        p.unlink(missing_ok=True)


# ------------------------------------------------------------------ targets


def target_store(data: bytes) -> None:
    """A session file from disk: open, load roadmap, views, calibrations and events."""
    from icenav.persistence.store import SessionStore

    path = _tmp(data, ".icenav")
    try:
        try:
            with SessionStore(path) as store:
                rm = store.load_roadmap()
                views = store.load_views()
                store.calibrations()
                store.events()
        except IcenavError:
            return
        # accepted: the roadmap refers only to its own vertices, views hold finite states
        uv, w = rm.edges()
        assert uv.size == 0 or (uv.min() >= 0 and uv.max() < rm.n_vertices)
        assert np.all(np.isfinite(rm.vertices()))
        for v in views:
            assert np.all(np.isfinite(v.q)) and v.name.strip()
    finally:
        _remove(path)


_COLUMNS = {
    "vertices": ("id", "phi1", "phi2", "phi3", "d4"),
    "edges": ("u", "v", "w"),
    "trace": ("seq", "vertex"),
    "views": (
        "name",
        "vertex",
        "phi1",
        "d4",
        "created_s",
        "arrival",
        "approach",
        "tip2base",
        "thumbnail",
        "notes",
        "ordinal",
    ),
    "meta": ("key", "value"),
    "events": ("t", "kind", "data"),
    "calibrations": ("kind", "data", "created_s"),
}
_VALUES: tuple[object, ...] = (
    None,
    -1,
    0,
    2**62,
    1e308,
    -1e308,
    "x",
    "",
    "[1, 2",
    "{}",
    "[]",
    "[0, 0, 0]",
    b"\x00",
    b"\x93NUMPY",
    "\u202e",
    3.5,
    "inf",
    '{"epsilon": -1}',
    "nan",
)


def target_store_rows(data: bytes) -> None:
    """A well-formed SQLite session whose rows were edited: every byte triple of ``data``
    sets one cell (table, column, row) to an awkward value, then the file is loaded."""
    path = _tmp(_store_seed_cached(), ".icenav")
    try:
        with sqlite3.connect(path) as db:
            tables = list(_COLUMNS)
            for i in range(0, len(data) - 2, 3):
                table = tables[data[i] % len(tables)]
                cols = _COLUMNS[table]
                col = cols[data[i + 1] % len(cols)]
                value = _VALUES[data[i + 2] % len(_VALUES)]
                offset = data[i + 2] // len(_VALUES)
                # NOT NULL / WITHOUT ROWID / unique refused: the file keeps its old cell
                with contextlib.suppress(sqlite3.DatabaseError):
                    db.execute(
                        f"UPDATE {table} SET {col}=? WHERE rowid = "
                        f"(SELECT rowid FROM {table} LIMIT 1 OFFSET ?)",
                        (value, offset),
                    )
        target_store(path.read_bytes())
    finally:
        _remove(path)


_STORE_SEED: list[bytes] = []


def _store_seed_cached() -> bytes:
    if not _STORE_SEED:
        _STORE_SEED.append(_store_seed())
    return _STORE_SEED[0]


def target_robot_config(data: bytes) -> None:
    """A robot configuration TOML file (hw.config.load_robot_config)."""
    from icenav.devices.canopen.config import load_robot_config

    path = _tmp(data, ".toml")
    try:
        try:
            cfg = load_robot_config(path)
        except IcenavError:
            return
        assert len(cfg.joints) == 4 and len(cfg.motors) >= 4
    finally:
        _remove(path)


def target_joystick_mapping(data: bytes) -> None:
    """A gamepad mapping TOML file (io.joystick.load_mapping)."""
    from icenav.control.teleop import load_mapping

    path = _tmp(data, ".toml")
    try:
        try:
            m = load_mapping(path)
        except IcenavError:
            return
        assert 0.0 <= m.deadzone < 1.0 and math.isfinite(m.knob_rate) and m.knob_rate > 0
    finally:
        _remove(path)


def target_calibration(data: bytes) -> None:
    """A calibration file (compensation.CalibrationSet.load)."""
    from icenav.compensation.elasticity import CalibrationSet

    path = _tmp(data, ".json")
    try:
        try:
            cal = CalibrationSet.load(path)
        except IcenavError:
            return
        assert np.all(np.isfinite(cal.q_motor)) and np.all(np.isfinite(cal.tip2base))
    finally:
        _remove(path)


def target_igtl_command(data: bytes) -> None:
    """An OpenIGTLink command STRING as a client sends it: every line gets exactly one
    reply, and only well-formed enabled commands reach the callback."""
    from icenav.io.igtl import IgtlCommand, IgtlConfig, IgtlOutcome, IgtlRequest, parse_command

    text = data.decode("utf-8", errors="replace")
    config = IgtlConfig(accepted_commands=frozenset(IgtlCommand))
    for line in text.splitlines():
        parsed = parse_command(line, config)
        if isinstance(parsed, IgtlRequest):
            assert isinstance(parsed.command, IgtlCommand)
            assert parsed.argument == parsed.argument.strip()
            assert parsed.command is IgtlCommand.STOP or parsed.argument
        else:
            assert parsed.outcome is IgtlOutcome.REFUSED and parsed.reason


def target_igtl_message(data: bytes) -> None:
    """Bytes as a peer sends them after the header's 58 bytes: header checks, CRC and body
    decoding (io.igtl_wire) raise only IgtlProtocolError."""
    from pyigtl.messages import CRC64

    from icenav.io.igtl_wire import HEADER_SIZE, decode_body, parse_header

    if len(data) < HEADER_SIZE:
        return
    try:
        header = parse_header(data[:HEADER_SIZE], max_body_bytes=1 << 20)
    except IcenavError:
        return
    body = data[HEADER_SIZE : HEADER_SIZE + header.body_size]
    for crc_ok in (False, True):
        if crc_ok:  # the same body with a matching CRC reaches the decoders
            header = type(header)(**{**header.__dict__, "crc": CRC64(body)})
        try:
            message = decode_body(header, body)
        except IcenavError:
            continue
        matrix = getattr(message, "matrix", None)
        assert matrix is None or bool(np.all(np.isfinite(matrix)))


TARGETS: dict[str, Callable[[bytes], None]] = {
    "store": target_store,
    "store_rows": target_store_rows,
    "robot_config": target_robot_config,
    "joystick_mapping": target_joystick_mapping,
    "calibration": target_calibration,
    "igtl_command": target_igtl_command,
    "igtl_message": target_igtl_message,
}
"""name -> target; ``fuzz/fuzz_<name>.py`` runs each under atheris."""


# ------------------------------------------------------------------ seeds


def _store_seed() -> bytes:
    from icenav.persistence.store import SessionStore
    from icenav.recovery.roadmap import Roadmap

    rng = np.random.default_rng(7)
    rm = Roadmap(epsilon=2.0)
    q = np.zeros(4)
    for _ in range(60):
        q = q + rng.normal(0, [0.02, 0.02, 0.03, 0.4])
        rm.add(np.clip(q, [-1.5, -1.5, -6, -45], [1.5, 1.5, 6, 45]))
    view = rm.make_view("apex", created_s=1.0, q=rm.vertices()[-1])
    fd, name = tempfile.mkstemp(suffix=".icenav", prefix="icenav-seed-")
    os.close(fd)
    path = Path(name)
    path.unlink()
    try:
        with SessionStore(path) as store:
            store.sync_roadmap(rm)
            store.add_view(view, rm)
            store.log_event(1.0, "fault", {"text": "drive 2"})
            store.save_calibration("c", "dense", {"n": 1}, 2.0)
        with sqlite3.connect(path) as db:  # one self-contained file, no WAL beside it
            db.execute("PRAGMA journal_mode=DELETE")
        return path.read_bytes()
    finally:
        _remove(path)


def _calibration_seed() -> bytes:
    from icenav.geometry.kinematics import forward

    q = np.array([[0.1, 0.0, 0.0, 0.0], [0.0, 0.2, 0.1, 1.0], [0.3, -0.2, 0.0, 2.0]])
    doc = {
        "format": "icenav.calibration.plans",
        "version": 1,
        "catheter_id": "seed",
        "vessel": "straight",
        "created": "2026-01-01",
        "method": "dense",
        "notes": "",
        "q_motor": q.tolist(),
        "tip2base": forward(q).tolist(),
    }
    return json.dumps(doc, indent=1).encode()


_JOYSTICK_SEED = b"""[joystick]
axis_phi1 = 1
axis_phi2 = 0
invert = [true, false, false, true]
deadzone = 0.1
knob_rate_deg = 30
roll_rate_deg = 45.0
translation_rate = 5.0
enable_button = 4
"""

_IGTL_SEEDS = [
    b"stop",
    b"save_view aortic valve",
    b"go_to_view apex",
    b"GO_TO_VIEW  x ",
    b"stop\nsave_view a\n\ngo_to_view a",
]


def _igtl_message_seeds() -> list[bytes]:
    import pyigtl

    eye = np.eye(4)
    eye[:3, 3] = (1.0, 2.0, 3.0)
    v2 = pyigtl.StringMessage("go_to_view apex", device_name="IcenavCommand")
    v2.header_version = 2
    v2.metadata = {"k": "v"}
    return [
        bytes(pyigtl.StringMessage("stop", device_name="IcenavCommand").pack()),
        bytes(pyigtl.TransformMessage(eye, device_name="TipToBase").pack()),
        bytes(v2.pack()),
    ]


def seed_inputs(name: str) -> list[bytes]:
    """Valid inputs for target ``name``."""
    if name == "store":
        return [_store_seed_cached()]
    if name == "store_rows":
        return [bytes([0, 1, 200]), bytes([3, 5, 6, 3, 6, 7]), bytes(range(0, 60, 1))]
    if name == "robot_config":
        return [(_EXAMPLES / "robot.toml").read_bytes()]
    if name == "joystick_mapping":
        return [_JOYSTICK_SEED, b""]
    if name == "calibration":
        return [_calibration_seed()]
    if name == "igtl_command":
        return list(_IGTL_SEEDS)
    if name == "igtl_message":
        return _igtl_message_seeds()
    raise KeyError(name)


SEEDS = tuple(TARGETS)
"""Names of the targets that have seeds (all)."""

_INTERESTING = [
    b"\x00",
    b"\xff",
    b"nan",
    b"inf",
    b"-1",
    b"1e309",
    b"9" * 30,
    b'"',
    b"[",
    b"]]",
    b"{",
    b"=",
    b"\n",
    b"\x1b[2J",
    b"../../etc/passwd",
    "\u202e".encode(),
]


def mutate(data: bytes, rng: random.Random, n_ops: int = 3) -> bytes:
    """``data`` after ``n_ops`` random byte-level mutations."""
    b = bytearray(data)
    for _ in range(n_ops):
        op = rng.randrange(7)
        pos = rng.randrange(len(b) + 1)
        if op == 0 and b:  # flip bits
            i = min(pos, len(b) - 1)
            b[i] ^= 1 << rng.randrange(8)
        elif op == 1:  # insert random bytes
            b[pos:pos] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 8)))
        elif op == 2 and b:  # delete a run
            del b[pos : pos + rng.randrange(1, 16)]
        elif op == 3:  # truncate
            del b[pos:]
        elif op == 4:  # interesting token
            b[pos:pos] = rng.choice(_INTERESTING)
        elif op == 5 and b:  # duplicate a chunk elsewhere (splice)
            j = rng.randrange(len(b))
            chunk = bytes(b[j : j + rng.randrange(1, 64)])
            b[pos:pos] = chunk
        elif b:  # overwrite a byte with a boundary value
            i = min(pos, len(b) - 1)
            b[i] = rng.choice([0, 1, 0x7F, 0x80, 0xFF, ord("0"), ord("-")])
    return bytes(b)
