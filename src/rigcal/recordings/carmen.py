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

and the odometry messages and the laser's mounting parameters:

    ODOM x y theta tv rv accel  ipc_timestamp host logger_timestamp
    PARAM robot_frontlaser_offset VALUE  (also _side_offset, _angular_offset)

A log holding both (the logger writes the front laser as FLASER and, with the robot
module running, as ROBOTLASER1) has each reading twice: a FLASER line whose ranges are a
ROBOTLASER1 line's within a second of it is skipped and counted (:func:`same_readings`).

g2o files written from CARMEN logs (the MIT Killian Court log, for one) keep the
ROBOTLASER1 lines next to their VERTEX_SE2 / EDGE_SE2 lines; every other message (SYNC,
other PARAMs, g2o vertices and edges, comments) is skipped and counted. In a corrected
log the laser pose (FLASER x y theta, ROBOTLASER1 laser pose) is the SLAM-corrected pose;
the odometry pose is the robot's raw odometry (ROBOTLASER1: the robot pose).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.io.files import read_log_text, text_lines
from rigcal.io.log_lines import CutLine, ShortLineError, cut_last_line
from rigcal.io.stamps import StampRepair, repair_stamps
from rigcal.io.validate import parse_real, parse_whole
from rigcal.io.wheel_odometry import WheelOdometry, checked
from rigcal.scan import Scan

