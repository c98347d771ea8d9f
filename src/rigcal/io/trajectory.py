"""Trajectory files: TUM and KITTI, as evo and most SLAM tools read them.

- TUM: one pose per line, ``timestamp tx ty tz qx qy qz qw`` (seconds, metres, unit
  quaternion in x, y, z, w order); ``#`` starts a comment. The pose is T_world_body: it
  maps body-frame points into the world frame.
- KITTI: one pose per line, the 12 numbers of the 3x4 matrix [R | t] of T_world_body in
  row-major order; no time stamps.

Readers validate every line and name the file and line number of a bad one. A TUM file
copied while it was written (a SLAM run's, a logger's) ends mid-line: :func:`read_tum_cut`
applies the importers' rule for logs cut short to it (:mod:`rigcal.io.log_lines`: the
incomplete last line left out and returned, or refused with ``strict``); each caller
decides whether its files can be cut short (docs/formats/sequence.md, "Logs cut short").
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.io.files import atomic_write_text, read_text, text_lines
from rigcal.io.log_lines import CutLine, ShortLineError, cut_last_line
from rigcal.io.stamps import check_seconds


@dataclass(frozen=True)
class Trajectory:
    """Poses over time.

    Attributes:
        poses: (N, 4, 4) T_world_body.
        stamps_s: (N,) seconds, increasing; None for KITTI files.
    """

    poses: FloatArray
    stamps_s: FloatArray | None = None

    def __len__(self) -> int:
        return len(self.poses)


def _lines(path: Path, text: str | None = None) -> list[tuple[int, list[str], str]]:
    """(line number, fields, the line) of each line that is not blank or a comment."""
    text = read_text(path, "trajectory file") if text is None else text
    out = []
    for n, line in enumerate(text_lines(text), start=1):
        body = line.split("#", 1)[0].strip()
        if body:
            out.append((n, body.replace(",", " ").split(), line))
    return out


def _numbers(
    path: Path, n: int, fields: list[str], count: int, what: str, hint: str = "", stamped: bool = False
) -> FloatArray:
    """Line ``n``'s ``count`` finite numbers; ``stamped``: the first is a stamp in seconds."""
    if len(fields) != count:
        short = ShortLineError if len(fields) < count else InputError  # fewer: maybe a line cut short
        raise short(f"{path}: line {n}: got {len(fields)} fields; expected {count} ({what}){hint}")
    try:
        v = np.array([float(f) for f in fields])
    except ValueError:
        names = not any(_is_number(f) for f in fields)  # a header row of column names
        raise InputError(
            f"{path}: line {n}: got {' '.join(fields)[:60]!r}; expected {count} numbers"
            + (" (a header line? start it with '#' to make it a comment)" if names else "")
        ) from None
    if not np.all(np.isfinite(v)):
        raise InputError(f"{path}: line {n}: got a non-finite number; expected {count} finite numbers")
    if stamped and abs(v[0]) > MAX_ABS:  # a stamp in ms, us or ns: named as such
        check_seconds(v[:1], f"{path}: line {n}", "timestamp")
    if np.abs(v).max() > MAX_ABS:
        raise InputError(f"{path}: line {n}: got {np.abs(v).max():g}; expected numbers within +-{MAX_ABS:g}")
    return v


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# Stamps (Unix seconds ~2e9) and coordinates (metres) are far below this; beyond it a
# trajectory's squared distances would lose all precision or overflow.
MAX_ABS = 1e12


