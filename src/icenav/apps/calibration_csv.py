"""Calibration recordings as CSV: the format, its reader, a recorder, and the replay.

The format (one tracker sample a row, comma-separated, a header line with these names in
this order; blank lines and lines starting with ``#`` are ignored)::

    t_s, phi1_rad, phi2_rad, phi3_rad, d4_mm, x_mm, y_mm, z_mm, qw, qx, qy, qz, status

- ``t_s``: time of the sample (s), non-decreasing;
- ``phi1_rad, phi2_rad, phi3_rad, d4_mm``: the motor joint state commanded when the
  sample was taken (the robot at rest there), within the joint limits;
- ``x_mm, y_mm, z_mm, qw, qx, qy, qz``: the EM sensor's pose in the tracker frame (position
  in mm, unit quaternion w first, as the NDI Aurora reports it); empty unless ``status`` is
  ``valid``;
- ``status``: ``valid``, ``missing`` or ``out_of_volume`` (:class:`icenav.devices.tracker.
  ToolStatus`; case-insensitive).

Consecutive rows at the same joint state are one *visit* (the mean of their valid poses).
:class:`ReplayTracker` replays a recording to a calibration procedure of the control core
(``make_procedure(kind)`` run by ``run_procedure``): each state the procedure asks for is
looked up in the recording, in order (a state not recorded reads as missing), so the
procedure fits exactly what it would have measured. :class:`RecordingTracker` wraps a
tracker and writes the rows while a procedure runs (on the twin or on a bench).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from icenav._typing import Array
from icenav.devices.tracker import ToolStatus, mean_sensor_pose
from icenav.errors import FileFormatError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry

__all__ = [
    "CSV_COLUMNS",
    "CsvSamples",
    "RecordingTracker",
    "ReplayTracker",
    "read_calibration_csv",
]

CSV_COLUMNS = (
    "t_s",
    "phi1_rad",
    "phi2_rad",
    "phi3_rad",
    "d4_mm",
    "x_mm",
    "y_mm",
    "z_mm",
    "qw",
    "qx",
    "qy",
    "qz",
    "status",
)
"""The columns of a calibration recording, in order."""

_MAX_LISTED = 20  # bad rows listed in an error message
_QUAT_NORM_TOL = 1e-2  # the Aurora sends 4 significant digits


@dataclass(frozen=True, eq=False)
class CsvSamples:
    """The rows of a calibration recording."""

    t_s: Array
    """(n,) sample times (s)."""
    q_motor: Array
    """(n, 4) commanded motor joint states (rad, rad, rad, mm)."""
    sensor2tracker: Array
    """(n, 4, 4) sensor poses in the tracker frame (mm); NaN unless valid."""
    valid: NDArray[np.bool_]
    """(n,) status ``valid``."""
    line: NDArray[np.int64]
    """(n,) line number of each row in the file (1-based)."""
    skipped: tuple[str, ...] = ()
    """Bad rows that were skipped (``line N: why``), with ``skip_bad_rows``."""

    @property
    def n(self) -> int:
        """Number of rows."""
        return int(self.t_s.shape[0])


def _quat_to_matrix(w: float, x: float, y: float, z: float) -> Array:
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _matrix_to_quat(r: Array) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z) of a rotation matrix (w >= 0)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(r).as_quat()
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    return float(w), float(x), float(y), float(z)


def _parse_row(
    fields: list[str], geometry: CatheterGeometry
) -> tuple[float, Array, Array | None, ToolStatus]:
    """One data row; FileFormatError with the reason (the caller adds the line number)."""
    if len(fields) != len(CSV_COLUMNS):
        raise FileFormatError(f"{len(fields)} columns, expected {len(CSV_COLUMNS)}")
    try:
        status = ToolStatus(fields[12].strip().lower())
    except ValueError:
        allowed = ", ".join(s.value for s in ToolStatus)
        raise FileFormatError(f"status {fields[12].strip()!r} is not one of {allowed}") from None
    numbers: list[float] = []
    for name, text in zip(CSV_COLUMNS[:5], fields[:5], strict=True):
        try:
            v = float(text)
        except ValueError:
            raise FileFormatError(f"{name} {text.strip()!r} is not a number") from None
        if not math.isfinite(v):
            raise FileFormatError(f"{name} is {v}, not a finite number")
        numbers.append(v)
    t, q = numbers[0], np.array(numbers[1:5])
    lo, hi = geometry.joint_limits[:, 0], geometry.joint_limits[:, 1]
    for j, name in enumerate(CSV_COLUMNS[1:5]):
        if not lo[j] <= q[j] <= hi[j]:
            unit = "mm" if j == 3 else "rad"
            raise FileFormatError(
                f"{name} {q[j]:g} {unit} is outside [{lo[j]:g}, {hi[j]:g}] {unit}"
            )
    if status is not ToolStatus.VALID:
        if any(f.strip() for f in fields[5:12]):
            raise FileFormatError(f"a {status.value} row must leave the pose columns empty")
        return t, q, None, status
    pose_numbers: list[float] = []
    for name, text in zip(CSV_COLUMNS[5:12], fields[5:12], strict=True):
        try:
            v = float(text)
        except ValueError:
            raise FileFormatError(
                f"{name} {text.strip()!r} is not a number (status valid)"
            ) from None
        if not math.isfinite(v):
            raise FileFormatError(f"{name} is {v}, not a finite number")
        pose_numbers.append(v)
    norm = math.sqrt(sum(v * v for v in pose_numbers[3:]))
    if abs(norm - 1.0) > _QUAT_NORM_TOL:
        raise FileFormatError(f"quaternion (qw, qx, qy, qz) has norm {norm:.4f}, not 1")
    pose = np.eye(4)
    pose[:3, :3] = _quat_to_matrix(*pose_numbers[3:])
    pose[:3, 3] = pose_numbers[:3]
    return t, q, pose, status


def read_calibration_csv(
    path: str | Path,
    *,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    skip_bad_rows: bool = False,
) -> CsvSamples:
    """Read a calibration recording (see the module docstring).

    Raises FileFormatError naming the file and, for bad rows, each row's line number and what
    is wrong (the first 20, and how many there are); with ``skip_bad_rows`` the bad rows are
    left out instead and listed in :attr:`CsvSamples.skipped`.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise FileFormatError(f"{p}: not a UTF-8 text (CSV) file") from exc
    except OSError as exc:
        raise FileFormatError(f"cannot read the calibration recording {p}: {exc}") from exc
    reader = csv.reader(io.StringIO(text))
    header: list[str] | None = None
    rows: list[tuple[float, Array, Array | None, ToolStatus, int]] = []
    bad: list[str] = []
    for fields in reader:
        line = reader.line_num
        if not fields or not "".join(fields).strip() or fields[0].lstrip().startswith("#"):
            continue
        if header is None:
            header = [f.strip() for f in fields]
            if tuple(header) != CSV_COLUMNS:
                raise FileFormatError(
                    f"{p}: line {line}: the header must be {','.join(CSV_COLUMNS)}; "
                    f"got {','.join(header)}"
                )
            continue
        try:
            t, q, pose, status = _parse_row(fields, geometry)
        except ValueError as exc:
            bad.append(f"line {line}: {exc}")
            continue
        if rows and t < rows[-1][0]:
            bad.append(f"line {line}: t_s {t:g} s is before the previous row's {rows[-1][0]:g} s")
            continue
        rows.append((t, q, pose, status, line))
    if header is None:
        raise FileFormatError(f"{p}: empty: no header line ({','.join(CSV_COLUMNS)})")
    if bad and not skip_bad_rows:
        listed = "\n  ".join(bad[:_MAX_LISTED])
        more = f"\n  ... and {len(bad) - _MAX_LISTED} more" if len(bad) > _MAX_LISTED else ""
        raise FileFormatError(
            f"{p}: {len(bad)} bad row(s) (use --skip-bad-rows to leave them out):\n  {listed}{more}"
        )
    if not rows:
        raise FileFormatError(f"{p}: no data rows after the header")
    poses = np.full((len(rows), 4, 4), np.nan)
    for i, r in enumerate(rows):
        if r[2] is not None:
            poses[i] = r[2]
    return CsvSamples(
        t_s=np.array([r[0] for r in rows]),
        q_motor=np.array([r[1] for r in rows]),
        sensor2tracker=poses,
        valid=np.array([r[3] is ToolStatus.VALID for r in rows]),
        line=np.array([r[4] for r in rows], dtype=np.int64),
        skipped=tuple(bad),
    )