LASER_MESSAGES = ("FLASER", "ROBOTLASER1")
# Returns at or beyond this are "no return" in FLASER lines (they carry no maximum range).
FLASER_RANGE_MAX_M = 50.0
# CARMEN's other laser messages, not read; named in the error of a log that has only these.
OTHER_LASER_MESSAGES = ("RAWLASER1", "RAWLASER2", "RAWLASER3", "RAWLASER4", "RLASER", "ROBOTLASER2")
OTHER_LASERS_NOT_READ = "not read: RAWLASER lines carry no pose, RLASER and ROBOTLASER2 are a rear laser"
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
        stamps: what the stamp repair did to the scans' stamps (rigcal.io.stamps).
        odom: (M, 4) the ODOM lines' stamp (repaired as the scans'), x, y, theta.
        odom_stamps: what the stamp repair did to the ODOM lines' stamps.
        params: the laser mounting's PARAM values read (name -> value).
        g2o_steps: (N - 1, 3) in a g2o file whose EDGE_SE2 lines link every vertex to the
            next, one vertex per laser line: those edges (dx, dy, dtheta), else (0, 3).
        cut: the last line when it was incomplete and left out (a log cut short,
            rigcal.io.log_lines), else None.
        skipped_kinds: the skipped lines by message name ("comment", "blank" for
            those), most first: what else the log holds.
    """

    scans: list[Scan]
    laser_poses: FloatArray
    odometry_poses: FloatArray
    line_numbers: NDArray[np.int64]
    skipped_lines: int
    stamps: StampRepair | None = None
    odom: FloatArray = field(default_factory=lambda: np.zeros((0, 4)))
    odom_stamps: StampRepair | None = None
    params: dict[str, float] = field(default_factory=dict)
    g2o_steps: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    cut: CutLine | None = None
    skipped_kinds: dict[str, int] = field(default_factory=dict)


def read_carmen(
    path: str | Path, flaser_range_max_m: float = FLASER_RANGE_MAX_M, stamps: str = "repair"
) -> CarmenLog:
    """Read the FLASER, ROBOTLASER1 and ODOM lines (and the laser's mounting PARAMs) of a
    CARMEN log or a g2o file. ``stamps``: "repair" mends equal stamps and small steps back
    (rigcal.io.stamps) and leaves out an incomplete last line (rigcal.io.log_lines),
    "strict" refuses both.

    Raises:
        InputError: unreadable file; a laser or ODOM line with too few fields, a field that
            is not a number, a beam count that is not a non-negative integer, a non-positive
            angular step or maximum range; stamps that do not increase (strict) or that the
            repair cannot mend; no laser line.
    """
    p = Path(path)
    text = read_log_text(p, "CARMEN log")
    rows = text_lines(text)
    last = max((i for i, r in enumerate(rows, start=1) if r.strip()), default=0)
    cut = None  # the last line, when a logger stopped mid-line left it incomplete
    scans: list[Scan] = []
    laser: list[FloatArray] = []
    odom: list[FloatArray] = []
    lines: list[int] = []
    skipped: Counter[str] = Counter()
    extra = _OtherMessages()
    kinds: list[str] = []
    for no, line in enumerate(rows, start=1):
        fields = line.split()
        try:
            if not fields or fields[0] not in LASER_MESSAGES:
                if not extra.read(fields, f"{p}:{no}", no):
                    skipped["blank" if not fields else "comment" if fields[0][0] == "#" else fields[0]] += 1
                continue
            where = f"{p}:{no}"
            parse = _flaser if fields[0] == "FLASER" else _robotlaser1
            scan, pose, odo = parse(fields[1:], where, flaser_range_max_m)
        except InputError as exc:  # a log cut short ends mid-line (rigcal.io.log_lines)
            cut = cut_last_line(exc, text, no, last, line, f"{p}:{no}", stamps == "strict")
            continue
        scans.append(scan)
        laser.append(pose)
        odom.append(odo)
        lines.append(no)
        kinds.append(fields[0])
    again = same_readings(scans, kinds)
    if again:
        skipped[FLASER_AGAIN] = len(again)
        keep = [i for i in range(len(scans)) if i not in again]
        scans, lines = [scans[i] for i in keep], [lines[i] for i in keep]
        laser, odom = [laser[i] for i in keep], [odom[i] for i in keep]
    if not scans:
        other = {k: n for k, n in skipped.items() if k in OTHER_LASER_MESSAGES}
        has = f" (it has {', '.join(f'{k} {n}' for k, n in sorted(other.items()))}, {OTHER_LASERS_NOT_READ})"
        raise InputError(
            f"{p}: no FLASER or ROBOTLASER1 lines{has if other else ''}; expected a CARMEN log or a g2o "
            "file with them"
        )
    line_numbers = np.array(lines, dtype=np.int64)
    fixed = repair_stamps([s.stamp_s for s in scans], f"{p}: laser ipc_timestamp", stamps, line_numbers)
    scans = [replace(s, stamp_s=float(t)) for s, t in zip(scans, fixed.stamps_s, strict=True)]
    odom_lines, odom_fixed = extra.odometry(p, stamps)
    return CarmenLog(
        scans,
        np.array(laser),
        np.array(odom),
        line_numbers,
        skipped.total(),
        fixed,
        odom_lines,
        odom_fixed,
        extra.params,
        extra.g2o_steps(len(scans)),
        cut,
        dict(skipped.most_common()),
    )


# A FLASER line that is a ROBOTLASER1 line's reading again: its kind among the lines skipped.
FLASER_AGAIN = "FLASER (a ROBOTLASER1 line's reading again)"
# Within this (s) of a ROBOTLASER1 line, a FLASER line with its ranges is the same reading.
SAME_READING_S = 1.0
# Ranges equal to within this (m) are the same reading's: both lines print it to 1 cm.
SAME_RANGE_M = 0.0051


def same_readings(scans: list[Scan], kinds: list[str]) -> set[int]:
    """The positions of the FLASER scans that are a ROBOTLASER1 scan's reading again: CARMEN's
    logger writes the front laser as FLASER and, with the robot module running, as
    ROBOTLASER1 too; read both, every scan would be read twice. Same reading: within
    :data:`SAME_READING_S`, as many beams, returns on the same beams (below both lines'
    maximum ranges) at ranges within :data:`SAME_RANGE_M`; two readings of a scanner never
    agree on every beam to that."""
    robot = [i for i, k in enumerate(kinds) if k == "ROBOTLASER1"]
    if not robot or len(robot) == len(kinds):
        return set()
    t = np.array([scans[i].stamp_s for i in robot])
    out = set()
    for i, k in enumerate(kinds):
        if k != "FLASER":
            continue
        f = scans[i]
        for j in np.flatnonzero(np.abs(t - f.stamp_s) <= SAME_READING_S):
            r = scans[robot[int(j)]]
            if len(r.ranges_m) != len(f.ranges_m):
                continue
            top = min(f.range_max_m, r.range_max_m)
            a, b = (np.where(np.isfinite(x.ranges_m) & (x.ranges_m < top), x.ranges_m, -1.0) for x in (f, r))
            if np.all(np.abs(a - b) <= SAME_RANGE_M):
                out.add(i)
                break
    return out


# CARMEN's laser mounting parameters: x forward (m), y left (m), yaw (rad) on the robot.
MOUNTING_PARAMS = (
    "robot_frontlaser_offset",
    "robot_frontlaser_side_offset",
    "robot_frontlaser_angular_offset",
)
# T_robot^-1 T_laser of every laser line within these of the first (m, rad): the log's
# laser poses are its odometry moved by a fixed mounting (a raw, uncorrected log).
MOUNTING_TOLERANCE = (1e-3, 1e-3)


class _OtherMessages:
    """ODOM lines and the mounting PARAMs, gathered as the log is read."""

    def __init__(self) -> None:
        self.odom: list[list[float]] = []
        self.lines: list[int] = []
        self.params: dict[str, float] = {}
        self.vertices = 0
        self.steps: dict[int, list[float]] = {}  # g2o EDGE_SE2 i -> i + 1: i -> (dx, dy, dth)

    def read(self, fields: list[str], where: str, no: int) -> bool:
        """Read the line if it is an ODOM line or a mounting PARAM; False otherwise (g2o
        vertices and sequential edges are read, and counted as skipped)."""
        if fields and fields[0] == "VERTEX_SE2":
            self.vertices += 1
        if len(fields) >= 6 and fields[0] == "EDGE_SE2":
            ij = [parse_whole(f, where, "EDGE_SE2 vertex id", lo=0, hi=2**62) for f in fields[1:3]]
            if ij[1] == ij[0] + 1:
                self.steps[ij[0]] = _numbers(fields, 3, 6, where, "EDGE_SE2", "i j dx dy dtheta, information")
            return False
        if fields and fields[0] == "ODOM":
            layout = "x y theta tv rv accel ipc_timestamp"
            _need(fields[1:], 7, where, "ODOM", layout)
            v = _numbers(fields[1:], 0, 7, where, "ODOM", layout)
            self.odom.append([v[6], v[0], v[1], v[2]])
            self.lines.append(no)
            return True
        if len(fields) >= 3 and fields[0] == "PARAM" and fields[1] in MOUNTING_PARAMS:
            self.params[fields[1]] = parse_real(fields[2], where, f"PARAM {fields[1]}")
            return True
        return False

    def g2o_steps(self, n: int) -> FloatArray:
        """The sequential edges 0 -> 1 -> ... -> n - 1 when the file has n vertices (one
        per laser line) and every such edge; else none."""
        if n < 2 or self.vertices != n or any(i not in self.steps for i in range(n - 1)):
            return np.zeros((0, 3))
        return np.array([self.steps[i] for i in range(n - 1)])

    def odometry(self, p: Path, stamps: str) -> tuple[FloatArray, StampRepair | None]:
        if not self.odom:
            return np.zeros((0, 4)), None
        a = np.array(self.odom)
        lines = np.array(self.lines, dtype=np.int64)
        fixed = repair_stamps(a[:, 0], f"{p}: ODOM ipc_timestamp", stamps, lines)
        a[:, 0] = fixed.stamps_s
        return a, fixed


def carmen_odometry(
    log: CarmenLog, where: str, mounting: FloatArray | None = None
) -> tuple[WheelOdometry | None, str]:
    """The log's wheel odometry and where its numbers came from: the ODOM lines when
    there are two or more; else, in a g2o file, its sequential EDGE_SE2 lines (vertex k
    to k + 1, chained; its vertices are the laser's poses, and its laser lines' robot
    poses are those vertices, not the raw odometry); else the odometry pose of each laser
    line (at the scan's stamp); None when those never change (a log that left them at 0). The laser's
    mounting on the robot: ``mounting`` when given; else the log's
    ``robot_frontlaser_*`` PARAMs; else, when every laser line's laser pose is its
    odometry pose moved by one fixed offset (a raw log), that offset; else none (0, 0, 0).

    Raises:
        InputError: odometry that is not finite, or whose span misses the scans'.
    """
    scan_t = np.array([s.stamp_s for s in log.scans], dtype=float)
    how = []
    if mounting is not None:
        mount = np.asarray(mounting, dtype=float)
        how.append("mounting given")
    elif any(k in log.params for k in MOUNTING_PARAMS):
        mount = np.array([log.params.get(k, 0.0) for k in MOUNTING_PARAMS])
        how.append("mounting from PARAM robot_frontlaser_*")
    else:
        fixed = _fixed_offset(log.odometry_poses, log.laser_poses)
        how.append("mounting from the laser lines" if fixed is not None else "no mounting known (0, 0, 0)")
        mount = np.zeros(3) if fixed is None else fixed
    if len(log.odom) < 2 and len(log.g2o_steps):
        if mounting is None:
            mount, how = np.zeros(3), ["the g2o's vertices are the laser's poses"]
        poses = [log.laser_poses[0]]
        for step in log.g2o_steps:
            poses.append(_compose(poses[-1], step))
        od = checked(scan_t, np.array(poses), mount, f"{where}: EDGE_SE2 lines", scan_t)
        return od, "; ".join([f"{len(log.g2o_steps)} sequential EDGE_SE2 lines", *how])
    if len(log.odom) < 2 and np.ptp(log.odometry_poses, axis=0).max(initial=0.0) == 0.0:
        return None, "no odometry: the laser lines' odometry poses never change"
    if len(log.odom) >= 2:
        od = checked(log.odom[:, 0], log.odom[:, 1:], mount, f"{where}: ODOM lines", scan_t)
        how.insert(0, f"{len(log.odom)} ODOM lines")
    else:
        od = checked(scan_t, log.odometry_poses, mount, f"{where}: laser lines' odometry", scan_t)
        how.insert(0, "the laser lines' odometry poses")
    return od, "; ".join(how)


def _compose(a: FloatArray, b: FloatArray) -> FloatArray:
    """Planar pose a moved by b in a's frame (x, y, theta)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def _fixed_offset(robot: FloatArray, laser: FloatArray) -> FloatArray | None:
    """T_robot^-1 T_laser when it is the same (within MOUNTING_TOLERANCE) on every line."""
    c, s = np.cos(robot[:, 2]), np.sin(robot[:, 2])
    d = laser[:, :2] - robot[:, :2]
    yaw = np.angle(np.exp(1j * (laser[:, 2] - robot[:, 2])))
    off = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], yaw])
    spread_m = np.abs(off[:, :2] - off[0, :2]).max()
    spread_rad = np.abs(np.angle(np.exp(1j * (off[:, 2] - off[0, 2])))).max()
    if spread_m > MOUNTING_TOLERANCE[0] or spread_rad > MOUNTING_TOLERANCE[1]:
        return None
    return np.asarray(off.mean(axis=0), dtype=float)


