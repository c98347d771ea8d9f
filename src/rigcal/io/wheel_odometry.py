"""Wheel odometry: the robot base's dead-reckoned poses and where the laser sits on it.

A sequence folder keeps it as ``odometry.tum`` (T_odom_base: the base's pose in the
odometry frame, TUM, z = 0) and ``odometry: {file, T_base_laser}`` in sequence.yaml (the
laser's mounting offset on the base, x y yaw: metres, radians; docs/formats/sequence.md).
Every source goes through :func:`checked`: stamps finite and increasing, poses finite,
and a time span that overlaps the scans', else a one-line error naming the file or topic.

The laser's motion between two stamps (:meth:`WheelOdometry.laser_motion`) is the base's
motion, interpolated at both stamps, seen from the laser:
T_laser0_laser1 = T_base_laser^-1 T_odom_base(t0)^-1 T_odom_base(t1) T_base_laser.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.io.stamps import check_beside_scans, check_increasing, check_overlap, check_seconds
from rigcal.io.trajectory import Trajectory, read_tum, tum_text

# A TUM odometry file is planar: its poses may tilt by at most this (rad) off the floor.
MAX_TILT_RAD = 0.2
# A pause between two odometry poses longer than this (s) and than GAP_PERIODS of the
# odometry's own period (median step) is a gap: a logger paused while the base counted on
# (its motion across the gap right: Killian Court's 15 gaps of 10-69 s agree with the
# SLAM poses to 6 cm and 0.3 deg), or a base rebooted or carried (its motion nonsense).
# Nothing in the odometry tells which, so its motion across a gap is no measurement
# (:func:`across_gaps`): it starts ICP unless the scans clearly contradict it
# (:func:`icp_starts`, rigcal.localize.odometry.contradicts); method odom takes no motion
# from it there, the filter only where the scans kept it (pipeline.wheel_measurements).
MAX_GAP_S = 1.0
GAP_PERIODS = 5.0


@dataclass(frozen=True)
class WheelOdometry:
    """The base's planar poses (N, 3: x, y, yaw) in the odometry frame at stamps (N,), and
    the laser's pose on the base (x, y, yaw)."""

    stamps_s: FloatArray
    poses: FloatArray
    T_base_laser: FloatArray

    def covers(self, t: float) -> bool:
        return bool(self.stamps_s[0] <= t <= self.stamps_s[-1])

    def base_pose(self, t: float) -> FloatArray:
        """The base's pose at t (x, y, yaw; linear, yaw unwrapped), held at the ends."""
        yaw = np.unwrap(self.poses[:, 2])
        s = self.stamps_s
        return np.array(
            [np.interp(t, s, self.poses[:, 0]), np.interp(t, s, self.poses[:, 1]), np.interp(t, s, yaw)]
        )

    def laser_motion(self, t0: float, t1: float) -> FloatArray | None:
        """The laser's pose at t1 in its frame at t0 (x, y, yaw), or None when either stamp
        is outside the odometry's span."""
        if not (self.covers(t0) and self.covers(t1)):
            return None
        return laser_motions(self, np.array([t0, t1]))[0]


def gap_s(odom: WheelOdometry) -> float:
    """The odometry's gap threshold (s): MAX_GAP_S, or GAP_PERIODS of its period if longer."""
    return max(MAX_GAP_S, GAP_PERIODS * float(np.median(np.diff(odom.stamps_s))))


def across_gaps(odom: WheelOdometry, stamps_s: FloatArray) -> NDArray[np.bool_]:
    """(N - 1,) whether the odometry has a gap (:func:`gap_s`) between each stamp and the next."""
    t = np.asarray(stamps_s, dtype=float)
    s = odom.stamps_s
    gaps = np.r_[0, np.cumsum(np.diff(s) > gap_s(odom))]  # gaps among the steps before pose k
    before = np.clip(np.searchsorted(s, t[:-1], side="right") - 1, 0, len(s) - 1)
    after = np.clip(np.searchsorted(s, t[1:], side="left"), 0, len(s) - 1)
    return np.asarray(gaps[after] > gaps[before])


