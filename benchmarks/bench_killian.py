"""Laser odometry on real scans: the MIT Killian Court log, rigcal ICP against KISS-ICP.

The log (3873 CARMEN ROBOTLASER1 scans of a SICK laser, 180 beams at 1 degree, with
SLAM-corrected poses) comes inside a g2o file with the rtb-data package. Both methods
run on the same scans in the same run, each started from its previous motion (constant
velocity), and are scored against the corrected poses: RPE over 1 m and 10 m of path as
``rigcal.localize.metrics`` computes it (evo's RPE), and the error of each scan-to-scan
step (translation, m; rotation, deg; RMS). Time per scan is wall time over the whole log.

KISS-ICP gets each scan's valid points with z = 0 and this configuration (its defaults
are for 3D lidar at 10 Hz): no deskewing (one 2D sweep, no per-point stamps), range
0.1-50 m (the log's maximum range), 0.1 m voxels (default: max_range / 100 = 0.5 m,
coarser than a 180-beam indoor scan), one thread (as rigcal); adaptive threshold
defaults.

    uv sync --group bench        # rtb-data, kiss-icp
    .venv/bin/python benchmarks/bench_killian.py
"""

from __future__ import annotations

import tempfile
import time
import zipfile
from collections.abc import Callable
from importlib import resources
from pathlib import Path

import numpy as np
from kiss_icp.config.parser import KISSConfig
from kiss_icp.kiss_icp import KissICP

from rigcal.geometry import pose_of, se2
from rigcal.localize.icp import IcpParams
from rigcal.localize.metrics import anchored, evaluate
from rigcal.localize.odometry import icp_odometry
from rigcal.recordings.carmen import read_carmen
from rigcal.scan import Scan

FloatArray = np.ndarray


def killian_scans() -> tuple[list[Scan], FloatArray]:
    """The log's scans and corrected laser poses (x, y, yaw)."""
    archive = resources.files("rtbdata") / "data" / "killian.g2o.zip"
    with tempfile.TemporaryDirectory() as tmp, zipfile.ZipFile(str(archive)) as z:
        z.extract("killian.g2o", tmp)
        log = read_carmen(Path(tmp) / "killian.g2o")
    return log.scans, log.laser_poses


def kiss_icp_odometry(scans: list[Scan], max_range_m: float = 50.0) -> FloatArray:
    """KISS-ICP's laser poses (x, y, yaw) over the scans (2D points with z = 0)."""
    config = KISSConfig(
        data={"deskew": False, "max_range": max_range_m, "min_range": 0.1},
        mapping={"voxel_size": 0.1},
        registration={"max_num_threads": 1},
    )
    kiss = KissICP(config)
    poses = []
    for s in scans:
        p = s.points[s.valid]
        kiss.register_frame(np.column_stack([p, np.zeros(len(p))]), np.zeros(0))
        T = kiss.last_pose
        poses.append([T[0, 3], T[1, 3], np.arctan2(T[1, 0], T[0, 0])])
    return np.array(poses)


def step_errors(est: FloatArray, gt: FloatArray) -> tuple[float, float]:
    """RMS translation (m) and rotation (deg) error of the scan-to-scan motions."""
    t, r = [], []
    for k in range(1, len(gt)):
        d_gt = np.linalg.inv(se2(gt[k - 1])) @ se2(gt[k])
        d_est = np.linalg.inv(se2(est[k - 1])) @ se2(est[k])
        e = pose_of(np.linalg.inv(d_gt) @ d_est)
        t.append(np.hypot(e[0], e[1]))
        r.append(np.degrees(abs(e[2])))
    return float(np.sqrt(np.mean(np.square(t)))), float(np.sqrt(np.mean(np.square(r))))


def main() -> None:
    scans, gt = killian_scans()
    runs: dict[str, Callable[[list[Scan]], FloatArray]] = {
        "rigcal ICP point-to-line": lambda s: icp_odometry(s, IcpParams(method="point-to-line")).poses,
        "rigcal ICP point-to-point": lambda s: icp_odometry(s, IcpParams(method="point-to-point")).poses,
        "KISS-ICP": kiss_icp_odometry,
    }
    rows = {}
    for name, run in runs.items():
        t0 = time.perf_counter()
        est = run(scans)
        ms = 1000.0 * (time.perf_counter() - t0) / len(scans)
        m = evaluate(anchored(est, gt), gt)
        rows[name] = (m["rpe_1m_rmse_m"], m["rpe_10m_rmse_m"], *step_errors(est, gt), ms)
    kiss_ms = rows["KISS-ICP"][-1]
    print(f"MIT Killian Court: {len(scans)} scans, {len(scans[0].ranges_m)} beams")
    print("| method | RPE 1 m (m) | RPE 10 m (m) | step RMS (m) | step RMS (deg) | ms per scan "
          "| time / KISS-ICP |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for name, (r1, r10, st, sr, ms) in rows.items():
        print(f"| {name} | {r1:.3f} | {r10:.3f} | {st:.3f} | {sr:.2f} | {ms:.2f} | {ms / kiss_ms:.2f} |")


if __name__ == "__main__":
    main()