class ReplayTracker:
    """A recording as the tracker (and ``move``) of a calibration procedure.

    ``move(q)`` says where the procedure went. A reading of ``n_average`` samples
    (``measure_sensor2tracker``, or ``measure_tip2base`` through ``registration``) takes the
    next ``n_average`` rows recorded at that state (joints within ``joint_tol``, rad or mm):
    the rest of the current visit when it is at that state, else the next visit at that state
    after the last one used; it returns the mean of their valid poses, or None (missing) when
    none is valid or no such visit follows. This is what :class:`RecordingTracker` wrote, so
    a procedure replays exactly what it measured (its retries and repeated states included);
    rows of a visit beyond what the procedure reads are left unused.
    """

    def __init__(
        self,
        samples: CsvSamples,
        joint_tol: float = 1e-3,
        registration: Any = None,
        ordered: bool = True,
    ):
        self.samples = samples
        self.registration = registration
        self.joint_tol = float(joint_tol)
        self.ordered = bool(ordered)
        """False: a state is looked up among all visits not used yet, in any order (a static
        raster recorded in another order than the procedure's)."""
        q = samples.q_motor
        change = np.any(np.abs(np.diff(q, axis=0)) > 1e-12, axis=1)
        starts = np.concatenate([[0], np.flatnonzero(change) + 1])
        ends = np.concatenate([starts[1:], [samples.n]])
        self._q = q[starts]
        self._spans = list(zip(starts.tolist(), ends.tolist(), strict=True))
        self._next = 0  # the first visit not used yet
        self._used = np.zeros(len(self._spans), dtype=bool)
        self._run: int | None = None  # the visit being read
        self._cursor = 0  # its next row
        self._q_now: Array | None = None
        self._new_visit = False
        self._counted: set[str] = set()
        self.asked = 0
        """States the procedure read at."""
        self.found = 0
        """Of them, states found in the recording (tracked or not)."""
        self.tracked = 0
        """Of them, states with at least one valid pose read."""

    @property
    def n_visits(self) -> int:
        """Visits in the recording (runs of rows at one joint state)."""
        return len(self._spans)

    def visits(self) -> tuple[Array, Array]:
        """Every recorded visit: joint states (m, 4) and the mean valid sensor pose of each in
        the tracker frame (m, 4, 4; NaN when none was valid)."""
        poses = np.full((len(self._spans), 4, 4), np.nan)
        for k, (a, b) in enumerate(self._spans):
            pose = mean_sensor_pose_of(self.samples.sensor2tracker[a:b][self.samples.valid[a:b]])
            if pose is not None:
                poses[k] = pose
        return self._q.copy(), poses

    def move(self, q_motor: Array) -> None:
        """The procedure goes to ``q_motor`` (4,)."""
        self._q_now = np.asarray(q_motor, dtype=np.float64)
        self._new_visit = True

    def _at(self, k: int) -> bool:
        assert self._q_now is not None
        return bool(np.all(np.abs(self._q[k] - self._q_now) <= self.joint_tol))

    def _rows(self, n: int) -> tuple[int, int] | None:
        """The next ``n`` rows at the current state (fewer at a visit's end), or None."""
        if (
            self._run is None
            or not self._at(self._run)
            or self._cursor >= self._spans[self._run][1]
        ):
            start = self._next if self.ordered else 0
            near = np.all(np.abs(self._q[start:] - self._q_now) <= self.joint_tol, axis=1)
            hits = np.flatnonzero(near & ~self._used[start:])
            if hits.size == 0:
                return None
            self._run = start + int(hits[0])
            self._used[self._run] = True
            self._next = self._run + 1
            self._cursor = self._spans[self._run][0]
        a = self._cursor
        b = min(a + max(int(n), 1), self._spans[self._run][1])
        self._cursor = b
        return a, b

    def _lookup(self, n: int) -> Array | None:
        assert self._q_now is not None, "move() before a reading"
        if self._new_visit:
            self._new_visit = False
            self._counted = set()
            self.asked += 1
        rows = self._rows(n)
        if rows is None:
            return None
        if "found" not in self._counted:
            self._counted.add("found")
            self.found += 1
        a, b = rows
        pose = mean_sensor_pose_of(self.samples.sensor2tracker[a:b][self.samples.valid[a:b]])
        if pose is not None and "tracked" not in self._counted:
            self._counted.add("tracked")
            self.tracked += 1
        return pose

    def measure_sensor2tracker(self, n_average: int = 1) -> Array | None:
        """The mean valid sensor pose (4, 4) of the next ``n_average`` rows at this state."""
        return self._lookup(n_average)

    def measure_tip2base(self, n_average: int = 1) -> Array | None:
        """The same through :attr:`registration` (None when unregistered)."""
        pose = self._lookup(n_average)
        if pose is None or self.registration is None:
            return None
        tip2base: Array = self.registration.tip2base(pose)
        return tip2base