def laser_motions(odom: WheelOdometry, stamps_s: FloatArray, over_gaps: bool = False) -> FloatArray:
    """(N - 1, 3) the laser's motion from each stamp to the next (T_laser_k-1_laser_k),
    from the base's poses interpolated at the stamps (vectorised); NaN for a step across a
    gap in the odometry (:func:`across_gaps`), unless ``over_gaps`` (the odometry's motion
    there, a start for ICP to verify, not a measurement)."""
    yaw = np.unwrap(odom.poses[:, 2])
    x = np.interp(stamps_s, odom.stamps_s, odom.poses[:, 0])
    y = np.interp(stamps_s, odom.stamps_s, odom.poses[:, 1])
    th = np.interp(stamps_s, odom.stamps_s, yaw)
    # The base's motion in its own frame at each earlier stamp.
    dx, dy = np.diff(x), np.diff(y)
    c, s = np.cos(th[:-1]), np.sin(th[:-1])
    bx, by, bth = c * dx + s * dy, -s * dx + c * dy, np.diff(th)
    # Conjugated by the mounting: T_bl^-1 (bx, by, bth) T_bl.
    lx, ly, lth = (float(v) for v in odom.T_base_laser)
    cl, sl = np.cos(lth), np.sin(lth)
    cb, sb = np.cos(bth), np.sin(bth)
    # t = R_l^T (R_b t_l + t_b - t_l)
    px = cb * lx - sb * ly + bx - lx
    py = sb * lx + cb * ly + by - ly
    out = np.column_stack([cl * px + sl * py, -sl * px + cl * py, bth])
    if not over_gaps:
        out[across_gaps(odom, stamps_s)] = np.nan
    return out


def icp_starts(odom: WheelOdometry, stamps_s: FloatArray) -> tuple[FloatArray, FloatArray]:
    """ICP's starts from the odometry between consecutive stamps (N,): the guesses (N - 1,
    3; NaN across a gap) and the odometry's motion across its gaps (N - 1, 3; NaN
    elsewhere), which starts ICP unless the scans contradict it
    (rigcal.localize.odometry.icp_odometry's ``guess`` and ``gap_guess``)."""
    over = laser_motions(odom, stamps_s, over_gaps=True)
    gaps = across_gaps(odom, stamps_s)
    guess, gap_guess = over.copy(), over
    guess[gaps] = np.nan
    gap_guess[~gaps] = np.nan
    return guess, gap_guess


def checked(
    stamps_s: FloatArray,
    poses: FloatArray,
    T_base_laser: FloatArray | tuple[float, float, float],
    where: str,
    scan_stamps_s: FloatArray | None = None,
) -> WheelOdometry:
    """Odometry from its stamps (N,) and base poses (N, 3), validated; ``where`` names the
    file or topic it came from.

    Raises:
        InputError: fewer than 2 poses, a stamp or pose that is not finite, stamps not
            increasing, or (given the scans' stamps) a span that does not overlap theirs.
    """
    t = np.asarray(stamps_s, dtype=float)
    p = np.asarray(poses, dtype=float).reshape(-1, 3)
    mount = np.asarray(T_base_laser, dtype=float)
    if len(t) < 2:
        raise InputError.at(where, "odometry", f"{len(t)} poses", "at least 2 odometry poses")
    bad = np.flatnonzero(~np.isfinite(t) | ~np.isfinite(p).all(axis=1))
    if len(bad):
        k = int(bad[0])
        raise InputError.at(
            where, f"odometry pose {k}", [float(t[k]), *p[k].tolist()], "finite stamp, x, y and yaw"
        )
    check_increasing(t, where, "odometry stamp")
    if mount.shape != (3,) or not np.isfinite(mount).all():
        raise InputError.at(where, "T_base_laser", mount.tolist(), "3 finite numbers: x y (m), yaw (rad)")
    # The unit from the odometry's own stamps (their magnitude and step), never from its
    # span against the scans': a robot's odometry may be logged for an hour around a
    # minute of scans.
    check_seconds(t, where, "odometry stamps", step="pose")
    if scan_stamps_s is not None and len(scan_stamps_s):
        check_beside_scans(t, scan_stamps_s, where, "odometry stamps")
    check_overlap(t, where, "odometry stamps", scan_stamps_s)
    return WheelOdometry(t, p, mount)