# A quaternion printed to 3 decimals is within this of unit length; it is normalised.
QUATERNION_NORM_TOLERANCE = 1e-3
_PLANAR_HINT = (
    ": a 2D 'timestamp x y yaw' file? write each pose as 'timestamp x y 0 0 0 sin(yaw/2) cos(yaw/2)'"
)


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory (quaternions are normalised if within 1e-3 of unit length);
    every line must be whole (a file rigcal wrote, or one that cannot have been cut short).

    Raises:
        InputError: a line that is not 8 finite numbers (a 2D file of 3 or 4 columns is
            named as such), a quaternion off unit length, stamps not increasing, no pose.
    """
    return _read_tum(Path(path), None)[0]


def read_tum_cut(path: str | Path, strict: bool) -> tuple[Trajectory, CutLine | None]:
    """:func:`read_tum` of a file that may have been copied while it was written: an
    incomplete last line (too few fields, or no newline and not a whole pose) is left out
    and returned (None when the file is whole), as the importers' logs cut short
    (:mod:`rigcal.io.log_lines`).

    Raises:
        InputError: as :func:`read_tum`; with ``strict`` also for a file cut short, saying so.
    """
    return _read_tum(Path(path), strict)


def _read_tum(path: Path, strict: bool | None) -> tuple[Trajectory, CutLine | None]:
    """The TUM reader; ``strict`` None: no line may be cut short (:func:`read_tum`)."""
    from scipy.spatial.transform import Rotation  # here: a drive's reading does without it

    text = read_text(path, "trajectory file")
    lines = _lines(path, text)
    stamps: list[float] = []
    poses: list[FloatArray] = []
    cut = None
    for n, fields, line in lines:
        try:
            v, norm = _tum_pose(path, n, fields, stamps)
        except InputError as exc:  # a file copied while written ends mid-line (rigcal.io.log_lines)
            if strict is None or not poses:  # nothing whole before it: not a file cut short
                raise
            cut = cut_last_line(exc, text, n, lines[-1][0], line, f"{path}: line {n}", strict)
            continue
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(v[4:8] / norm).as_matrix()
        T[:3, 3] = v[1:4]
        stamps.append(float(v[0]))
        poses.append(T)
    if not poses:
        raise InputError(f"{path}: no poses; expected lines 'timestamp tx ty tz qx qy qz qw'")
    return Trajectory(np.array(poses), np.array(stamps)), cut


def _tum_pose(path: Path, n: int, fields: list[str], stamps: list[float]) -> tuple[FloatArray, float]:
    """Line ``n``'s 8 numbers and its quaternion's norm, checked (stamps: those before it)."""
    planar = not stamps and len(fields) in (3, 4)  # "t x y [yaw]" from the start: a 2D tool's file
    hint = _PLANAR_HINT if planar else ""
    v = _numbers(path, n, fields, 8, "timestamp tx ty tz qx qy qz qw", hint, stamped=True)
    q = v[4:8]
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        few = " (printed with too few decimals?)" if abs(norm - 1.0) < 0.02 else ""
        raise InputError(
            f"{path}: line {n}: qx qy qz qw: got {q.tolist()} (norm {norm:.6g}){few}; expected a unit "
            f"quaternion (norm within {QUATERNION_NORM_TOLERANCE:g} of 1, as printed to 3 decimals)"
        )
    if stamps and v[0] <= stamps[-1]:
        raise InputError(
            f"{path}: line {n}: timestamp {float(v[0])!r} not after {stamps[-1]!r}; expected increasing"
        )
    return v, norm


def read_kitti(path: str | Path) -> Trajectory:
    """Read a KITTI trajectory (rotations must be orthonormal to 1e-6)."""
    path = Path(path)
    poses: list[FloatArray] = []
    for n, fields, _ in _lines(path):
        v = _numbers(path, n, fields, 12, "the 3x4 matrix [R | t], row-major")
        T = np.eye(4)
        T[:3, :] = v.reshape(3, 4)
        R = T[:3, :3]
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise InputError(f"{path}: line {n}: the 3x3 part is not a rotation matrix")
        poses.append(T)
    if not poses:
        raise InputError(f"{path}: no poses; expected lines of 12 numbers")
    return Trajectory(np.array(poses), None)


def tum_text(traj: Trajectory) -> str:
    if traj.stamps_s is None:
        raise ValueError("TUM files need time stamps")
    from scipy.spatial.transform import Rotation

    rows = ["# timestamp tx ty tz qx qy qz qw"]
    for t, T in zip(traj.stamps_s, traj.poses, strict=True):
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        rows.append(" ".join(repr(float(x)) for x in (t, *T[:3, 3], *q)))
    return "\n".join(rows) + "\n"


def kitti_text(traj: Trajectory) -> str:
    return "".join(" ".join(repr(float(x)) for x in T[:3, :].ravel()) + "\n" for T in traj.poses)


def write_tum(path: str | Path, traj: Trajectory, force: bool = False) -> Path:
    return atomic_write_text(path, tum_text(traj), force=force)


def write_kitti(path: str | Path, traj: Trajectory, force: bool = False) -> Path:
    return atomic_write_text(path, kitti_text(traj), force=force)


def planar_trajectory(stamps_s: FloatArray | None, poses: FloatArray, z_m: float = 0.0) -> Trajectory:
    """The trajectory of planar poses (N, 3) (x m, y m, yaw rad about z) at height ``z_m``."""
    from rigcal.geometry import make_T, rotvec_to_R

    T = [make_T(rotvec_to_R([0.0, 0.0, p[2]]), [p[0], p[1], z_m]) for p in np.asarray(poses, dtype=float)]
    return Trajectory(np.array(T).reshape(-1, 4, 4), None if stamps_s is None else np.asarray(stamps_s))
