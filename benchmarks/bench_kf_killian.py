"""The Kalman filter on a real log without a camera: ICP's steps and the log's odometry
fused, against each input alone, on Killian Court.

Killian Court (the rtb-data package's g2o file, 3873 scans ~0.5 m and ~2 s apart, 15
pauses of 10-69 s), read as ``rigcal import-carmen`` does; ICP started from the odometry
(across its gaps unless the scans contradict it: rigcal.io.wheel_odometry.icp_starts).
The filter (rigcal.localize.kalman.run_filter) runs on ICP's steps with their covariances
alone, driven by them (``--kf driven``), and on ICP's and the odometry's steps (the
odometry with its rate noise model, none across its gaps) in the modes of ``rigcal
localize --kf``, with the wheels raw (neither witness nor calibrated); and on ICP's steps
with the ones the odometry overruled under the odometry's noise model instead of left
out, and on the odometry's steps alone. Scored against the
g2o's vertices by ATE (SE(2)-aligned), the end position error and the relation error over
consecutive scans (rigcal.localize.metrics). Then the filter as ``rigcal localize --method
kf`` runs it on a log without images: ICP's steps, the overruled ones under the
odometry's noise model and the odometry's own step there left out (each step measured
once: rigcal.localize.pipeline.overruled_as_odometry), and the odometry's
(wheel_measurements: across a gap only where ICP measured nothing), the causal path
anchored (KfParams.anchored), in each mode; and the odometry's steps alone, anchored.

    uv sync --group bench        # rtb-data
    .venv/bin/python benchmarks/bench_kf_killian.py
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from bench_wheel_odometry import chained, killian_log, killian_row
from rigcal.io.wheel_odometry import icp_starts, laser_motions
from rigcal.localize import kalman
from rigcal.localize.icp import IcpParams
from rigcal.localize.odometry import icp_odometry
from rigcal.localize.pipeline import overruled_as_odometry, wheel_measurements


def main() -> None:
    log, odom, _ = killian_log()
    scans, gt = log.scans, log.laser_poses
    t = np.array([s.stamp_s for s in scans])
    guess, gap_guess = icp_starts(odom, t)
    od = icp_odometry(scans, IcpParams(method="point-to-line"), guess=guess, gap_guess=gap_guess)
    wheels = chained(laser_motions(odom, t, over_gaps=True))  # across its gaps too
    icp = kalman.increments(t, od.poses, od.covariance, source="icp")
    measured = np.r_[True, ~np.isnan(guess).any(axis=1)]  # no odometry step across a gap
    wheel = kalman.increments(t, wheels, kalman.WHEEL_SIGMAS, measured=measured, source="wheel")
    no_cov = int((~np.isfinite(od.covariance[1:]).all(axis=(1, 2))).sum())
    print(
        f"Killian Court: {len(scans)} scans; ICP's steps in the filter {len(icp)} of {len(t) - 1} "
        f"({no_cov} without a covariance: the odometry overruled them); odometry steps {len(wheel)}"
    )
    # ICP's steps with the overruled ones (the odometry's motion) under the odometry's
    # rate noise model instead of left out.
    cov = od.covariance.copy()
    dt = np.r_[1.0, np.diff(t)]
    missing = ~np.isfinite(cov).all(axis=(1, 2))
    missing[0] = False  # index 0: no step
    for k in np.flatnonzero(missing):
        cov[k] = kalman.rate_covariance(kalman.WHEEL_SIGMAS, float(dt[k]), False)
    filled = kalman.increments(t, od.poses, cov, source="icp")
    rows = [("ICP from the odometry", od.poses), ("the odometry", wheels)]
    weighted = kalman.KF_MODES["weighted"]
    raw = dataclasses.replace(weighted, wheel_witness=False, wheel_calibrated=False)
    for name, ms, params in (
        ("KF on ICP alone (weighted)", icp, kalman.KF_MODES["weighted"]),
        ("KF on ICP alone (driven)", icp, kalman.KF_MODES["driven"]),
        ("KF on ICP alone, the overruled steps under the odometry's noise (weighted)", filled, weighted),
        ("KF on the odometry alone (weighted)", wheel, weighted),
        ("KF on ICP + odometry (weighted)", icp + wheel, kalman.KF_MODES["weighted"]),
        ("KF on ICP + odometry (icp-first)", icp + wheel, kalman.KF_MODES["icp-first"]),
        ("KF on ICP + odometry raw (weighted)", icp + wheel, raw),
    ):
        rows.append((name, kalman.path_at(kalman.run_filter(ms, params), t).poses))
    # As rigcal localize --method kf runs it without images: anchored.
    cov_used, used = overruled_as_odometry(t, od.covariance, wheel_measurements(odom, t, od.covariance))
    icp_used = kalman.increments(t, od.poses, cov_used, source="icp")
    for name, ms, mode in (
        (
            "rigcal's KF without images: ICP + odometry, anchored (weighted, the default)",
            icp_used + used,
            "weighted",
        ),
        ("rigcal's KF without images: ICP + odometry, anchored (driven)", icp_used + used, "driven"),
        ("rigcal's KF without images: ICP + odometry, anchored (icp-first)", icp_used + used, "icp-first"),
        (
            "KF on the odometry alone, across its gaps too, anchored (weighted)",
            kalman.increments(t, wheels, kalman.WHEEL_SIGMAS, source="wheel"),
            "weighted",
        ),
    ):
        params = dataclasses.replace(kalman.KF_MODES[mode], anchored=True)
        rows.append((name, kalman.path_at(kalman.run_filter(ms, params), t).poses))
    print(f"load average (1 min) {os.getloadavg()[0]:.1f}")
    print("| method | ATE (m) | end error (m) | relation error, consecutive (m) | (deg) |")
    print("|---|---|---|---|---|")
    for name, est in rows:
        print(killian_row(name, est, gt))


if __name__ == "__main__":
    main()
