"""Laser odometry by ICP on the simulated loops, in the form of the paper's Table 1.

One lap of each built-in loop (``rigcal.sim``: 1 cm range noise, 1 % dropouts; and the
cubicle loop without noise or dropouts) at a 10 Hz laser, localized with point-to-line
ICP (line normals, as ``rigcal localize`` runs it, and 5-nearest-neighbour normals) and
point-to-point ICP, scored against the ground truth
(``rigcal.localize.metrics``), with the mean (bias) and RMS of the scan-to-scan yaw
error. Time per scan is also given as a ratio to the laser's period (real time = 1).

Then the time per scan pair of the simulated Hokuyo (1081 beams over 270 deg, 40 Hz) on
the first 400 scans of the cubicle loop, by the laser odometry as ``rigcal localize`` runs
it (each scan's lines extracted for the line normals; each pair started from the previous
motion), and with 5-nearest-neighbour normals as before: the best of three passes
(other processes on the machine only slow a pass down), as a ratio to the laser's 25 ms
period and to the 5 ms target, and, when the ``bench`` dependency group is installed,
KISS-ICP's time per scan on the same scans in the same run (its configuration as in
``bench_killian.py``, range up to 30 m).

    .venv/bin/python benchmarks/bench_icp.py
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np

from rigcal.localize.icp import IcpParams
from rigcal.localize.metrics import anchored, evaluate, steps
from rigcal.localize.odometry import icp_odometry
from rigcal.sim.drive import DriveSpec, Motion, laser_stamps, simulate_scans
from rigcal.sim.world import BUILTIN


def main() -> None:
    spec = DriveSpec(laser_rate_hz=10.0, seed=1)
    print("| world | method | loop closure (m) | loop closure (%) | avg position error (m) | ATE RMSE (m) "
          "| RPE 10 m (m) | step yaw bias (mdeg) | step yaw RMS (mdeg) "
          "| ms per scan | x real time |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    variants = {
        "point-to-line": IcpParams(),
        "point-to-line, 5-nearest normals": IcpParams(normals="neighbours"),
        "point-to-point": IcpParams(method="point-to-point"),
    }
    noiseless = dataclasses.replace(spec, range_sigma_m=0.0, dropout_fraction=0.0)
    for name, spec_w in (
        ("corridor-loop", spec),
        ("cubicle-loop", spec),
        ("cubicle-loop, noiseless", noiseless),
    ):
        world = BUILTIN[name.split(",")[0]]()
        motion = Motion(world, spec_w)
        stamps = laser_stamps(motion, spec_w)
        gt = motion.poses(stamps)
        scans = simulate_scans(world, gt, stamps, spec_w)
        for label, params in variants.items():
            t0 = time.perf_counter()
            od = icp_odometry(scans, params)
            ms = 1000.0 * (time.perf_counter() - t0) / len(scans)
            m = evaluate(anchored(od.poses, gt), gt)
            bias, rms = step_yaw_errors_mdeg(od.poses, gt)
            figures = (
                f"{m['loop_closure_error_m']:.3f} | {m['loop_closure_error_percent']:.2f} | "
                f"{m['average_position_error_m']:.3f} | {m['ate_rmse_m']:.3f} | {m['rpe_10m_rmse_m']:.3f} | "
                f"{bias:.2f} | {rms:.1f}"
            )
            speed = f"{ms:.1f} | {(1000.0 / spec.laser_rate_hz) / ms:.1f}"
            print(f"| {name} | {label} | {figures} | {speed} |", flush=True)

    pair_timing()


def pair_timing(target_ms: float = 5.0) -> None:
    """Time per 1081-point scan pair at 40 Hz (best of three passes)."""
    spec = DriveSpec(laser_rate_hz=40.0, seed=1)
    world = BUILTIN["cubicle-loop"]()
    motion = Motion(world, spec)
    stamps = laser_stamps(motion, spec)[:400]
    scans = simulate_scans(world, motion.poses(stamps), stamps, spec)
    budget_ms = 1000.0 / spec.laser_rate_hz
    print()
    print(f"| method | beams | ms per scan pair | x real time ({budget_ms:.0f} ms) "
          f"| x {target_ms:.0f} ms target | time / KISS-ICP |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    times: dict[str, float] = {}
    variants = {
        "point-to-line": IcpParams(),
        "point-to-line, 5-nearest normals": IcpParams(normals="neighbours"),
        "point-to-point": IcpParams(method="point-to-point"),
    }
    for label, params in variants.items():
        # The odometry as `rigcal localize` runs it: each scan's lines extracted (for the
        # line normals), restarts from zero motion included.
        times[label] = best_ms(lambda params=params: icp_odometry(scans, params), len(scans) - 1)
    try:
        from bench_killian import kiss_icp_odometry  # the bench group's kiss-icp
    except ImportError:
        kiss = None
    else:
        kiss = best_ms(lambda: kiss_icp_odometry(scans, max_range_m=30.0), len(scans) - 1)
    beams = len(scans[0].ranges_m)
    for method, ms in [*times.items(), ("KISS-ICP", kiss)]:
        if ms is None:
            continue
        ratio = f"{ms / kiss:.2f}" if kiss else "-"
        print(f"| {method} | {beams} | {ms:.2f} | {budget_ms / ms:.1f} | {target_ms / ms:.2f} | {ratio} |")


def step_yaw_errors_mdeg(poses: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """Mean (bias) and RMS of the scan-to-scan yaw error against the truth, millidegrees:
    a bias adds up round a loop driven one way."""
    est, true = steps(poses)[:, 2], steps(gt)[:, 2]
    e = np.degrees(np.angle(np.exp(1j * (est - true)))) * 1000.0
    return float(e.mean()), float(np.sqrt(np.mean(e * e)))


def best_ms(work: Callable[[], None], pairs: int, passes: int = 3) -> float:
    """Milliseconds per scan pair of the best of several passes of ``work``."""
    out = []
    for _ in range(passes):
        t0 = time.perf_counter()
        work()
        out.append(1000.0 * (time.perf_counter() - t0) / pairs)
    return min(out)


if __name__ == "__main__":
    main()