def planar_poses(traj: Trajectory, where: str) -> FloatArray:
    """(N, 3) x, y, yaw of a trajectory's poses, refusing ones tilted off the floor
    (an odometry file of a 3D body, or the wrong frames)."""
    R = traj.poses[:, :3, :3]
    check_level(R, where, "pose {k}", "TUM's quaternions are qx qy qz qw, w last")
    return np.column_stack([traj.poses[:, 0, 3], traj.poses[:, 1, 3], np.arctan2(R[:, 1, 0], R[:, 0, 0])])


def check_level(R: FloatArray, where: str, key: str, hint: str) -> None:
    """Refuse odometry rotations (N, 3, 3) tilted more than :data:`MAX_TILT_RAD` off the
    floor: a 3D body's, or frames with z down (NED), whose heading would read mirrored.
    ``key`` names the pose (``{k}``: its index), ``hint`` what may have gone wrong.

    Raises:
        InputError: ``where: key: got 'tilted 180.0 deg'; expected planar odometry ...``.
    """
    tilt = np.arccos(np.clip(R[:, 2, 2], -1.0, 1.0))
    if (tilt > MAX_TILT_RAD).any():
        k = int(np.argmax(tilt))
        raise InputError.at(
            where,
            key.format(k=k),
            f"tilted {np.degrees(tilt[k]):.1f} deg",
            f"planar odometry (z axis up; {hint})",
        )


def read_odometry_tum(
    path: str | Path, T_base_laser: FloatArray | tuple[float, float, float], scan_stamps_s: FloatArray | None
) -> WheelOdometry:
    """Wheel odometry from a TUM file (T_odom_base per line), every line whole."""
    return odometry_of_tum(read_tum(path), path, T_base_laser, scan_stamps_s)


def odometry_of_tum(
    traj: Trajectory,
    path: str | Path,
    T_base_laser: FloatArray | tuple[float, float, float],
    scan_stamps_s: FloatArray | None,
) -> WheelOdometry:
    """Wheel odometry from a TUM file's trajectory (T_odom_base), checked (:func:`checked`)."""
    assert traj.stamps_s is not None
    return checked(traj.stamps_s, planar_poses(traj, str(path)), T_base_laser, str(path), scan_stamps_s)


def odometry_tum(odom: WheelOdometry) -> str:
    """The base's poses as TUM text (z = 0)."""
    from rigcal.geometry import make_T, rotvec_to_R

    T = np.array([make_T(rotvec_to_R([0.0, 0.0, th]), [x, y, 0.0]) for x, y, th in odom.poses])
    return tum_text(Trajectory(T, odom.stamps_s))


def parse_mounting(text: str, option: str = "--laser-offset") -> FloatArray:
    """``X,Y,YAW_DEG`` (metres, degrees) as (x, y, yaw rad)."""
    parts = text.replace(" ", "").split(",")
    try:
        v = [float(p) for p in parts]
    except ValueError:
        v = []
    if len(v) != 3 or not all(np.isfinite(v)) or max(abs(v[0]), abs(v[1])) > 100 or abs(v[2]) > 360:
        raise InputError.at(None, option, text, "X,Y,YAW_DEG: the laser on the base (m, m, deg)")
    return np.array([v[0], v[1], np.radians(v[2])])
