"""CARMEN laser logs: FLASER and ROBOTLASER1 lines, in a plain log or inside a g2o file.

A CARMEN log holds one message per line, ``NAME fields... ipc_timestamp ipc_hostname
logger_timestamp``. The laser messages read here:

    FLASER n r_1 .. r_n  x y theta  odom_x odom_y odom_theta  ipc_timestamp host logger_timestamp
    ROBOTLASER1 laser_type start_angle fov angular_resolution max_range accuracy
        remission_mode n r_1 .. r_n  m rem_1 .. rem_m  laser_x laser_y laser_theta
        robot_x robot_y robot_theta  tv rv forward_safety side_safety turn_axis
        ipc_timestamp host logger_timestamp

FLASER carries no beam geometry: CARMEN's front laser spans 180 degrees from -90 degrees
(n even: n steps of 180/n degrees, as 180 beams at 1 degree; n odd: both ends included,
as 181 or 361 beams), and no maximum range (``flaser_range_max_m``).

g2o files written from CARMEN logs (the MIT Killian Court log, for one) keep the
ROBOTLASER1 lines next to their VERTEX_SE2 / EDGE_SE2 lines; every other message (ODOM,
PARAM, SYNC, g2o vertices and edges, comments) is skipped and counted. In a corrected
log the laser pose (FLASER x y theta, ROBOTLASER1 laser pose) is the SLAM-corrected pose;
the odometry pose is the robot's raw odometry (ROBOTLASER1: the robot pose).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rigcal.errors import InputError
from rigcal.io.validate import parse_real, parse_whole
from rigcal.scan import Scan

FloatArray = NDArray[np.float64]

LASER_MESSAGES = ("FLASER", "ROBOTLASER1")
# Returns at or beyond this are "no return" in FLASER lines (they carry no maximum range).
FLASER_RANGE_MAX_M = 50.0
# More beams than any scanner has: a larger count is a broken line.
MAX_BEAMS = 100_000


@dataclass(frozen=True)
class CarmenLog:
    """The laser messages of a CARMEN log, in file order.

    Attributes:
        scans: one scan per laser line, stamped with its ipc_timestamp (s).
        laser_poses: (N, 3) the laser's logged pose (x, y, theta; metres, radians).
        odometry_poses: (N, 3) the robot's odometry pose logged with each scan.
        line_numbers: (N,) 1-based line of each scan in the file.
        skipped_lines: lines of other messages, blank lines and comments.
    """

    scans: list[Scan]
    laser_poses: FloatArray
    odometry_poses: FloatArray
    line_numbers: NDArray[np.int64]
    skipped_lines: int


def read_carmen(path: str | Path, flaser_range_max_m: float = FLASER_RANGE_MAX_M) -> CarmenLog:
    """Read the FLASER and ROBOTLASER1 lines of a CARMEN log or a g2o file.

    Raises:
        InputError: unreadable file; a laser line with too few fields, a field that is not
            a number, a beam count that is not a non-negative integer, a non-positive
            angular step or maximum range; stamps not strictly increasing; no laser line.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc.strerror or exc}") from exc
    scans: list[Scan] = []
    laser: list[FloatArray] = []
    odom: list[FloatArray] = []
    lines: list[int] = []
    skipped = 0
    for no, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0] not in LASER_MESSAGES:
            skipped += 1
            continue
        where = f"{p}:{no}"
        parse = _flaser if fields[0] == "FLASER" else _robotlaser1
        scan, pose, odo = parse(fields[1:], where, flaser_range_max_m)
        last = scans[-1].stamp_s if scans else None
        if last is not None and scan.stamp_s is not None and scan.stamp_s <= last:
            raise InputError.at(
                where, f"{fields[0]} ipc_timestamp", scan.stamp_s, f"a stamp after line {lines[-1]}'s"
            )
        scans.append(scan)
        laser.append(pose)
        odom.append(odo)
        lines.append(no)
    if not scans:
        raise InputError(
            f"{p}: no FLASER or ROBOTLASER1 lines; expected a CARMEN log or a g2o file with them"
        )
    return CarmenLog(scans, np.array(laser), np.array(odom), np.array(lines, dtype=np.int64), skipped)