def _numbers(fields: list[str], start: int, stop: int, where: str, what: str, names: str) -> list[float]:
    """Fields start..stop-1 as floats; one that is not a number is an InputError (fields
    are counted from 1 after the message name)."""
    return [parse_real(fields[i], where, f"{what} field {i + 1} ({names})") for i in range(start, stop)]


def _count(value: str, where: str, key: str, lo: int = 0) -> int:
    return parse_whole(value, where, key, lo=lo, hi=MAX_BEAMS)


def _ranges(fields: list[str], start: int, n: int, where: str, what: str, names: str) -> list[float]:
    """The n ranges from field ``start`` (m): ``nan`` and ``inf`` are no return (as a
    converter from a ROS bag writes them), a negative range or a non-number is an error."""
    out = []
    for i in range(n):
        try:
            r = float(fields[start + i])
        except ValueError:
            r = parse_real(fields[start + i], where, f"{what} field {start + i + 1} ({names})")
        if r < 0:
            raise InputError.at(where, f"{what} range {i + 1}", r, "a range >= 0 (m; nan or inf: no return)")
        out.append(r if math.isfinite(r) else math.nan)
    return out


def _need(fields: list[str], n: int, where: str, what: str, layout: str) -> None:
    if len(fields) < n:
        raise ShortLineError.at(where, what, f"{len(fields)} fields", f"at least {n}: {layout}")