def mean_sensor_pose_of(poses: Array) -> Array | None:
    """Mean (4, 4) of poses (k, 4, 4) as the tracker averages (None when k = 0)."""
    if poses.shape[0] == 0:
        return None
    from icenav.geometry.se3 import pose_mean

    return np.asarray(pose_mean(poses), dtype=np.float64)


class RecordingTracker:
    """Wraps a tracker and writes one CSV row per sample while a procedure runs.

    Each reading of ``n_average`` samples asks the wrapped tracker for ``n_average`` single
    samples (``measure_sensor2tracker(1)``), writes them at the joint state of the last
    :meth:`move` with the time of ``clock``, and returns their mean (through the wrapped
    tracker's registration for ``measure_tip2base``), as the wrapped tracker would.
    """

    def __init__(self, tracker: Any, out: TextIO, clock: Callable[[], float]):
        self.tracker = tracker
        self.registration = tracker.registration
        self._out = csv.writer(out, lineterminator="\n")
        self._out.writerow(CSV_COLUMNS)
        self._clock = clock
        self._q = np.zeros(4)
        self.rows = 0

    def move(self, q_motor: Array) -> None:
        """The joint state the next rows are written at."""
        self._q = np.asarray(q_motor, dtype=np.float64)

    def measure_sensor2tracker(self, n_average: int = 1) -> Array | None:
        frames = []
        for _ in range(int(n_average)):
            pose = self.tracker.measure_sensor2tracker(1)
            t = float(self._clock())
            q = [repr(float(v)) for v in self._q]
            if pose is None:
                self._out.writerow([repr(t), *q, "", "", "", "", "", "", "", "missing"])
            else:
                p = np.asarray(pose, dtype=np.float64)
                quat = _matrix_to_quat(p[:3, :3])
                pos = [repr(float(v)) for v in p[:3, 3]]
                self._out.writerow([repr(t), *q, *pos, *(repr(v) for v in quat), "valid"])
                frames.append(_frame(p))
            self.rows += 1
        return mean_sensor_pose(frames)

    def measure_tip2base(self, n_average: int = 1) -> Array | None:
        pose = self.measure_sensor2tracker(n_average)
        if pose is None or self.registration is None:
            return None
        tip2base: Array = self.registration.tip2base(pose)
        return tip2base


def _frame(pose: Array) -> Any:
    """A VALID tracker frame of ``pose`` (as written: through its quaternion)."""
    from icenav.devices.tracker import TrackerFrame

    written = np.eye(4)
    written[:3, :3] = _quat_to_matrix(*_matrix_to_quat(pose[:3, :3]))
    written[:3, 3] = pose[:3, 3]
    return TrackerFrame(0.0, written, ToolStatus.VALID, 1.0)
