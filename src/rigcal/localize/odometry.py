"""Laser odometry: ICP between successive scans of a sequence, chained into a trajectory."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rigcal.calib.lines import Segment, extract_lines, return_labels
from rigcal.localize.icp import IcpParams, icp, line_normals, pose_of, se2
from rigcal.scan import Scan

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Odometry:
    """Poses (N, 3) of the laser in the first scan's frame, per-step degeneracy and ICP
    fit RMS, how many steps were skipped (too few points) and kept the last motion, and
    how many were tried again from zero motion (a poor fit from the previous motion)."""

    poses: FloatArray
    degeneracy: FloatArray
    rms_m: FloatArray
    skipped: int
    restarts: int = 0


def icp_odometry(
    scans: Sequence[Scan],
    params: IcpParams | None = None,
    progress: Callable[[int], None] | None = None,
    lines: Callable[[int], list[Segment]] | None = None,
) -> Odometry:
    """Chain ICP increments T_prev_cur over the scans, each started from the previous
    increment (constant velocity) and, when that fit is poor
    (``params.restart_below_inliers``), from zero motion too, the better fit kept;
    ``progress`` is called with the scans done so far. Point-to-line with
    ``params.normals == "lines"`` takes each model scan's normals from its lines
    (``lines(k)``: scan k's segments, to share them with other stages; by default
    extracted here)."""
    params = params or IcpParams()
    use_lines = params.method == "point-to-line" and params.normals == "lines"

    def normals_of(k: int) -> FloatArray | None:
        if not use_lines:
            return None
        segs = lines(k) if lines is not None else extract_lines(scans[k])
        return line_normals(scans[k].points[scans[k].valid], return_labels(scans[k], segs))

    T = np.eye(3)
    poses = [pose_of(T)]
    deg, rms = [1.0], [0.0]
    last = np.zeros(3)
    skipped = restarts = 0
    prev = scans[0].points[scans[0].valid]
    prev_normals = normals_of(0)
    for k, scan in enumerate(scans[1:], start=2):
        if progress is not None:
            progress(k)
        cur = scan.points[scan.valid]
        if len(cur) < 10 or len(prev) < 10:
            step, d, r = last, 0.0, float("nan")
            skipped += 1
        else:
            res = icp(prev, cur, initial=last, params=params, model_normals=prev_normals)
            if res.inlier_fraction < params.restart_below_inliers:
                again = icp(prev, cur, initial=np.zeros(3), params=params, model_normals=prev_normals)
                if (again.inlier_fraction, -again.rms_m) > (res.inlier_fraction, -res.rms_m):
                    res = again
                restarts += 1
            step, d, r = res.pose, res.degeneracy, res.rms_m
        T = T @ se2(step)
        poses.append(pose_of(T))
        deg.append(d)
        rms.append(r)
        last = step
        if len(cur) >= 10:
            prev, prev_normals = cur, normals_of(k - 1)
    return Odometry(np.array(poses), np.array(deg), np.array(rms), skipped, restarts)