def _flaser(fields: list[str], where: str, range_max_m: float) -> tuple[Scan, FloatArray, FloatArray]:
    layout = "n, n ranges, x y theta, odom_x odom_y odom_theta, ipc_timestamp"
    _need(fields, 1, where, "FLASER", layout)
    n = _count(fields[0], where, "FLASER num_readings", lo=1)
    _need(fields, 1 + n + 7, where, "FLASER", layout)
    v = _ranges(fields, 1, n, where, "FLASER", layout) + _numbers(
        fields, 1 + n, 1 + n + 7, where, "FLASER", layout
    )
    # 180 degrees from -90: n even, n steps (1 degree for 180); n odd, both ends (181, 361).
    step = math.pi / (n - 1 if n % 2 else n) if n > 1 else math.pi
    ranges = _no_return_at(v[:n], range_max_m)
    scan = Scan.from_uniform(-math.pi / 2, step, ranges, 0.0, range_max_m, stamp_s=v[n + 6])
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
    ranges = _ranges(fields, 8, n, where, "ROBOTLASER1", layout)
    m = _count(fields[8 + n], where, "ROBOTLASER1 num_remissions")
    tail = 9 + n + m
    _need(fields, tail + 12, where, "ROBOTLASER1", layout)
    v = _numbers(fields, tail, tail + 12, where, "ROBOTLASER1", layout)
    if not 0 < step <= 2 * math.pi:
        raise InputError.at(where, "ROBOTLASER1 angular_resolution", fields[3], "an angle in (0, 2 pi] rad")
    if not -2 * math.pi <= start <= 2 * math.pi:
        raise InputError.at(where, "ROBOTLASER1 start_angle", fields[1], "an angle in [-2 pi, 2 pi] rad")
    if not range_max > 0:
        raise InputError.at(where, "ROBOTLASER1 max_range", fields[4], "a positive range (m)")
    scan = Scan.from_uniform(start, step, _no_return_at(ranges, range_max), 0.0, range_max, stamp_s=v[11])
    return scan, np.array(v[0:3]), np.array(v[3:6])


def _no_return_at(ranges: list[float], range_max: float) -> list[float]:
    """A reading of exactly the maximum range is CARMEN's no return (a measured surface is
    never at exactly the maximum): inf, as the readings beyond it."""
    return [math.inf if r == range_max else r for r in ranges]
