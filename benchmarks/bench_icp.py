"""Laser odometry by ICP on the simulated loops, in the form of the paper's Table 1.

One lap of each built-in loop (``rigcal.sim``: 1 cm range noise, 1 % dropouts) at a 10 Hz
laser, localized with point-to-line and point-to-point ICP, scored against the ground
truth (``rigcal.localize.metrics``). Time per scan is also given as a ratio to the laser's
period (real time = 1).

    .venv/bin/python benchmarks/bench_icp.py
"""

from __future__ import annotations

import time

from rigcal.localize.icp import IcpParams
from rigcal.localize.metrics import anchored, evaluate
from rigcal.localize.odometry import icp_odometry
from rigcal.sim.drive import DriveSpec, Motion, laser_stamps, simulate_scans
from rigcal.sim.world import BUILTIN


def main() -> None:
    spec = DriveSpec(laser_rate_hz=10.0, seed=1)
    print("| world | method | loop closure (m) | loop closure (%) | avg position error (m) | ATE RMSE (m) "
          "| RPE 10 m (m) | ms per scan | x real time |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for name in ("corridor-loop", "cubicle-loop"):
        world = BUILTIN[name]()
        motion = Motion(world, spec)
        stamps = laser_stamps(motion, spec)
        gt = motion.poses(stamps)
        scans = simulate_scans(world, gt, stamps, spec)
        for method in ("point-to-line", "point-to-point"):
            t0 = time.perf_counter()
            od = icp_odometry(scans, IcpParams(method=method))
            ms = 1000.0 * (time.perf_counter() - t0) / len(scans)
            m = evaluate(anchored(od.poses, gt), gt)
            figures = (
                f"{m['loop_closure_error_m']:.3f} | {m['loop_closure_error_percent']:.2f} | "
                f"{m['average_position_error_m']:.3f} | {m['ate_rmse_m']:.3f} | {m['rpe_10m_rmse_m']:.3f}"
            )
            speed = f"{ms:.1f} | {(1000.0 / spec.laser_rate_hz) / ms:.1f}"
            print(f"| {name} | {method} | {figures} | {speed} |", flush=True)


if __name__ == "__main__":
    main()