def _numbers(fields: list[str], start: int, stop: int, where: str, what: str, names: str) -> list[float]:
    """Fields start..stop-1 as floats; one that is not a number is an InputError (fields
    are counted from 1 after the message name)."""
    return [parse_real(fields[i], where, f"{what} field {i + 1} ({names})") for i in range(start, stop)]


def _count(value: str, where: str, key: str, lo: int = 0) -> int:
    return parse_whole(value, where, key, lo=lo, hi=MAX_BEAMS)


def _ranges(ranges: list[float], where: str, what: str) -> None:
    for i, r in enumerate(ranges):
        if r < 0:
            raise InputError.at(where, f"{what} range {i + 1}", r, "a range >= 0 (m)")


def _need(fields: list[str], n: int, where: str, what: str, layout: str) -> None:
    if len(fields) < n:
        raise InputError.at(where, what, f"{len(fields)} fields", f"at least {n}: {layout}")


def _flaser(fields: list[str], where: str, range_max_m: float) -> tuple[Scan, FloatArray, FloatArray]:
    layout = "n, n ranges, x y theta, odom_x odom_y odom_theta, ipc_timestamp"
    _need(fields, 1, where, "FLASER", layout)
    n = _count(fields[0], where, "FLASER num_readings", lo=1)
    _need(fields, 1 + n + 7, where, "FLASER", layout)
    v = _numbers(fields, 1, 1 + n + 7, where, "FLASER", layout)
    # 180 degrees from -90: n even, n steps (1 degree for 180); n odd, both ends (181, 361).
    step = math.pi / (n - 1 if n % 2 else n) if n > 1 else math.pi
    _ranges(v[:n], where, "FLASER")
    scan = Scan.from_uniform(-math.pi / 2, step, v[:n], 0.0, range_max_m, stamp_s=v[n + 6])
    return scan, np.array(v[n : n + 3]), np.array(v[n + 3 : n + 6])


def _robotlaser1(fields: list[str], where: str, _: float) -> tuple[Scan, FloatArray, FloatArray]:
    layout = (
        "laser_type start_angle fov angular_resolution max_range accuracy remission_mode, n, n ranges, "
        "m, m remissions, laser x y theta, robot x y theta, tv rv forward side turn_axis, ipc_timestamp"
    )
    _need(fields, 8, where, "ROBOTLASER1", layout)
    head = _numbers(fields, 1, 6, where, "ROBOTLASER1", layout)
    start, _fov, step, range_max = head[0], head[1], head[2], head[3]
    n = _count(fields[7], where, "ROBOTLASER1 num_readings", lo=1)
    _need(fields, 8 + n + 1, where, "ROBOTLASER1", layout)
    ranges = _numbers(fields, 8, 8 + n, where, "ROBOTLASER1", layout)
    m = _count(fields[8 + n], where, "ROBOTLASER1 num_remissions")
    tail = 9 + n + m
    _need(fields, tail + 12, where, "ROBOTLASER1", layout)
    v = _numbers(fields, tail, tail + 12, where, "ROBOTLASER1", layout)
    if not 0 < step <= 2 * math.pi:
        raise InputError.at(where, "ROBOTLASER1 angular_resolution", fields[3], "an angle in (0, 2 pi] rad")
    if not -2 * math.pi <= start <= 2 * math.pi:
        raise InputError.at(where, "ROBOTLASER1 start_angle", fields[1], "an angle in [-2 pi, 2 pi] rad")
    _ranges(ranges, where, "ROBOTLASER1")
    if not range_max > 0:
        raise InputError.at(where, "ROBOTLASER1 max_range", fields[4], "a positive range (m)")
    scan = Scan.from_uniform(start, step, ranges, 0.0, range_max, stamp_s=v[11])
    return scan, np.array(v[0:3]), np.array(v[3:6])
